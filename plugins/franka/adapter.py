"""Franka Emika Panda / FR3 through franky (libfranka's FCI), as a weldcell :class:`Robot`.

Frames. franky reports and commands the *end effector* frame EE of libfranka:
``O_T_EE = O_T_F · F_T_EE`` with ``F_T_EE = F_T_NE · NE_T_EE`` (F = flange, NE = the nominal end effector set
in Desk, EE = NE plus :meth:`set_ee`). weldcell's robot API is in the flange frame F, so

* state:    ``T_base_flange = O_T_EE · (F_T_EE)^-1`` (both read from the same ``robot.state`` sample);
* commands: ``CartesianMotion(Affine(T_base_flange · F_T_EE))`` — the target of the configured EE;
* servo:    the flange twist (base frame) is moved to the EE origin, ``v_EE = v_F + ω × (R_OF · p_F_EE)``.

Speeds. franky scales Franka's own limits with a *relative dynamics factor*; a TCP speed ``v`` [m/s] is sent
as ``RelativeDynamicsFactor(v / vmax, a / amax,
                            min(...))`` with the limits from the settings (Panda defaults).
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from typing import Any

import franky
import numpy as np
from weldcell.hal.lifecycle import State
from weldcell.hal.robot import Robot
from weldcell.hal.safety import SafetyGate
from weldcell.sdk.errors import DeviceError, SafetyError
from weldcell.sdk.geometry import invert

from .settings import FrankaSettings

FCI_PORT = 1337  # libfranka's command port on the control unit

_FRANKY_ERRORS = tuple(
    getattr(franky, n)
    for n in (
        "ControlException",
        "CommandException",
        "NetworkException",
        "ProtocolException",
        "RealtimeException",
        "InvalidOperationException",
        "IncompatibleVersionException",
        "Exception",
    )
    if hasattr(franky, n)
)


def _factor(value: float, limit: float) -> float:
    return float(np.clip(value / limit, 1e-3, 1.0))


class FrankaRobot(Robot):
    """A Franka arm behind ``franky.Robot``; flange poses in the robot base frame O."""

    def __init__(
        self,
        settings: FrankaSettings,
        name: str = "franka",
        gate: SafetyGate | None = None,
        dry_run: bool = False,
        robot_factory: Callable[..., Any] | None = None,
    ) -> None:
        super().__init__(name, gate=gate, motion=settings, dry_run=dry_run)
        self.settings = settings
        self._factory = robot_factory or franky.Robot
        self._robot: Any = None
        self.F_T_EE = np.eye(4)

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        if self._robot is None:
            s = self.settings
            try:
                self._robot = self._factory(
                    s.host,
                    relative_dynamics_factor=s.relative_dynamics_factor,
                    default_torque_threshold=s.torque_threshold,
                    default_force_threshold=s.force_threshold,
                )
            except _FRANKY_ERRORS as e:
                raise DeviceError(
                    f"cannot connect to the Franka at {s.host}: {e}",
                    "unlock the joints and activate FCI in Desk; check the host address",
                ) from e
        st = self._robot.state
        if st.robot_mode == franky.RobotMode.Reflex or self._robot.has_errors:
            raise DeviceError(
                f"the Franka is in a reflex/error state ({st.current_errors})",
                "call recover() (runs recover_from_errors) after clearing the cause",
            )
        self.F_T_EE = np.asarray(st.F_T_EE.matrix, dtype=float)

    def on_deactivate(self) -> None:
        if self._robot is not None:
            try:
                self._robot.stop()
            except _FRANKY_ERRORS:
                pass

    def on_close(self) -> None:
        self._robot = None  # franky closes the FCI connection when the Robot is released

    def on_recover(self) -> None:
        if self._robot is None:
            return
        try:
            ok = self._robot.recover_from_errors()
        except _FRANKY_ERRORS as e:
            self._robot = None  # connection lost: reconnect on configure()
            raise DeviceError(f"recover_from_errors failed: {e}", "check the robot and the FCI link") from e
        if not ok:
            raise DeviceError(
                "the Franka refused automatic error recovery",
                "release the user stop / fix the reflex cause, then call recover() again",
            )

    # -- helpers ---------------------------------------------------------------------------------
    def _guard(self, what: str, fn: Callable[[], Any]) -> Any:
        try:
            return fn()
        except _FRANKY_ERRORS as e:
            kind = type(e).__name__
            raise self.fault(f"{what} aborted by the robot ({kind}: {e})") from e

    def _run(self, motion: Any, what: str) -> None:
        r = self._robot

        def go() -> None:
            r.move(motion, asynchronous=True)
            if not r.join_motion(self.settings.motion_timeout):
                r.stop()
                raise DeviceError(f"{what} did not finish within {self.settings.motion_timeout:.0f} s")

        try:
            self._guard(what, go)
        except DeviceError as e:
            if self._state is not State.ERROR:  # (Robot.state() is the robot state reading)
                raise self.fault(e.message) from e
            raise

    def _ee(self, T_base_flange: np.ndarray) -> Any:
        return franky.Affine(np.asarray(T_base_flange, dtype=float) @ self.F_T_EE)

    def _dyn(self, speed: float, accel: float) -> Any:
        v = _factor(speed, self.settings.max_translation_speed)
        a = _factor(accel, self.settings.max_translation_accel)
        return franky.RelativeDynamicsFactor(v, a, min(v, a))

    # -- driver ----------------------------------------------------------------------------------
    def _read_state(self) -> tuple[np.ndarray, np.ndarray, dict]:
        st = self._guard("state read", lambda: self._robot.state)
        mode = st.robot_mode
        if mode == franky.RobotMode.Reflex:
            raise self.fault(f"the robot is in a reflex ({st.current_errors})")
        O_T_EE = np.asarray(st.O_T_EE.matrix, dtype=float)
        self.F_T_EE = np.asarray(st.F_T_EE.matrix, dtype=float)
        T = O_T_EE @ invert(self.F_T_EE)
        extra = {
            "qd": np.asarray(st.dq, dtype=float).ravel(),
            "moving": mode == franky.RobotMode.Move,
            "protective_stop": mode == franky.RobotMode.UserStopped,
        }
        return np.asarray(st.q, dtype=float).ravel(), T, extra

    def _move_linear(self, T_base_flange: np.ndarray, speed: float, accel: float) -> None:
        m = franky.CartesianMotion(
            self._ee(T_base_flange), franky.ReferenceType.Absolute, self._dyn(speed, accel)
        )
        self._run(m, "linear move")

    def _move_joint(self, q: np.ndarray, speed: float, accel: float) -> None:
        v = _factor(speed, self.settings.max_joint_speed)
        a = _factor(accel, self.settings.max_joint_accel)
        m = franky.JointMotion(
            franky.JointState(np.asarray(q, dtype=float)),
            franky.ReferenceType.Absolute,
            franky.RelativeDynamicsFactor(v, a, min(v, a)),
        )
        self._run(m, "joint move")

    def _follow_path(self, poses: np.ndarray, speed: float, accel: float, blend: float) -> None:
        dyn = self._dyn(speed, accel)
        wps = [franky.CartesianWaypoint(self._ee(T), franky.ReferenceType.Absolute, dyn) for T in poses]
        self._run(franky.CartesianWaypointMotion(wps, relative_dynamics_factor=dyn), "path")

    def _speed_linear(self, twist: np.ndarray, accel: float, duration: float) -> None:
        tw = np.asarray(twist, dtype=float).reshape(6)
        st = self._guard("state read", lambda: self._robot.state)
        O_T_EE = np.asarray(st.O_T_EE.matrix, dtype=float)
        r = (
            O_T_EE[:3, :3] @ invert(np.asarray(st.F_T_EE.matrix, dtype=float))[:3, 3]
        )  # EE -> flange, base frame
        v_ee = tw[:3] - np.cross(tw[3:], r)
        m = franky.CartesianVelocityMotion(
            franky.Twist(v_ee, tw[3:]),
            duration=franky.Duration(max(1, int(round(duration * 1000)))),
            relative_dynamics_factor=self._dyn(max(np.linalg.norm(v_ee), 1e-3), accel),
        )
        self._guard("velocity command", lambda: self._robot.move(m, asynchronous=True))

    def _stop(self, decel: float) -> None:
        if self._robot is None:
            return
        try:
            self._robot.stop()
            self._robot.join_motion(1.0)
        except _FRANKY_ERRORS as e:
            raise self.fault(f"stop: {type(e).__name__}: {e}") from e


def make_franka(settings: FrankaSettings, ctx: Any) -> FrankaRobot:
    """Device factory: the gate uses the cell's limits and the ``settings.model`` kinematics."""
    from weldcell.hal.kinematics import get_model

    try:
        model = get_model(settings.model)
    except Exception as e:
        raise SafetyError(
            f"robot.franka: unknown kinematic model {settings.model!r}", "use 'franka-panda'"
        ) from e
    gate = SafetyGate(getattr(ctx, "safety", None), model=model)
    return FrankaRobot(
        settings, name=getattr(ctx, "role", "franka"), gate=gate, dry_run=bool(getattr(ctx, "dry_run", False))
    )


def probe_franka(settings: FrankaSettings, timeout: float = 1.0) -> str:
    """TCP connect to the FCI command port (no motion, no control token taken)."""
    try:
        with socket.create_connection((settings.host, FCI_PORT), timeout=timeout):
            pass
    except OSError as e:
        raise DeviceError(
            f"Franka FCI at {settings.host}:{FCI_PORT} does not answer ({e})",
            "power the control unit, activate FCI in Desk, check the network",
        ) from e
    return f"Franka FCI answers at {settings.host}:{FCI_PORT}"
