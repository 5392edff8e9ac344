"""The UR adapter: ur-rtde's RTDEControlInterface (motion), RTDEReceiveInterface (state),
DashboardClient (protective-stop unlock).

The controller's TCP is set to the flange on connect (``setTcp([0]*6)``), so ``getActualTCPPose``
is the flange pose and every command is a flange pose; the tool offset lives in weldcell
(:class:`~weldcell.hal.robot.Robot` converts TCP <-> flange and gates every motion first).
In dry-run mode only the receive interface is opened: nothing can take control of the arm.
"""

from __future__ import annotations

import logging
import time

import dashboard_client
import numpy as np
import rtde_control
import rtde_receive
from weldcell.hal.robot import Robot
from weldcell.hal.safety import SafetyGate
from weldcell.hal.safety import path_blends as gate_path_blends
from weldcell.plugins.ur import rtde_protocol as P
from weldcell.plugins.ur.settings import URSettings
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.geometry import T_from_ur_pose, T_to_ur_pose

log = logging.getLogger("weldcell.ur")

_NET_FIX = "check the robot is on, in remote control, and reachable at {host} (network cable, IP address)"


def path_blends(poses: np.ndarray, blend: float) -> np.ndarray:
    """Per-waypoint blend radii for moveL paths (UR refuses overlapping blends and needs the path to end
    with a zero blend): the gate's own rule, :func:`weldcell.hal.safety.path_blends`, on the positions."""
    return gate_path_blends(np.asarray(poses, dtype=float)[:, :3, 3], blend)


class URRobot(Robot):
    """A UR arm through ur-rtde (device ``robot.ur-rtde``)."""

    def __init__(
        self,
        settings: URSettings | None = None,
        name: str = "robot",
        gate: SafetyGate | None = None,
        dry_run: bool = False,
    ) -> None:
        self.settings = settings or URSettings()
        super().__init__(name, gate=gate, motion=self.settings, dry_run=dry_run)
        self._r = None
        self._c = None
        self._protective_stop_seen = False
        self._last_ts: float | None = None
        self._last_change = 0.0

    # -- lifecycle -------------------------------------------------------------------------------
    @property
    def _freq(self) -> float:
        return -1.0 if self.settings.frequency is None else float(self.settings.frequency)

    def _fix(self) -> str:
        return _NET_FIX.format(host=self.settings.host)

    def on_configure(self) -> None:
        s = self.settings
        if self._r is None or not self._r.isConnected():
            self._drop(self._r)
            self._r = None
            try:
                self._r = rtde_receive.RTDEReceiveInterface(s.host, self._freq)
            except RuntimeError as e:
                raise DeviceError(
                    f"RTDE receive connection to {s.host}:30004 failed: {e}", self._fix()
                ) from e
        self._last_ts, self._last_change = None, time.monotonic()
        self._check_safety()
        if self.dry_run:
            return
        if self._c is None or not self._c.isConnected():
            self._drop(self._c)
            self._c = None
            flags = rtde_control.RTDEControlInterface.FLAG_UPLOAD_SCRIPT
            if s.use_external_control_urcap:
                flags = rtde_control.RTDEControlInterface.FLAG_USE_EXT_UR_CAP
            try:
                self._c = rtde_control.RTDEControlInterface(s.host, self._freq, int(flags), s.ur_cap_port)
            except RuntimeError as e:
                raise DeviceError(
                    f"RTDE control connection to {s.host} failed: {e}",
                    "put the robot in remote control (e-Series), power it on and release the brakes; "
                    + self._fix(),
                ) from e
        if not self._c.setTcp([0.0] * 6):
            raise DeviceError(
                "the controller refused setTcp([0]*6)", "check that the control script is running"
            )

    def on_activate(self) -> None:
        self._check_link()
        self._check_safety()

    def on_deactivate(self) -> None:
        if self._c is not None and self._c.isConnected():
            self._c.stopL(max(self.motion.accel, 1.0), False)

    def on_close(self) -> None:
        c, r = self._c, self._r
        self._c = self._r = None
        self._drop(c)
        self._drop(r)

    @staticmethod
    def _drop(iface) -> None:
        if iface is None:
            return
        try:
            if iface.isConnected():
                iface.disconnect()
        except Exception as e:  # noqa: BLE001 - a broken link must not stop closing
            log.debug("disconnect failed: %s", e)

    def on_recover(self) -> None:
        """Close the safety popup and unlock a protective stop through the Dashboard, then reconnect."""
        s = self.settings
        if self._protective_stop_seen:
            dash = dashboard_client.DashboardClient(s.host, s.dashboard_port)
            try:
                dash.connect(int(s.connect_timeout * 1000))
                dash.closeSafetyPopup()
                dash.unlockProtectiveStop()
            except RuntimeError as e:
                raise DeviceError(
                    f"Dashboard server at {s.host}:{s.dashboard_port} failed: {e}",
                    "clear the protective stop on the teach pendant",
                ) from e
            finally:
                try:
                    dash.disconnect()
                except RuntimeError:
                    pass
        for iface in (self._r, self._c):
            if iface is not None and not iface.isConnected():
                try:
                    iface.reconnect()
                except RuntimeError as e:
                    raise DeviceError(f"cannot reconnect to {s.host}: {e}", self._fix()) from e
        if self._r is not None and self._protective_stop_seen:
            deadline = time.monotonic() + max(1.0, 2 * s.state_timeout)
            while self._r.isProtectiveStopped() and time.monotonic() < deadline:
                time.sleep(0.01)
            if self._r.isProtectiveStopped():
                raise DeviceError(
                    "the protective stop is still active after the unlock request",
                    "wait 5 s after the stop, remove its cause, then recover() again",
                )
        self._protective_stop_seen = False

    # -- checks ----------------------------------------------------------------------------------
    def _check_link(self) -> None:
        if self._r is None or not self._r.isConnected():
            raise self.fault(f"RTDE connection to {self.settings.host} lost")
        if not self.dry_run and (self._c is None or not self._c.isConnected()):
            raise self.fault(f"RTDE control connection to {self.settings.host} lost")

    def _check_safety(self) -> None:
        r = self._r
        mode = int(r.getSafetyMode())
        if r.isProtectiveStopped() or mode in P.STOPPED_SAFETY_MODES:
            self._protective_stop_seen = True
            name = P.SAFETY_MODES.get(mode, str(mode))
            e = self.fault(f"robot is stopped by its safety system ({name}); motion is locked")
            raise DeviceError(
                e.message,
                "remove the cause of the stop, then recover() (closes the popup and "
                "unlocks a protective stop through the Dashboard server) and configure() again",
            )

    def _check_fresh(self) -> None:
        ts, now = float(self._r.getTimestamp()), time.monotonic()
        if ts != self._last_ts:
            self._last_ts, self._last_change = ts, now
        elif now - self._last_change > self.settings.state_timeout:
            raise self.fault(
                f"no new RTDE data from {self.settings.host} for {now - self._last_change:.2f} s"
            )

    def _await_fresh_state(self, packages: int = 2) -> None:
        """After a blocking motion: wait (bounded) for ``packages`` new RTDE packages, so the next state
        reading was sampled after the motion ended (one package may already be on its way)."""
        r = self._r
        last, seen = float(r.getTimestamp()), 0
        deadline = time.monotonic() + self.settings.state_timeout
        while seen < packages and time.monotonic() < deadline:
            ts = float(r.getTimestamp())
            if ts != last:
                last, seen = ts, seen + 1
            else:
                time.sleep(0.0005)

    # -- driver side -----------------------------------------------------------------------------
    def _read_state(self) -> tuple[np.ndarray, np.ndarray, dict]:
        self._check_link()
        self._check_safety()
        self._check_fresh()
        r = self._r
        q = np.asarray(r.getActualQ(), dtype=float)
        T = T_from_ur_pose(r.getActualTCPPose())
        qd = np.asarray(r.getActualQd(), dtype=float)
        return q, T, {"qd": qd, "moving": bool(np.max(np.abs(qd)) > 1e-3), "protective_stop": False}

    def _command(self, what: str, fn, *args) -> None:
        self._check_link()
        try:
            ok = fn(*args)
        except RuntimeError as e:
            raise self.fault(f"{what} failed: {e}") from e
        if ok is False:
            self._check_link()
            self._check_safety()
            raise DeviceError(
                f"the controller did not complete {what}",
                "check the pendant's log (singularity, joint limit, or the program was stopped)",
            )

    def _move_linear(self, T_base_flange: np.ndarray, speed: float, accel: float) -> None:
        self._command("moveL", self._c.moveL, T_to_ur_pose(T_base_flange).tolist(), speed, accel, False)
        self._await_fresh_state()

    def _move_joint(self, q: np.ndarray, speed: float, accel: float) -> None:
        self._command("moveJ", self._c.moveJ, np.asarray(q, dtype=float).tolist(), speed, accel, False)
        self._await_fresh_state()

    def _follow_path(self, poses: np.ndarray, speed: float, accel: float, blend: float) -> None:
        blends = path_blends(poses, blend)
        path = [
            [*T_to_ur_pose(T).tolist(), speed, accel, float(b)] for T, b in zip(poses, blends, strict=True)
        ]
        self._command("moveL path", self._c.moveL, path, False)
        self._await_fresh_state()

    def _speed_linear(self, twist: np.ndarray, accel: float, duration: float) -> None:
        self._command("speedL", self._c.speedL, np.asarray(twist, dtype=float).tolist(), accel, duration)

    def _stop(self, decel: float) -> None:
        c = self._c
        if c is None or not c.isConnected():
            log.warning(
                "stop: no control connection to %s (the control script stops the arm when its "
                "connection drops)",
                self.settings.host,
            )
            return
        try:
            c.stopL(decel, False)
        except RuntimeError as e:
            log.warning("stopL failed: %s", e)
