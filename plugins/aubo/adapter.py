"""AUBO i-series (ARCS controller) through ``pyaubo_sdk`` as a weldcell :class:`Robot`.

The SDK's ``RpcClient`` speaks JSON-RPC 2.0 over TCP (port 30004; frames ``b"SOF\\x01"`` + big-endian length +
JSON; methods like ``rob1.MotionControl.moveLine`` with named parameters). Poses on the wire are
``[x, y, z, rx, ry, rz]`` in metres and roll-pitch-yaw (``R = Rz Ry Rx``, :func:`T_from_rpy`) of the
controller's *active TCP*; its offset from the flange (``RobotConfig.getTcpOffset``) is read at configure:

* state:    ``T_base_flange = T(getTcpPose) · T(tcp_offset)^-1``
* commands: ``moveLine(T_base_flange · T(tcp_offset))``; ``speedLine`` gets the twist of that TCP.

Motions are queued by the controller; completion is followed with ``MotionControl.getExecId`` (-1 = idle),
as in AUBO's ``waitArrival`` example, while the safety mode is watched for protective stops.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pyaubo_sdk
from weldcell.hal.lifecycle import State
from weldcell.hal.robot import Robot
from weldcell.hal.safety import SafetyGate
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.geometry import T_from_rpy, T_to_rpy, invert

from .settings import AuboSettings

log = logging.getLogger("weldcell.aubo")
FACTORY_PASSWORD = "123456"  # AUBO's documented factory default, used only when the env variable is unset
FAULT_SAFETY = {"Violation", "Fault", "SystemEmergencyStop", "RobotEmergencyStop"}
STOP_SAFETY = {"ProtectiveStop", "SafeguardStop"}


def pose_to_T(pose: Any) -> np.ndarray:
    p = np.asarray(pose, dtype=float).reshape(6)
    return T_from_rpy(p[3:], p[:3])


def T_to_pose(T: np.ndarray) -> list[float]:
    return [*map(float, np.asarray(T)[:3, 3]), *map(float, T_to_rpy(T))]


def _enum_name(v: Any) -> str:
    name = getattr(v, "name", None)
    return str(name) if name is not None else str(v).split(".")[-1]


class AuboRobot(Robot):
    """An AUBO arm behind ``pyaubo_sdk.RpcClient``; flange poses in the robot base frame."""

    def __init__(
        self,
        settings: AuboSettings,
        name: str = "aubo",
        gate: SafetyGate | None = None,
        dry_run: bool = False,
        rpc_factory: Callable[[], Any] | None = None,
    ) -> None:
        super().__init__(name, gate=gate, motion=settings, dry_run=dry_run)
        self.settings = settings
        self._rpc_factory = rpc_factory or pyaubo_sdk.RpcClient
        self._rpc: Any = None
        self._ri: Any = None
        self.T_flange_ctrltcp = np.eye(4)
        self.robot_name = ""

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        s = self.settings
        rpc = self._rpc_factory()
        rpc.setRequestTimeout(int(s.request_timeout * 1000))
        code = rpc.connect(s.host, s.port)
        if not rpc.hasConnected():
            raise DeviceError(
                f"cannot connect to the AUBO controller at {s.host}:{s.port} (code {code})",
                "check the address, the network and that the controller is booted",
            )
        password = os.environ.get(s.password_env)
        if password is None:
            log.warning("%s is unset; logging in with the factory default password", s.password_env)
            password = FACTORY_PASSWORD
        self._rpc = rpc
        code = self._call("login", lambda: rpc.login(s.user, password))
        if code != 0 or not rpc.hasLogined():
            raise DeviceError(
                f"AUBO login as {s.user!r} failed (code {code})",
                f"check the user and the password in ${s.password_env}",
            )
        names = list(self._call("getRobotNames", rpc.getRobotNames))
        if not names:
            raise DeviceError("the AUBO controller reports no robot", "check the controller configuration")
        if s.robot_name and s.robot_name not in names:
            raise DeviceError(
                f"no robot {s.robot_name!r} on the controller (it has {names})", "fix robot_name"
            )
        self.robot_name = s.robot_name or names[0]
        self._ri = rpc.getRobotInterface(self.robot_name)
        st = self._ri.getRobotState()
        mode = _enum_name(self._call("getRobotModeType", st.getRobotModeType))
        if mode != "Running":
            raise DeviceError(
                f"the AUBO arm is '{mode}', not 'Running'",
                "power on and release the brakes (AUBOPE / RobotManage.poweron + startup)",
            )
        self._check_safety(st)
        off = self._call("getTcpOffset", self._ri.getRobotConfig().getTcpOffset)
        self.T_flange_ctrltcp = pose_to_T(off)

    def on_deactivate(self) -> None:
        if self._ri is not None:
            try:
                self._ri.getMotionControl().stopLine(self.settings.accel, self.settings.joint_accel)
            except Exception:
                pass

    def on_close(self) -> None:
        rpc, self._rpc, self._ri = self._rpc, None, None
        if rpc is not None:
            for fn in ("logout", "disconnect"):
                try:
                    getattr(rpc, fn)()
                except Exception:
                    pass

    def on_recover(self) -> None:
        if self._ri is not None:
            try:
                safety = _enum_name(self._ri.getRobotState().getSafetyModeType())
                if safety in STOP_SAFETY:
                    code = self._ri.getRobotManage().setUnlockProtectiveStop()
                    if code != 0:
                        raise DeviceError(
                            f"setUnlockProtectiveStop refused (code {code})",
                            "clear the stop cause on the teach pendant",
                        )
            except DeviceError:
                raise
            except Exception:
                pass  # connection lost: reconnecting below is the recovery
        self.on_close()

    # -- helpers ---------------------------------------------------------------------------------
    def _call(self, what: str, fn: Callable[[], Any]) -> Any:
        try:
            return fn()
        except Exception as e:  # pyaubo_sdk.AuboException on timeouts / lost connections
            if self._state in (State.ACTIVE, State.INACTIVE):
                raise self.fault(f"{what}: {type(e).__name__}: {e}") from e
            raise DeviceError(f"AUBO {what} failed: {e}", "check the controller connection") from e

    def _ok(self, what: str, code: Any) -> None:
        if code != 0:
            name = ""
            try:
                name = pyaubo_sdk.errorCode2Str(int(code))
            except Exception:
                pass
            raise self.fault(f"{what} refused by the controller (code {code} {name})".rstrip())

    def _check_safety(self, st: Any) -> str:
        safety = _enum_name(self._call("getSafetyModeType", st.getSafetyModeType))
        if safety in FAULT_SAFETY:
            raise (
                self.fault(f"safety mode {safety}")
                if self._state is State.ACTIVE
                else DeviceError(
                    f"the AUBO is in safety mode {safety}", "clear it on the teach pendant, then recover()"
                )
            )
        return safety

    def _wait(self, what: str) -> None:
        mc, st = self._ri.getMotionControl(), self._ri.getRobotState()
        s = self.settings
        t0 = time.monotonic()
        started = False
        while time.monotonic() - t0 < s.motion_timeout:
            exec_id = self._call("getExecId", mc.getExecId)
            if exec_id != -1:
                started = True
            elif started or time.monotonic() - t0 > 0.25:  # done (or finished before the first poll)
                break
            safety = self._check_safety(st)
            if safety in STOP_SAFETY:
                raise self.fault(f"{what} interrupted: {safety}")
            time.sleep(s.poll_period)
        else:
            self._call("stopLine", lambda: mc.stopLine(s.accel, s.joint_accel))
            raise self.fault(f"{what} did not finish within {s.motion_timeout:.0f} s")
        safety = self._check_safety(st)
        if safety in STOP_SAFETY:
            raise self.fault(f"{what} interrupted: {safety}")

    def _ctrl_pose(self, T_base_flange: np.ndarray) -> list[float]:
        return T_to_pose(np.asarray(T_base_flange, dtype=float) @ self.T_flange_ctrltcp)

    # -- driver ----------------------------------------------------------------------------------
    def _read_state(self) -> tuple[np.ndarray, np.ndarray, dict]:
        st = self._ri.getRobotState()
        q = np.asarray(self._call("getJointPositions", st.getJointPositions), dtype=float)
        pose = self._call("getTcpPose", st.getTcpPose)
        safety = self._check_safety(st)
        steady = bool(self._call("isSteady", st.isSteady))
        T = pose_to_T(pose) @ invert(self.T_flange_ctrltcp)
        return q, T, {"moving": not steady, "protective_stop": safety in STOP_SAFETY}

    def _move_linear(self, T_base_flange: np.ndarray, speed: float, accel: float) -> None:
        mc = self._ri.getMotionControl()
        pose = self._ctrl_pose(T_base_flange)
        self._ok("moveLine", self._call("moveLine", lambda: mc.moveLine(pose, accel, speed, 0.0, 0.0)))
        self._wait("linear move")

    def _move_joint(self, q: np.ndarray, speed: float, accel: float) -> None:
        mc = self._ri.getMotionControl()
        qq = [float(v) for v in q]
        self._ok("moveJoint", self._call("moveJoint", lambda: mc.moveJoint(qq, accel, speed, 0.0, 0.0)))
        self._wait("joint move")

    def _follow_path(self, poses: np.ndarray, speed: float, accel: float, blend: float) -> None:
        mc = self._ri.getMotionControl()
        for i, T in enumerate(poses):
            r = float(blend) if i < len(poses) - 1 else 0.0
            pose = self._ctrl_pose(T)
            self._ok(
                f"moveLine (path point {i})",
                self._call("moveLine", lambda p=pose, r=r: mc.moveLine(p, accel, speed, r, 0.0)),
            )
        self._wait("path")

    def _speed_linear(self, twist: np.ndarray, accel: float, duration: float) -> None:
        tw = np.asarray(twist, dtype=float).reshape(6).copy()
        st = self._ri.getRobotState()
        T_f = pose_to_T(self._call("getTcpPose", st.getTcpPose)) @ invert(self.T_flange_ctrltcp)
        r = T_f[:3, :3] @ self.T_flange_ctrltcp[:3, 3]
        tw[:3] = tw[:3] + np.cross(tw[3:], r)  # the controller's TCP moves with v_F + w x r
        mc = self._ri.getMotionControl()
        self._ok("speedLine", self._call("speedLine", lambda: mc.speedLine(tw.tolist(), accel, duration)))

    def _stop(self, decel: float) -> None:
        if self._ri is None:
            return
        mc = self._ri.getMotionControl()
        self._ok("stopLine", self._call("stopLine", lambda: mc.stopLine(decel, max(decel, 1.0))))


def make_aubo(settings: AuboSettings, ctx: Any) -> AuboRobot:
    """Device factory: the gate uses the cell's limits and the ``settings.model`` kinematics."""
    from weldcell.hal.kinematics import get_model

    gate = SafetyGate(getattr(ctx, "safety", None), model=get_model(settings.model))
    return AuboRobot(
        settings, name=getattr(ctx, "role", "aubo"), gate=gate, dry_run=bool(getattr(ctx, "dry_run", False))
    )


def probe_aubo(settings: AuboSettings, timeout: float = 1.0) -> str:
    """TCP connect to the RPC port, then ask the controller its interface version and robot names."""
    try:
        with socket.create_connection((settings.host, settings.port), timeout=timeout):
            pass
    except OSError as e:
        raise DeviceError(
            f"AUBO RPC at {settings.host}:{settings.port} does not answer ({e})",
            "check the controller address and that ARCS is running",
        ) from e
    rpc = pyaubo_sdk.RpcClient()
    rpc.setRequestTimeout(int(timeout * 1000))
    try:
        rpc.connect(settings.host, settings.port)
        password = os.environ.get(settings.password_env, FACTORY_PASSWORD)
        if rpc.login(settings.user, password) != 0:
            raise DeviceError("AUBO RPC answers but the login failed", f"check ${settings.password_env}")
        names = list(rpc.getRobotNames())
    except DeviceError:
        raise
    except Exception as e:
        raise DeviceError(
            f"AUBO RPC at {settings.host}:{settings.port} did not answer the handshake ({e})",
            "check that this is an ARCS controller (SDK >= 0.24)",
        ) from e
    finally:
        for fn in ("logout", "disconnect"):
            try:
                getattr(rpc, fn)()
            except Exception:
                pass
    return f"AUBO ARCS at {settings.host}:{settings.port}: robots {', '.join(names)}"
