"""The robot interface. Every public motion method runs the safety gate before the driver.

Adapters implement ``_read_state``, ``_move_linear``, ``_move_joint``, ``_follow_path``,
``_speed_linear`` and ``_stop`` in terms of **flange** poses in the robot base frame; the public
methods take **TCP** poses (``T_base_tcp``; the TCP is the flange unless a tool offset is set),
convert them, and refuse any command that fails the gate: a refused command never reaches the
driver, and nothing but :class:`~weldcell.sdk.errors.SafetyError` (or a device's own
``DeviceError``) leaves a motion method. The driver gets validated values only: finite rigid 4x4
flange poses, finite positive speeds, accelerations and durations, finite non-negative blends (see
docs/safety.md). In dry-run mode a command that passes the gate is logged in ``dry_run_log`` instead.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import Field
from weldcell.hal.interfaces import INTERFACES
from weldcell.hal.lifecycle import Device
from weldcell.hal.readings import RobotState
from weldcell.hal.safety import SafetyGate, as_number, as_pose
from weldcell.sdk.geometry import T_from_rpy, invert
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Acceleration, Angle, AngularAcceleration, AngularSpeed, Length, Speed

log = logging.getLogger("weldcell.robot")


class RobotMotionSettings(Settings):
    """Motion defaults and the tool offset, shared by every robot adapter's settings."""

    tcp_xyz: tuple[Length, Length, Length] = Field(
        (0.0, 0.0, 0.0), description="TCP offset from the flange [m]"
    )
    tcp_rpy: tuple[Angle, Angle, Angle] = Field(
        (0.0, 0.0, 0.0), description="TCP rotation from the flange [rad]"
    )
    speed: Speed = Field(0.05, gt=0, description="default TCP speed [m/s]")
    accel: Acceleration = Field(0.5, gt=0, description="default TCP acceleration [m/s^2]")
    joint_speed: AngularSpeed = Field(0.5, gt=0, description="default joint speed [rad/s]")
    joint_accel: AngularAcceleration = Field(1.0, gt=0, description="default joint acceleration [rad/s^2]")


@dataclass
class DryRunEntry:
    """A command that passed the gate and would have been sent."""

    stamp: float
    command: str
    args: dict[str, Any] = field(default_factory=dict)


class Robot(Device):
    """A robot arm: state, linear/joint moves, path following, velocity servo, stop."""

    kind = "robot"

    def __init__(
        self,
        name: str = "robot",
        gate: SafetyGate | None = None,
        motion: RobotMotionSettings | None = None,
        dry_run: bool = False,
    ) -> None:
        super().__init__(name, frame=f"{name}.base")
        self.gate = gate or SafetyGate()
        self.motion = motion or RobotMotionSettings()
        self.T_flange_tcp = T_from_rpy(self.motion.tcp_rpy, self.motion.tcp_xyz)
        self.dry_run = dry_run
        self.dry_run_log: list[DryRunEntry] = []

    # -- state -----------------------------------------------------------------------------------
    def state(self) -> RobotState:
        """Joints and flange/TCP poses now."""
        self.require_active()
        q, T_base_flange, extra = self._read_state()
        self.mark_reading()
        return RobotState(
            stamp=time.time(),
            q=np.asarray(q, dtype=float),
            T_base_flange=T_base_flange,
            T_base_tcp=T_base_flange @ self.T_flange_tcp,
            **extra,
        )

    def _flange(self, T_base_tcp: np.ndarray) -> np.ndarray:
        return np.asarray(T_base_tcp, dtype=float) @ invert(self.T_flange_tcp)

    def _send(self, command: str, fn, **args) -> Any:
        if self.dry_run:
            entry = DryRunEntry(time.time(), command, args)
            self.dry_run_log.append(entry)
            log.info(
                "dry run: %s %s",
                command,
                {k: np.round(v, 5).tolist() if isinstance(v, np.ndarray) else v for k, v in args.items()},
            )
            return None
        return fn(**args)

    def program_settings(self) -> dict[str, Any]:
        """What a program exporter needs to write, and gate-check, a program for this robot: the model the
        gate uses (``robot_model``), the tool (``tcp_xyz``, ``tcp_rpy``) and the cell's limits (``safety``).
        Fill an exporter's settings with :func:`weldcell.sdk.settings.with_defaults`."""
        model = getattr(self.gate.model, "name", None)
        return {
            "robot_model": model,
            "tcp_xyz": tuple(self.motion.tcp_xyz),
            "tcp_rpy": tuple(self.motion.tcp_rpy),
            "safety": self.gate.limits,
        }

    # -- motions ---------------------------------------------------------------------------------
    def move_linear(
        self, T_base_tcp: np.ndarray, speed: float | None = None, accel: float | None = None
    ) -> None:
        """Straight-line TCP move to ``T_base_tcp``."""
        self.require_active()
        speed = self.motion.speed if speed is None else speed
        accel = self.motion.accel if accel is None else accel
        st = self.state()
        with self.gate.refusing("linear move"):
            T = as_pose(T_base_tcp, "linear move target")
            speed, accel = self.gate.check_speed(speed, accel)
            self.gate.check_linear(st.T_base_tcp, T, self.T_flange_tcp, speed, accel, st.q, "linear move")
            flange = self._flange(T)
        self._send("move_linear", self._move_linear, T_base_flange=flange, speed=speed, accel=accel)

    def move_joint(self, q: np.ndarray, speed: float | None = None, accel: float | None = None) -> None:
        """Joint-space move to ``q`` (rad)."""
        self.require_active()
        speed = self.motion.joint_speed if speed is None else speed
        accel = self.motion.joint_accel if accel is None else accel
        with self.gate.refusing("joint move"):
            speed, accel = self.gate.check_joint_speed(speed, accel)
            self.gate.check_joints(q, "joint move target")
            q = np.array(q, dtype=float)
        if self.gate.model is not None:
            st = self.state()
            self.gate.check_joint_move(st.q, q, self.T_flange_tcp, speed, accel, "joint move")
        self._send("move_joint", self._move_joint, q=q, speed=speed, accel=accel)

    def follow_path(
        self, poses: np.ndarray, speed: float | None = None, accel: float | None = None, blend: float = 0.0
    ) -> None:
        """Follow TCP poses (K, 4, 4) in order with linear segments (blended by ``blend`` metres: the
        radius at each waypoint is at most 45 % of the shorter neighbouring segment, see
        :func:`~weldcell.hal.safety.path_blends`).

        The whole path is checked, from the current pose, before anything is sent.
        """
        self.require_active()
        speed = self.motion.speed if speed is None else speed
        accel = self.motion.accel if accel is None else accel
        st = self.state()
        with self.gate.refusing("path"):
            speed, accel = self.gate.check_speed(speed, accel)
            blend = as_number(blend, "blend radius", unit="m", positive=False)
            self.gate.check_path(st.T_base_tcp, poses, self.T_flange_tcp, speed, accel, blend, st.q, "path")
            flange = np.stack([self._flange(T) for T in np.asarray(poses, dtype=float)])
        self._send("follow_path", self._follow_path, poses=flange, speed=speed, accel=accel, blend=blend)

    def speed_linear(self, twist: np.ndarray, accel: float | None = None, duration: float = 0.008) -> None:
        """TCP velocity ``[vx, vy, vz, wx, wy, wz]`` (base frame) for ``duration`` seconds (servoing).

        The driver receives the equivalent constant flange twist; the gate checks the motion it makes
        over exactly ``duration`` (see :meth:`~weldcell.hal.safety.SafetyGate.check_servo`).
        """
        self.require_active()
        accel = self.motion.accel if accel is None else accel
        st = self.state()
        with self.gate.refusing("velocity command"):
            accel = as_number(accel, "acceleration", unit="m/s^2", positive=False)
            duration = as_number(duration, "velocity command duration", unit="s")
            tw = self.gate.check_servo(twist, accel, st.T_base_flange, st.q, self.T_flange_tcp, duration)
        self._send("speed_linear", self._speed_linear, twist=tw, accel=accel, duration=duration)

    def stop(self, decel: float | None = None) -> None:
        """Stop any motion (always allowed; never gated)."""
        if self.dry_run:
            self.dry_run_log.append(DryRunEntry(time.time(), "stop", {}))
            return
        self._stop(decel if decel is not None else max(self.motion.accel, 1.0))

    # -- driver side -----------------------------------------------------------------------------
    def _read_state(self) -> tuple[np.ndarray, np.ndarray, dict]:
        """Return (q, T_base_flange, extra RobotState fields)."""
        raise NotImplementedError

    def _move_linear(self, T_base_flange: np.ndarray, speed: float, accel: float) -> None:
        raise NotImplementedError

    def _move_joint(self, q: np.ndarray, speed: float, accel: float) -> None:
        raise NotImplementedError

    def _follow_path(self, poses: np.ndarray, speed: float, accel: float, blend: float) -> None:
        raise NotImplementedError

    def _speed_linear(self, twist: np.ndarray, accel: float, duration: float) -> None:
        raise NotImplementedError

    def _stop(self, decel: float) -> None:
        raise NotImplementedError


INTERFACES["robot"] = Robot
