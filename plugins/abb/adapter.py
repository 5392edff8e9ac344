"""The ABB adapter: abb-robot-client's RWS (Robot Web Services 1.0, IRC5 / RobotWare 6) and EGM.

* State: the EGM stream (joints and tool0 in the base frame at 250 Hz) when ``use_egm``; otherwise RWS
  ``jointtarget`` / ``robtarget`` polls. Controller state (``ctrlstate``, ``opmode``, RAPID execution)
  through RWS before every motion and whenever the stream says the motors are off or it stops.
* Motion: RAPID. The server module ``WeldcellServer`` (rapid/WeldcellServer.mod) executes MoveL paths and
  MoveAbsJ moves from PERS variables the adapter writes through RWS; ``speed_linear`` streams pose targets
  through EGM (EGMRunPose). A stop increments ``wc_stop``, whose IPers trap stops and clears the path.

Every pose crossing the wire is tool0 (the flange) in wobj0 (the robot base); the TCP offset lives in
weldcell (:class:`~weldcell.hal.robot.Robot` converts TCP <-> flange and runs the safety gate first).
"""

from __future__ import annotations

import logging
import time

import numpy as np
import requests
from abb_robot_client.rws import RWS, ABBException
from weldcell.hal.lifecycle import Health
from weldcell.hal.robot import Robot
from weldcell.hal.safety import SafetyGate
from weldcell.plugins.abb import RAPID_MODULE
from weldcell.plugins.abb import rapid_values as V
from weldcell.plugins.abb.egm_stream import EgmSample, EgmStream
from weldcell.plugins.abb.settings import ABBSettings
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.geometry import rotation_angle

log = logging.getLogger("weldcell.abb")

CMD_PATH, CMD_JOINT, CMD_EGM = 1, 2, 3
MODULE_VERSION = 1
STATUS_OK, STATUS_STOPPED, STATUS_ERROR = 0, 1, 2

_STOPPED = {
    "emergencystop": (
        "the emergency stop is pressed",
        "release the emergency stop, press the reset button "
        "on the cabinet/FlexPendant, switch the motors on, then recover()",
    ),
    "emergencystopreset": (
        "the emergency stop was reset but the motors are still off",
        "press Motors On (or set motors_on = true in AUTO), then recover()",
    ),
    "guardstop": (
        "a guard stop is active (safety fence, light curtain or enabling device)",
        "close the guard / clear the light curtain and reset the stop, then recover()",
    ),
    "sysfail": (
        "the controller is in system failure",
        "read the event log on the FlexPendant and restart the controller",
    ),
}


class ABBRobot(Robot):
    """An ABB IRC5 arm through RWS + EGM (device ``robot.abb-rws``)."""

    def __init__(
        self,
        settings: ABBSettings | None = None,
        name: str = "robot",
        gate: SafetyGate | None = None,
        dry_run: bool = False,
    ) -> None:
        self.settings = settings or ABBSettings()
        super().__init__(name, gate=gate, motion=self.settings, dry_run=dry_run)
        self._rws: RWS | None = None
        self._egm: EgmStream | None = None
        self._egm_seen = False
        self._seq = 0
        self._servo_seq: int | None = None
        self._last_q: tuple[float, np.ndarray] | None = None
        self._status = ""

    # -- RWS helpers -----------------------------------------------------------------------------
    def _var(self, name: str) -> str:
        return f"{self.settings.module}/{name}"

    def _call(self, what: str, fn, *args, **kw):
        """One RWS request; a broken link or an HTTP error becomes a fault with a fix."""
        if self._rws is None:
            raise self.fault(f"no RWS session with {self.settings.url}")
        try:
            return fn(*args, **kw)
        except ABBException as e:
            raise DeviceError(
                f"controller refused {what}: {e} (code {e.code})",
                f"check that module {self.settings.module} is loaded in task {self.settings.task} "
                "(docs/devices/abb.md) and that no other client holds RAPID mastership",
            ) from e
        except requests.RequestException as e:
            raise self.fault(f"RWS request '{what}' to {self.settings.url} failed: {e}") from e
        except Exception as e:  # noqa: BLE001 - the library raises bare Exception for HTTP errors
            msg = str(e)
            if "401" in msg:
                raise DeviceError(
                    f"RWS at {self.settings.url} rejected user '{self.settings.username}' ({msg})",
                    'set username and password = "${env:ABB_RWS_PASSWORD}" in the profile and export the '
                    "variable (RobotWare 6 factory default: 'Default User' / 'robotics')",
                ) from e
            raise self.fault(f"RWS request '{what}' failed: {msg}") from e

    def _get_num(self, name: str) -> float:
        task = self.settings.task
        return float(self._call(f"read {name}", self._rws.get_rapid_variable, self._var(name), task))

    def _set(self, name: str, value) -> None:
        task = self.settings.task
        self._call(f"write {name}", self._rws.set_rapid_variable, self._var(name), str(value), task)

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        s = self.settings
        if s.password is None:
            raise DeviceError(
                f"no RWS password configured for {s.url}",
                'add password = "${env:ABB_RWS_PASSWORD}" to the device\'s settings and export '
                "ABB_RWS_PASSWORD (the controller's factory default is 'robotics')",
            )
        self._rws = RWS(s.url.rstrip("/"), s.username, s.password.get_secret_value())
        self._status = ""
        version = self._module_version()
        if version != MODULE_VERSION and s.install_module and not self.dry_run:
            self.install_module()
            version = self._module_version()
        if version != MODULE_VERSION:
            found = "is not loaded" if version is None else f"has version {version:g}"
            raise DeviceError(
                f"RAPID module {s.module} {found} in task {s.task}; "
                f"this weldcell needs version {MODULE_VERSION}",
                "load plugins/abb/rapid/WeldcellServer.mod (docs/devices/abb.md), or set "
                "install_module = true to let weldcell load it through RWS (AUTO mode)",
            )
        raw = str(self._call("read ctrlstate", self._rws.get_controller_state))
        if raw in ("motoroff", "emergencystopreset") and s.motors_on and not self.dry_run:
            self._require_auto("switch the motors on")
            self._call("motors on", self._rws.set_controller_state, "motoron")
        ctrl = self._ctrlstate()
        running = self._execution() == "running"
        if not running and s.start_program and not self.dry_run:
            self._start_program(ctrl)
            running = True
        self._seq = int(max(self._get_num("wc_seq"), self._get_num("wc_done")))
        if s.use_egm:
            self._open_egm(running)

    def _module_version(self) -> float | None:
        """``wc_version`` of the loaded module, None when the controller has no such symbol."""
        try:
            return self._get_num("wc_version")
        except DeviceError as e:
            if isinstance(e.__cause__, ABBException):
                return None
            raise

    def install_module(self) -> None:
        """Upload WeldcellServer.mod to $HOME and load it into the task through RWS (stops RAPID; AUTO
        mode; takes and releases RAPID mastership). The RWS calls abb-robot-client has no wrapper for
        (mastership, loadmod) go through its own authenticated session (``_do_post``)."""
        s = self.settings
        path = f"$HOME/{s.module}.mod"
        self._require_auto(f"load {s.module}")
        if self._execution() == "running":
            self._call("stop RAPID", self._rws.stop)
        self._call(f"upload {path}", self._rws.upload_file, path, RAPID_MODULE.read_bytes())
        self._call("request RAPID mastership", self._rws._do_post, "rw/mastership/rapid?action=request")
        try:
            self._call(
                f"load {path} into {s.task}",
                self._rws._do_post,
                f"rw/rapid/tasks/{s.task}?action=loadmod",
                {"modulepath": path, "replace": "true"},
            )
        finally:
            try:
                self._rws._do_post("rw/mastership/rapid?action=release")
            except Exception as e:  # noqa: BLE001 - a failed release must not hide the load's result
                log.warning("releasing RAPID mastership failed: %s", e)
        log.info("loaded %s into %s on %s", path, s.task, s.url)

    def _open_egm(self, running: bool) -> None:
        s = self.settings
        if self._egm is None:
            try:
                self._egm = EgmStream(s.egm_host, s.egm_port)
            except OSError as e:
                raise DeviceError(
                    f"cannot bind the EGM UDP socket {s.egm_host}:{s.egm_port}: {e}",
                    "free the port or choose another egm_port (and the UC device's remote port)",
                ) from e
        self._egm_seen = False
        t0 = time.time() - 1e-3
        if self._egm.wait_newer(t0, 1, s.egm_timeout):
            self._egm_seen = True
            self._check_egm_frame()
        elif running:
            raise DeviceError(
                f"RAPID runs but no EGM message arrived on UDP port {self._egm.port} "
                f"within {s.egm_timeout} s",
                "check the UC device 'WeldcellPC' (remote address = this PC, remote port = egm_port) and the "
                "firewall; or set use_egm = false",
            )
        else:
            log.warning("RAPID is stopped: no EGM stream; reading the state through RWS until it starts")

    def _check_egm_frame(self) -> None:
        """EGM's pose must be tool0 in the base frame: compare it once with RWS's robtarget."""
        s = self._egm.latest
        T_rws = self._rws_flange()
        err = float(np.linalg.norm(s.T_base_flange[:3, 3] - T_rws[:3, 3]))
        ang = rotation_angle(s.T_base_flange[:3, :3].T @ T_rws[:3, :3])
        if err > 2e-3 or ang > np.radians(0.5):
            raise DeviceError(
                f"EGM reports the flange {err * 1000:.1f} mm / {np.degrees(ang):.2f} deg away from RWS's "
                "robtarget(tool0, wobj0, Base)",
                "the EGM setup must use tool0 and wobj0, and wobj0 must be the base frame "
                "(check EGMActPose in WeldcellServer and the robot's base/world frames)",
            )

    def _start_program(self, ctrl: str) -> None:
        s = self.settings
        self._require_auto("start RAPID")
        if ctrl != "motoron":
            raise DeviceError(
                f"cannot start {s.module}: the motors are off (controller state {ctrl})",
                "press Motors On (or set motors_on = true), then configure() again",
            )
        self._call("reset program pointer", self._rws.resetpp)
        self._call("start RAPID", self._rws.start, "forever", [s.task])
        deadline = time.monotonic() + 2.0
        while self._execution() != "running":
            if time.monotonic() > deadline:
                raise DeviceError("RAPID did not start", "start the program on the FlexPendant")
            time.sleep(0.02)

    def on_activate(self) -> None:
        self._read_state()

    def on_deactivate(self) -> None:
        if self._servo_seq is not None:
            self._stop_quietly()  # a servo still streaming must not outlive the active state
        if self._egm is not None:
            self._egm.end_servo()

    def on_close(self) -> None:
        egm, rws = self._egm, self._rws
        self._egm = self._rws = None
        if egm is not None:
            egm.close()
        if rws is not None:
            try:
                rws.close()  # logs out (frees one of the controller's RWS sessions)
            except Exception as e:  # noqa: BLE001 - a broken link must not stop closing
                log.debug("RWS logout failed: %s", e)

    def on_recover(self) -> None:
        """Drop the sessions; configure() logs in again, restarts RAPID and reopens EGM."""
        self.on_close()

    def health(self) -> Health:
        h = super().health()
        if h.ok and self._status:
            return Health(ok=h.ok, state=h.state, message=self._status, last_reading_age=h.last_reading_age)
        return h

    # -- controller state ------------------------------------------------------------------------
    def _ctrlstate(self) -> str:
        st = str(self._call("read ctrlstate", self._rws.get_controller_state))
        if st in _STOPPED:
            what, fix = _STOPPED[st]
            self.fault(f"{what} (controller state {st})")
            raise DeviceError(f"{self.kind} '{self.name}': {what} (controller state {st})", fix)
        return st

    def _execution(self) -> str:
        return str(self._call("read RAPID execution state", self._rws.get_execution_state).ctrlexecstate)

    def _require_auto(self, what: str) -> None:
        mode = str(self._call("read operation mode", self._rws.get_operation_mode))
        if mode != "AUTO":
            self._status = f"controller in {mode} mode"
            raise DeviceError(
                f"cannot {what}: the controller is in {mode} mode (manual or changing)",
                "weldcell commands the arm only in AUTO: turn the key switch to AUTO and acknowledge "
                "the mode change on the FlexPendant",
            )

    def _require_ready(self, what: str) -> None:
        """Before any motion: no stop active, motors on, AUTO, RAPID running."""
        ctrl = self._ctrlstate()
        self._require_auto(what)
        if ctrl != "motoron":
            self._status = f"motors are {ctrl}"
            raise DeviceError(
                f"cannot {what}: the motors are off (controller state {ctrl})",
                "press Motors On on the cabinet/FlexPendant (or set motors_on = true), then try again",
            )
        if self._execution() != "running":
            self._status = "RAPID stopped"
            raise DeviceError(
                f"cannot {what}: RAPID execution is stopped, so {self.settings.module} is not serving",
                "recover() and configure() again (start_program = true restarts it), or press Play",
            )
        self._status = ""

    # -- state -----------------------------------------------------------------------------------
    def _rws_flange(self) -> np.ndarray:
        rt = self._call(
            "read robtarget", self._rws.get_robtarget, self.settings.mechunit, "tool0", "wobj0", "Base"
        )
        return V.T_from_abb(rt.trans, rt.rot)

    def _fresh_egm(self) -> EgmSample | None:
        if self._egm is None:
            return None
        s = self._egm.latest
        if s is not None and time.time() - s.stamp <= self.settings.state_timeout:
            self._egm_seen = True
            return s
        return None

    def _read_state(self) -> tuple[np.ndarray, np.ndarray, dict]:
        s = self._fresh_egm()
        if s is None and self._egm_seen and self._egm is not None:
            # one more period of grace before a late stream counts as stopped (a busy host)
            last = self._egm.latest
            if self._egm.wait_newer(0.0 if last is None else last.stamp, 1, self.settings.state_timeout):
                s = self._fresh_egm()
        if s is not None:
            if not s.motors_on:
                ctrl = self._ctrlstate()  # raises (and faults) for E-stop, guard stop, system failure
                self._status = f"motors are {ctrl}"
            q, T, stamp = s.q, s.T_base_flange, s.stamp
        else:
            if self._egm_seen:
                ctrl = self._ctrlstate()  # raises (and faults) for E-stop, guard stop, system failure
                if ctrl != "motoron":
                    raise self.fault(f"the motors went off ({ctrl}); RAPID and the EGM stream stopped")
                if self._execution() != "running":
                    raise self.fault("RAPID execution stopped: the EGM stream and WeldcellServer ended")
                age = (
                    "never"
                    if self._egm is None or self._egm.latest is None
                    else (f"{time.time() - self._egm.latest.stamp:.2f} s ago")
                )
                raise self.fault(f"the EGM stream stopped (last message {age}) while RAPID runs")
            self._ctrlstate()
            jt = self._call("read jointtarget", self._rws.get_jointtarget, self.settings.mechunit)
            q = np.radians(np.asarray(jt.robax[:6], dtype=float))
            T, stamp = self._rws_flange(), time.time()
        qd = None
        if self._last_q is not None and stamp > self._last_q[0]:
            qd = (q - self._last_q[1]) / (stamp - self._last_q[0])
        self._last_q = (stamp, q)
        moving = qd is not None and bool(np.max(np.abs(qd)) > 1e-3)
        return q, T, {"qd": qd, "moving": moving, "protective_stop": False}

    def stream(self) -> list[EgmSample]:
        """Every EGM sample since the last call (time-stamped on arrival, 250 Hz), oldest first."""
        self.require_active()
        return [] if self._egm is None else self._egm.drain()

    # -- motion through WeldcellServer -----------------------------------------------------------
    def _run(self, cmd: int, data: dict[str, str], planned_time: float, what: str) -> None:
        self._require_ready(what)
        self._finish_servo()
        for name, value in data.items():
            self._set(name, value)
        self._seq += 1
        seq = self._seq
        self._set("wc_cmd", cmd)
        self._set("wc_seq", seq)  # last: WeldcellServer starts on this write
        self._await(seq, planned_time + self.settings.motion_timeout_margin, what)

    def _await(self, seq: int, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                if self._get_num("wc_done") >= seq:
                    break
                s = self._fresh_egm()
                if s is not None and not s.motors_on:
                    self._ctrlstate()
                    raise DeviceError(f"{what}: the motors went off during the motion", "see the event log")
                if self._egm is not None and self._egm_seen and s is None:
                    self._read_state()  # raises the reason the stream stopped
            except DeviceError:
                self._stop_quietly()
                raise
            if time.monotonic() > deadline:
                self._stop_quietly()
                raise DeviceError(
                    f"{what} did not finish within {timeout:.1f} s; the robot was stopped",
                    "check the FlexPendant (speed override, a held program) and the event log",
                )
            time.sleep(self.settings.poll_period)
        status = int(self._get_num("wc_status"))
        if status == STATUS_STOPPED:
            raise DeviceError(f"{what} was stopped before it finished", "start the motion again if intended")
        if status != STATUS_OK:
            errno = int(self._get_num("wc_errno"))
            raise DeviceError(
                f"the controller could not execute {what} (RAPID error {errno})",
                "read the event log: a target out of reach, a joint limit or a singularity on the path",
            )
        if self._egm is not None and self._egm_seen:
            self._egm.wait_newer(time.time(), 2, self.settings.state_timeout)

    def _move_time(self, T0: np.ndarray, poses: np.ndarray, speed: float, accel: float) -> float:
        pts = np.vstack([T0[:3, 3], poses[:, :3, 3]])
        dist = float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))
        return dist / speed + 2 * speed / accel * len(poses)

    def _move_linear(self, T_base_flange: np.ndarray, speed: float, accel: float) -> None:
        self._follow_path(T_base_flange[None], speed, accel, 0.0)

    def _follow_path(self, poses: np.ndarray, speed: float, accel: float, blend: float) -> None:
        s = self.settings
        n = s.path_chunk
        T0 = self._read_state()[1]
        v_ori = min(self.gate.limits.max_angular_speed, np.radians(500.0))
        for i in range(0, len(poses), n):
            chunk = poses[i : i + n]
            data = {
                "wc_speed": V.speeddata(speed, v_ori),
                "wc_zone": V.zonedata(blend),
                "wc_acc": f"{max(accel, 0.1):.4f}",
                "wc_path": V.array([V.robtarget(T) for T in chunk], 100),
                "wc_n": str(len(chunk)),
            }
            self._run(CMD_PATH, data, self._move_time(T0, chunk, speed, max(accel, 0.1)), "linear move")
            T0 = chunk[-1]

    def _move_joint(self, q: np.ndarray, speed: float, accel: float) -> None:
        q0 = self._read_state()[0]
        v_tcp = self.gate.limits.max_linear_speed
        t = float(np.max(np.abs(np.asarray(q) - q0))) / speed + 2 * speed / accel
        if self.gate.model is not None:  # the TCP cap may be what limits the move: its path length
            qs = q0 + np.linspace(0.0, 1.0, 33)[:, None] * (np.asarray(q) - q0)
            p = np.array([(self.gate.model.fk(x) @ self.T_flange_tcp)[:3, 3] for x in qs])
            t = max(t, float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) / v_tcp)
        # MoveAbsJ: v_tcp = the cell's TCP speed cap, v_ori = the joint speed (see docs/devices/abb.md)
        data = {
            "wc_speed": V.speeddata(v_tcp, speed),
            "wc_jtarget": V.jointtarget(q),
        }
        self._run(CMD_JOINT, data, t, "joint move")

    def _speed_linear(self, twist: np.ndarray, accel: float, duration: float) -> None:
        if self._egm is None:
            raise DeviceError("speed_linear needs the EGM stream", "set use_egm = true (docs/devices/abb.md)")
        s = self._fresh_egm()
        if s is None or not s.mci_running:
            self._start_servo()
        self._egm.servo(twist, duration)

    def _finish_servo(self) -> None:
        """Let a running EGM servo converge on its held target and end (EGMRunPose's CondTime)."""
        if self._egm is None or self._servo_seq is None:
            return
        seq, self._servo_seq = self._servo_seq, None
        self._egm.hold()
        try:
            self._await(seq, 2.0, "EGM servo")
        except DeviceError as e:
            if "was stopped" not in e.message:
                raise
        finally:
            self._egm.end_servo()

    def _start_servo(self) -> None:
        self._require_ready("servo through EGM")
        self._finish_servo()
        self._set("wc_egm_time", "0.5")
        self._seq += 1
        self._set("wc_cmd", CMD_EGM)
        self._set("wc_seq", self._seq)
        self._servo_seq = self._seq
        self._egm.servo(np.zeros(6), 0.0)  # start streaming the current pose as the target
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            s = self._egm.latest
            if s is not None and s.mci_running:
                return
            time.sleep(0.002)
        self._stop_quietly()
        raise DeviceError("EGMRunPose did not start within 1 s", "check the event log (EGM errors)")

    def _stop_quietly(self) -> None:
        try:
            self._stop(1.0)
        except Exception as e:  # noqa: BLE001 - stopping must not mask the original error
            log.warning("stop failed: %s", e)

    def _stop(self, decel: float) -> None:
        self._servo_seq = None
        if self._egm is not None:
            self._egm.end_servo()
        if self._rws is None:
            log.warning("stop: no RWS session with %s", self.settings.url)
            return
        try:
            n = self._rws.get_rapid_variable(self._var("wc_stop"), self.settings.task)
            self._rws.set_rapid_variable(self._var("wc_stop"), str(int(float(n)) + 1), self.settings.task)
        except Exception as e:  # noqa: BLE001 - fall back to stopping RAPID
            log.warning("stop through wc_stop failed (%s); stopping RAPID execution", e)
            try:
                self._rws.stop()
            except Exception as e2:  # noqa: BLE001
                log.error("RAPID stop failed too: %s", e2)
