"""The safety gate every motion command passes before it reaches a robot driver.

It checks, in the robot base frame: the TCP stays inside the cell's workspace box along the whole
motion; the target is within reach and has an inverse-kinematics solution inside the joint limits
(when the robot's kinematic model is known); a linear motion has no unreachable stretch or branch
flip; speeds and accelerations stay under the profile's caps. A failed check raises
:class:`~weldcell.sdk.errors.SafetyError` saying which limit, by how much, and what to change.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import SafetyError
from weldcell.sdk.geometry import interpolate_poses, rotation_angle


class KinematicModel(Protocol):
    """What the gate needs from a robot model (see :mod:`weldcell.hal.sim.kinematics`)."""

    name: str
    reach: float
    joint_limits: np.ndarray

    def fk(self, q: np.ndarray) -> np.ndarray: ...

    def ik(self, T_base_flange: np.ndarray, q_seed: np.ndarray | None = None) -> np.ndarray: ...


def _fmt(p: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.3f}" for v in p) + "] m"


class SafetyGate:
    """Checks motions against :class:`SafetyLimits` and, when given, a kinematic model."""

    def __init__(self, limits: SafetyLimits | None = None, model: KinematicModel | None = None) -> None:
        self.limits = limits or SafetyLimits()
        self.model = model
        self.lo = np.asarray(self.limits.workspace_min, dtype=float)
        self.hi = np.asarray(self.limits.workspace_max, dtype=float)

    @property
    def reach(self) -> float | None:
        if self.limits.max_reach is not None:
            return self.limits.max_reach
        return None if self.model is None else float(self.model.reach)

    # -- single checks ---------------------------------------------------------------------------
    def check_point(self, p: np.ndarray, what: str = "target") -> None:
        """The TCP position ``p`` is inside the workspace box and within reach."""
        p = np.asarray(p, dtype=float)
        if not np.all(np.isfinite(p)):
            raise SafetyError(f"{what} has a NaN or infinite coordinate", "check the command's source data")
        below, above = p < self.lo, p > self.hi
        if below.any() or above.any():
            axis = "xyz"[int(np.argmax(below | above))]
            raise SafetyError(
                f"{what} {_fmt(p)} is outside the cell's workspace box (axis {axis}; box "
                f"{_fmt(self.lo)} .. {_fmt(self.hi)})",
                "move the part or target inside the box, or widen [cell.safety] workspace_min/max if the "
                "cell really allows it",
            )
        reach = self.reach
        dist_fn = (
            getattr(self.model, "distance_from_shoulder", None) if self.limits.max_reach is None else None
        )
        dist = float(dist_fn(p)) if dist_fn is not None else float(np.linalg.norm(p))
        if reach is not None and dist > reach:
            origin = "shoulder" if dist_fn is not None else "base"
            raise SafetyError(
                f"{what} {_fmt(p)} is {dist:.3f} m from the robot's {origin}, beyond its reach of "
                f"{reach:.3f} m",
                "bring the part closer to the robot or choose a robot with more reach",
            )

    def check_speed(self, speed: float, accel: float) -> None:
        lim = self.limits
        if not (0 < speed <= lim.max_linear_speed):
            raise SafetyError(
                f"TCP speed {speed:.4g} m/s is not within (0, {lim.max_linear_speed:.4g}] m/s "
                "(the cell's cap)",
                "lower the speed, or raise [cell.safety] max_linear_speed if the process allows it",
            )
        if not (0 < accel <= lim.max_linear_accel):
            raise SafetyError(
                f"TCP acceleration {accel:.4g} m/s^2 is not within (0, {lim.max_linear_accel:.4g}] m/s^2",
                "lower the acceleration, or raise [cell.safety] max_linear_accel",
            )

    def check_joint_speed(self, speed: float, accel: float) -> None:
        lim = self.limits
        if not (0 < speed <= lim.max_joint_speed):
            raise SafetyError(
                f"joint speed {speed:.4g} rad/s is not within (0, {lim.max_joint_speed:.4g}] rad/s",
                "lower the speed, or raise [cell.safety] max_joint_speed",
            )
        if not (0 < accel <= lim.max_joint_accel):
            raise SafetyError(
                f"joint acceleration {accel:.4g} rad/s^2 is not within "
                f"(0, {lim.max_joint_accel:.4g}] rad/s^2",
                "lower the acceleration, or raise [cell.safety] max_joint_accel",
            )

    def check_joints(self, q: np.ndarray, what: str = "target") -> None:
        """Joint positions inside the model's limits."""
        if self.model is None:
            return
        q = np.asarray(q, dtype=float)
        lim = np.asarray(self.model.joint_limits, dtype=float)
        if q.shape != (len(lim),):
            raise SafetyError(
                f"{what} has {q.size} joint values; the {self.model.name} has {len(lim)} joints",
                "give one value per joint, in radians",
            )
        bad = np.nonzero((q < lim[:, 0] - 1e-9) | (q > lim[:, 1] + 1e-9))[0]
        if len(bad):
            j = int(bad[0])
            raise SafetyError(
                f"{what} joint {j + 1} = {np.degrees(q[j]):.1f} deg is outside its limits "
                f"[{np.degrees(lim[j, 0]):.1f}, {np.degrees(lim[j, 1]):.1f}] deg",
                "choose another configuration or target",
            )

    def solve(
        self, T_base_flange: np.ndarray, q_seed: np.ndarray | None, what: str = "target"
    ) -> np.ndarray | None:
        """IK within limits (None when there is no model). SafetyError when there is no solution."""
        if self.model is None:
            return None
        try:
            q = self.model.ik(T_base_flange, q_seed)
        except SafetyError as e:
            raise SafetyError(f"{what}: {e.message}", e.fix or "choose a reachable target") from None
        self.check_joints(q, what)
        return q

    # -- whole motions ---------------------------------------------------------------------------
    def check_pose(self, T_base_tcp: np.ndarray, T_base_flange: np.ndarray, q_seed=None, what="target"):
        """A single target pose: box, reach and IK. Returns the joint solution (or None)."""
        T = np.asarray(T_base_tcp, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise SafetyError(f"{what} is not a finite 4x4 transform", "pass T_base_tcp as a 4x4 matrix")
        self.check_point(T[:3, 3], what)
        return self.solve(T_base_flange, q_seed, what)

    def check_linear(self, T0_tcp, T1_tcp, T_flange_tcp, speed, accel, q_seed=None, what="linear move"):
        """A straight TCP line from ``T0`` to ``T1``: every ``path_check_step`` inside the box with a
        continuous IK solution (no joint jump over 0.35 rad between checks). Returns the final joints."""
        self.check_speed(speed, accel)
        T0, T1 = np.asarray(T0_tcp, dtype=float), np.asarray(T1_tcp, dtype=float)
        dist = float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]))
        ang = rotation_angle(T0[:3, :3].T @ T1[:3, :3])
        n = max(2, int(np.ceil(max(dist / self.limits.path_check_step, ang / 0.02))) + 1)
        inv_tcp = np.linalg.inv(T_flange_tcp)
        q = q_seed
        for i, T in enumerate(interpolate_poses(T0, T1, np.linspace(0.0, 1.0, n))):
            where = f"{what} at {100.0 * i / (n - 1):.0f}% of the path"
            self.check_point(T[:3, 3], where)
            if i == 0 and q_seed is not None:
                continue  # the start is the robot's current pose, whose joints are q_seed
            q_new = self.solve(T @ inv_tcp, q, where)
            if q is not None and q_new is not None and np.max(np.abs(q_new - q)) > 0.35:
                raise SafetyError(
                    f"{where}: the joints would jump by {np.degrees(np.max(np.abs(q_new - q))):.0f} deg "
                    "(near a singularity or a change of arm configuration)",
                    "split the motion with a joint move, or change the approach orientation",
                )
            q = q_new
        return q

    def check_twist(self, twist: np.ndarray, accel: float, T_base_tcp: np.ndarray, horizon: float) -> None:
        """A TCP velocity command ``[vx, vy, vz, wx, wy, wz]`` held for ``horizon`` seconds."""
        tw = np.asarray(twist, dtype=float).reshape(6)
        if not np.all(np.isfinite(tw)):
            raise SafetyError("velocity command has NaN or infinite values", "check the servo's inputs")
        v, w = float(np.linalg.norm(tw[:3])), float(np.linalg.norm(tw[3:]))
        if v > self.limits.max_linear_speed:
            raise SafetyError(
                f"velocity command {v:.4g} m/s exceeds the cap {self.limits.max_linear_speed:.4g} m/s",
                "lower the servo gain or raise [cell.safety] max_linear_speed",
            )
        if w > self.limits.max_angular_speed:
            raise SafetyError(
                f"angular velocity command {w:.4g} rad/s exceeds the cap "
                f"{self.limits.max_angular_speed:.4g} rad/s",
                "lower the servo gain or raise [cell.safety] max_angular_speed",
            )
        if not (0 < accel <= self.limits.max_linear_accel):
            raise SafetyError(
                f"acceleration {accel:.4g} m/s^2 is not within (0, {self.limits.max_linear_accel}]",
                "lower the acceleration",
            )
        p_next = np.asarray(T_base_tcp)[:3, 3] + tw[:3] * horizon
        self.check_point(p_next, f"velocity command (TCP after {horizon:.3g} s)")
