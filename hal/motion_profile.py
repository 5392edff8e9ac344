"""Rest-to-rest motion profiles and the move durations of a robot model.

:func:`trapezoid_time` / :func:`trapezoid_position` are the trapezoidal (or triangular) profile;
:class:`MotionTimes`, mixed into :class:`weldcell.hal.kinematics.RobotModel`, times synchronized joint
moves and straight TCP moves and turns a straight TCP line into joints by IK.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from weldcell.sdk.errors import SafetyError, UsageError
from weldcell.sdk.geometry import interpolate_poses, rotation_angle


def trapezoid_time(distance: np.ndarray | float, vmax: np.ndarray | float, amax: np.ndarray | float) -> Any:
    """Minimum time to travel ``distance`` from rest to rest with speed ``vmax`` and acceleration ``amax``.

    Triangular profile ``2 sqrt(D / a)`` when the top speed is never reached (``D < v^2 / a``),
    trapezoidal ``D / v + v / a`` otherwise.
    """
    D = np.abs(np.asarray(distance, dtype=float))
    v = np.asarray(vmax, dtype=float)
    a = np.asarray(amax, dtype=float)
    return np.where(D < v * v / a, 2.0 * np.sqrt(D / a), D / v + v / a)


def trapezoid_position(t: np.ndarray, distance: float, vmax: float, amax: float) -> np.ndarray:
    """Distance covered at times ``t`` along the rest-to-rest profile of :func:`trapezoid_time`."""
    t = np.asarray(t, dtype=float)
    D = abs(float(distance))
    if D == 0.0:
        return np.zeros_like(t)
    v = min(vmax, math.sqrt(D * amax))  # peak speed (triangle when the top speed is not reached)
    ta = v / amax
    T = float(trapezoid_time(D, vmax, amax))
    t = np.clip(t, 0.0, T)
    acc = 0.5 * amax * t**2
    cruise = 0.5 * amax * ta**2 + v * (t - ta)
    dec = D - 0.5 * amax * (T - t) ** 2
    return np.where(t < ta, acc, np.where(t > T - ta, dec, cruise))


class MotionTimes:
    """Move durations and straight-line joint paths of :class:`weldcell.hal.kinematics.RobotModel`."""

    if TYPE_CHECKING:  # provided by RobotModel
        name: str
        dof: int
        joint_speed_limits: np.ndarray
        joint_accel_limits: np.ndarray
        max_tcp_speed: float
        max_tcp_rot_speed: float

        def ik(
            self, T_base_flange: Any, q_seed: Any = None, *, tol_pos: float = 1e-5, tol_rot: float = 1e-4
        ) -> np.ndarray: ...
        def _as_q(self, q: Any) -> np.ndarray: ...
        def _check_target(self, T: Any) -> np.ndarray: ...

    def joint_move_time(self, q0: Any, q1: Any, speed_scale: float = 1.0) -> float:
        """Duration (s) of a synchronized joint move (straight line in joint space, rest to rest).

        All joints share one trapezoidal profile ``s(t)`` in [0, 1]; its speed and acceleration are the
        largest that keep every joint within ``speed_scale * v_i`` and ``speed_scale^2 * a_i`` (the leading
        axis decides). Scaling speed by ``speed_scale`` stretches time by ``1 / speed_scale`` exactly.
        """
        dq = np.abs(self._as_q(q1) - self._as_q(q0))
        vs, as_ = self._sync_limits(dq, speed_scale)
        if vs is None:
            return 0.0
        return float(trapezoid_time(1.0, vs, as_))

    def _sync_limits(self, dq: np.ndarray, speed_scale: float) -> tuple[float | None, float]:
        if not (0.0 < speed_scale <= 1.0):
            raise UsageError(
                f"speed_scale must be in (0, 1], got {speed_scale}", "use a fraction of full speed"
            )
        moving = dq > 1e-12
        if not np.any(moving):
            return None, 0.0
        vs = float(np.min(speed_scale * self.joint_speed_limits[moving] / dq[moving]))
        as_ = float(np.min(speed_scale**2 * self.joint_accel_limits[moving] / dq[moving]))
        return vs, as_

    def sample_joint_move(
        self, q0: Any, q1: Any, dt: float = 0.008, speed_scale: float = 1.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Times (K,) and joint positions (K, dof) of :meth:`joint_move_time`'s profile every ``dt`` s."""
        q0a, q1a = self._as_q(q0), self._as_q(q1)
        vs, as_ = self._sync_limits(np.abs(q1a - q0a), speed_scale)
        if vs is None:
            return np.zeros(1), q0a[None].copy()
        T = float(trapezoid_time(1.0, vs, as_))
        t = np.append(np.arange(0.0, T, dt), T)
        s = trapezoid_position(t, 1.0, vs, as_)
        return t, q0a + s[:, None] * (q1a - q0a)

    def linear_move_time(
        self,
        T0: Any,
        T1: Any,
        speed: float,
        accel: float,
        *,
        rot_speed: float | None = None,
        rot_accel: float | None = None,
    ) -> float:
        """Duration (s) of a straight-line TCP move: trapezoids along the path length (``speed`` m/s,
        ``accel`` m/s^2) and the rotation angle (``rot_speed`` rad/s, default ``max_tcp_rot_speed``;
        ``rot_accel`` default with the same ramp time as the translation); the slower one decides.

        Raises :class:`SafetyError` when ``speed`` exceeds ``max_tcp_speed``.
        """
        if speed <= 0 or accel <= 0:
            raise UsageError(
                f"linear move needs speed > 0 and accel > 0, got {speed}, {accel}",
                "give the TCP speed in m/s and acceleration in m/s^2",
            )
        if speed > self.max_tcp_speed + 1e-12:
            raise SafetyError(
                f"{self.name}: TCP speed {speed:.3f} m/s exceeds the limit {self.max_tcp_speed} m/s",
                f"use a speed <= {self.max_tcp_speed} m/s",
            )
        wr = self.max_tcp_rot_speed if rot_speed is None else rot_speed
        if wr > self.max_tcp_rot_speed + 1e-12 or wr <= 0:
            raise SafetyError(
                f"{self.name}: TCP rotation speed {wr:.3f} rad/s outside (0, {self.max_tcp_rot_speed:.3f}]",
                "lower rot_speed",
            )
        ar = rot_accel if rot_accel is not None else accel * wr / speed
        A, B = np.asarray(T0, dtype=float), np.asarray(T1, dtype=float)
        L = float(np.linalg.norm(B[:3, 3] - A[:3, 3]))
        th = rotation_angle(A[:3, :3].T @ B[:3, :3])
        return float(max(trapezoid_time(L, speed, accel), trapezoid_time(th, wr, ar)))

    def linear_path_joints(
        self,
        T0: Any,
        T1: Any,
        q_seed: Any,
        step: float = 0.005,
        *,
        step_rot: float = 0.02,
        max_joint_step: float = 0.3,
    ) -> np.ndarray:
        """Joint trajectory (K, dof) following the straight TCP line T0 -> T1 (slerp orientation) via IK.

        Waypoints every ``step`` m / ``step_rot`` rad; each IK is seeded with the previous solution.
        Raises :class:`SafetyError` naming the fraction of the path where it fails: a waypoint out of
        reach or limits, or a joint jump above ``max_joint_step`` rad (singularity / branch flip).
        """
        A = self._check_target(T0)
        B = self._check_target(T1)
        L = float(np.linalg.norm(B[:3, 3] - A[:3, 3]))
        th = rotation_angle(A[:3, :3].T @ B[:3, :3])
        n = max(1, math.ceil(L / step), math.ceil(th / step_rot))
        s = np.linspace(0.0, 1.0, n + 1)
        poses = interpolate_poses(A, B, s)
        q_prev = self._as_q(q_seed)
        out = np.empty((n + 1, self.dof))
        for i, (si, Ti) in enumerate(zip(s, poses, strict=True)):
            try:
                q = self.ik(Ti, q_prev)
            except SafetyError as err:
                raise SafetyError(
                    f"{self.name}: linear path fails at {100 * si:.0f}% of the way (s={si:.3f}, "
                    f"{si * L:.3f} m from the start): {err.message}",
                    err.fix,
                ) from err
            jump = float(np.max(np.abs(q - q_prev)))
            if i > 0 and jump > max_joint_step:
                j = int(np.argmax(np.abs(q - q_prev)))
                raise SafetyError(
                    f"{self.name}: linear path fails at {100 * si:.0f}% of the way (s={si:.3f}): "
                    f"joint {j + 1} "
                    f"jumps {math.degrees(jump):.1f} deg in one step (singularity or branch flip)",
                    "move in joint space past this region, or change the path or the tool orientation",
                )
            out[i] = q
            q_prev = q
        return out
