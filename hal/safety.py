"""The safety gate every motion command passes before it reaches a robot driver.

Order of work, for every command: (1) validate the inputs (finite numbers, 4x4 rigid transforms, joint
vectors of the right length, positive durations/speeds, blends); (2) check the end points against the
workspace box and reach, so that a target far away is refused in microseconds; (3) check the motion the
driver will execute, conservatively where it can be bounded:

* linear moves and path segments: the TCP moves on a straight line, so box and reach (convex sets) hold
  along it when they hold at its ends; the joints are tracked continuously along the line (Newton steps
  from the previous solution, adaptive steps of at most 0.02 rad per joint), inside their limits, and the
  joint speed implied by the commanded TCP speed stays under the robot's hardware limits and the cell's
  ``max_joint_speed``;
* joint moves: straight lines in joint space; the TCP excursion between two checks is bounded by the
  kinematic chain (``sum |dq_i| * lever_i``) and the motion is subdivided until that bound is inside the
  margin to the box and reach sphere;
* velocity (servo) commands: the constant flange twist the driver receives, integrated in closed form
  over the actual duration (flange origin on a line, orientation ``exp([w] t) R0``), the TCP checked with
  a bound on its speed between checks, joints tracked as for linear moves.

A failed check raises :class:`~weldcell.sdk.errors.SafetyError` saying which limit, by how much, and what
to change; anything unexpected inside the gate is turned into a refusal too (:meth:`SafetyGate.refusing`).
See docs/safety.md for the guarantees and their limits. The inputs' checks are in
:mod:`weldcell.hal.safety_inputs`, the continuous joint tracking in :mod:`weldcell.hal.safety_tracking`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, Protocol

import numpy as np
from weldcell.hal.safety_inputs import (  # noqa: F401 - re-exported: part of the gate's public API
    BLEND_FRACTION,
    ORTHO_TOL,
    ROW_TOL,
    _log_rot,
    _rodrigues,
    as_joints,
    as_number,
    as_pose,
    as_twist,
    path_blends,
    servo_flange_pose,
)
from weldcell.hal.safety_tracking import DQ_STEP, TINY, JointTracking  # noqa: F401 - DQ_STEP re-exported
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import SafetyError, WeldcellError
from weldcell.sdk.geometry import invert

ROT_STEP = 0.02  # rad: the largest TCP rotation between two checks
MAX_CHECKS = 20000  # work bound per motion: refuse (and say so) rather than compute for ever
MAX_PATH_POSES = 100000


class KinematicModel(Protocol):
    """What the gate needs from a robot model (see :mod:`weldcell.hal.kinematics`).

    Optional, used when present: ``jacobian(q)`` or ``fk_jacobian(q)`` (continuous tracking),
    ``joint_speed_limits`` (rad/s), ``max_tcp_rot_speed`` (rad/s), ``joint_lever_bounds()``,
    ``distance_from_shoulder(p)``.
    """

    name: str
    reach: float
    joint_limits: np.ndarray

    def fk(self, q: np.ndarray) -> np.ndarray: ...

    def ik(self, T_base_flange: np.ndarray, q_seed: np.ndarray | None = None) -> np.ndarray: ...


def _fmt(p: np.ndarray) -> str:
    return "[" + ", ".join(f"{v:.3f}" for v in p) + "] m"


class SafetyGate(JointTracking):
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

    @property
    def joint_speed_limits(self) -> np.ndarray | None:
        """Per-joint speed limits (rad/s) for Cartesian motions: the model's hardware limits capped by the
        cell's ``max_joint_speed`` (None without a model)."""
        if self.model is None:
            return None
        n = len(np.asarray(self.model.joint_limits))
        hw = getattr(self.model, "joint_speed_limits", None)
        hw = np.full(n, np.inf) if hw is None else np.asarray(hw, dtype=float)
        return np.minimum(hw, self.limits.max_joint_speed)

    @contextmanager
    def refusing(self, what: str) -> Iterator[None]:
        """Turn anything unexpected raised inside the block into a refusal (the command is not sent)."""
        try:
            with np.errstate(all="ignore"):
                yield
        except SafetyError:
            raise
        except WeldcellError as e:
            raise SafetyError(f"{what} refused: {e.message}", e.fix or "check the command's inputs") from None
        except (ArithmeticError, ValueError, TypeError, IndexError, np.linalg.LinAlgError, MemoryError) as e:
            raise SafetyError(
                f"{what} refused: the safety check could not be completed ({type(e).__name__}: {e})",
                "check the command's inputs; report this if they are valid",
            ) from None

    # -- single checks ---------------------------------------------------------------------------
    def _distance(self, p: np.ndarray) -> tuple[float, str]:
        dist_fn = (
            getattr(self.model, "distance_from_shoulder", None) if self.limits.max_reach is None else None
        )
        if dist_fn is not None:
            return float(dist_fn(p)), "shoulder"
        return float(np.linalg.norm(p)), "base"

    def margin(self, p: np.ndarray) -> float:
        """Distance (m) from ``p`` to the edge of the allowed region (box and reach); < 0 outside."""
        m = float(min(np.min(p - self.lo), np.min(self.hi - p)))
        reach = self.reach
        if reach is not None:
            m = min(m, reach - self._distance(p)[0])
        return m

    def check_point(self, p: np.ndarray, what: str = "target") -> None:
        """The TCP position ``p`` is inside the workspace box and within reach."""
        p = np.asarray(p, dtype=float).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
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
        if reach is not None:
            dist, origin = self._distance(p)
            if dist > reach:
                raise SafetyError(
                    f"{what} {_fmt(p)} is {dist:.3f} m from the robot's {origin}, beyond its reach of "
                    f"{reach:.3f} m",
                    "bring the part closer to the robot or choose a robot with more reach",
                )

    def check_speed(self, speed: Any, accel: Any) -> tuple[float, float]:
        """TCP speed and acceleration: finite, positive, under the cell's caps. Returns them as floats."""
        lim = self.limits
        speed = as_number(speed, "TCP speed", unit="m/s", positive=False)
        accel = as_number(accel, "TCP acceleration", unit="m/s^2", positive=False)
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
        return speed, accel

    def check_joint_speed(self, speed: Any, accel: Any) -> tuple[float, float]:
        """Joint speed and acceleration of a joint move: finite, positive, under the cell's caps."""
        lim = self.limits
        speed = as_number(speed, "joint speed", unit="rad/s", positive=False)
        accel = as_number(accel, "joint acceleration", unit="rad/s^2", positive=False)
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
        return speed, accel

    def check_joints(self, q: np.ndarray, what: str = "target") -> None:
        """Joint positions finite and inside the model's limits."""
        q = as_joints(q, None, what)
        if self.model is None:
            return
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
        T = as_pose(T_base_flange, what)
        with self.refusing(what):
            try:
                q = self.model.ik(T, q_seed)
            except SafetyError as e:
                raise SafetyError(f"{what}: {e.message}", e.fix or "choose a reachable target") from None
        self.check_joints(q, what)
        return np.asarray(q, dtype=float)

    def check_pose(self, T_base_tcp: np.ndarray, T_base_flange: np.ndarray, q_seed=None, what="target"):
        """A single target pose: box, reach and IK. Returns the joint solution (or None)."""
        T = as_pose(T_base_tcp, what)
        self.check_point(T[:3, 3], what)
        return self.solve(T_base_flange, q_seed, what)

    # -- shared machinery ------------------------------------------------------------------------
    def _budget(self, n: int, what: str) -> None:
        if n > MAX_CHECKS:
            raise SafetyError(
                f"{what}: the motion could not be verified within {MAX_CHECKS} checks (it runs very close "
                "to the workspace edge, a singularity, or is very long)",
                "split it into shorter motions, or keep it further from the workspace edge",
            )

    def _sweep(self, pos_at: Callable[[float], np.ndarray], lipschitz: float, label: Callable[[float], str]):
        """Prove a TCP curve ``p(s)``, ``s`` in [0, 1], stays in the box and reach: ``|dp/ds| <= lipschitz``,
        so between two checks a and b it stays inside when ``lipschitz * (b - a) <= margin_a + margin_b``;
        subdivide until it does. A check outside raises at that point."""
        s, p = 0.0, pos_at(0.0)
        self.check_point(p, label(0.0))
        m_a, h, n = self.margin(p), 1.0, 0
        while s < 1.0:
            n += 1
            self._budget(n, label(s))
            h = min(h, 1.0 - s)
            b = 1.0 if s + h >= 1.0 - 1e-15 else s + h
            p = pos_at(b)
            self.check_point(p, label(b))
            m_b = self.margin(p)
            if lipschitz * h > m_a + m_b and lipschitz * h > TINY:
                h /= 2.0
                continue
            s, m_a, h = b, m_b, 2.0 * h

    # -- whole motions ---------------------------------------------------------------------------
    def check_linear(self, T0_tcp, T1_tcp, T_flange_tcp, speed, accel, q_seed=None, what="linear move"):
        """A straight TCP line from ``T0`` to ``T1`` (slerped orientation) at ``speed``.

        Inputs validated; both ends inside the box and reach (convex, so the whole line is); with a model,
        the joints tracked continuously along the line inside their limits and under the joint speed
        limits at the commanded TCP speed. Returns the final joints (None without a model).
        """
        with self.refusing(what):
            speed, accel = self.check_speed(speed, accel)
            T0 = as_pose(T0_tcp, f"{what} start")
            T1 = as_pose(T1_tcp, f"{what} target")
            T_ft = as_pose(T_flange_tcp, "tool offset (T_flange_tcp)")
            p0, p1 = T0[:3, 3], T1[:3, 3]
            self.check_point(p0, f"{what} start (the current TCP)")
            self._check_line_ends(p0, p1, what)
            if self.model is None:
                return None
            n_joints = len(np.asarray(self.model.joint_limits))
            q = as_joints(q_seed, n_joints, f"{what} start joints") if q_seed is not None else None
            inv_ft = invert(T_ft)
            if q is None:
                q = self.solve(T0 @ inv_ft, None, f"{what} at 0% of the path")
            dist = float(np.linalg.norm(p1 - p0))
            rv = _log_rot(T0[:3, :3].T @ T1[:3, :3])
            ang = float(np.linalg.norm(rv))
            self._check_flange_line(T0, T1, T_ft, ang, what)
            if dist < 1e-12 and ang < 1e-12:
                self.check_joints(q, f"{what} start joints")
                return q
            w_max = float(getattr(self.model, "max_tcp_rot_speed", self.limits.max_angular_speed))
            sdot = min(speed / dist if dist > 1e-12 else math.inf, w_max / ang if ang > 1e-12 else math.inf)
            h0 = min(1.0, self.limits.path_check_step / max(dist, 1e-12), ROT_STEP / max(ang, 1e-12))

            def flange_at(s: float) -> np.ndarray:
                T = np.eye(4)
                T[:3, :3] = T0[:3, :3] @ _rodrigues(rv, s)
                T[:3, 3] = (1.0 - s) * p0 + s * p1
                return T @ inv_ft

            w_unit = T0[:3, :3] @ rv  # angular velocity per unit s (constant for a slerp)

            def twist_at(s: float, F: np.ndarray) -> np.ndarray:
                p_tcp = (1.0 - s) * p0 + s * p1
                return np.concatenate([p1 - p0 + np.cross(w_unit, F[:3, 3] - p_tcp), w_unit])

            def label(s: float) -> str:
                return f"{what} at {100.0 * s:.0f}% of the path"

            return self._track(flange_at, twist_at, q, h0, sdot, dist + 0.1 * ang, label)

    def _check_flange_line(self, T0: np.ndarray, T1: np.ndarray, T_ft: np.ndarray, ang: float, what: str):
        """A controller that interpolates the flange (what the driver receives) instead of the TCP moves
        the TCP off the straight TCP line by at most ``|r| (1 - cos(ang / 2))`` (``r`` the tool offset):
        when both ends keep that margin the whole line does (margins are concave), else sweep that curve."""
        r = float(np.linalg.norm(T_ft[:3, 3]))
        dev = r * (1.0 - math.cos(ang / 2.0))
        if dev <= 0.0 or min(self.margin(T0[:3, 3]), self.margin(T1[:3, 3])) >= dev:
            return
        inv_ft = invert(T_ft)
        F0, F1 = T0 @ inv_ft, T1 @ inv_ft
        rv = _log_rot(F0[:3, :3].T @ F1[:3, :3])
        r_f = T_ft[:3, 3]

        def pos_at(s: float) -> np.ndarray:
            return (1.0 - s) * F0[:3, 3] + s * F1[:3, 3] + F0[:3, :3] @ _rodrigues(rv, s) @ r_f

        lip = float(np.linalg.norm(F1[:3, 3] - F0[:3, 3])) + ang * r
        self._sweep(pos_at, lip, lambda s: f"{what} at {100.0 * s:.0f}% of the path (tool swinging round)")

    def _exit_fraction(self, p0: np.ndarray, d: np.ndarray) -> float:
        """Fraction of the segment ``p0 + s d`` (``p0`` inside) where it leaves the box or reach ball."""
        s_exit = 1.0
        for i in range(3):
            if d[i] > 0:
                s_exit = min(s_exit, (self.hi[i] - p0[i]) / d[i])
            elif d[i] < 0:
                s_exit = min(s_exit, (self.lo[i] - p0[i]) / d[i])
        reach = self.reach
        if reach is not None:
            centre = np.zeros(3)
            if self.limits.max_reach is None and hasattr(self.model, "distance_from_shoulder"):
                centre = np.asarray(getattr(self.model, "shoulder", centre), dtype=float)
            f = p0 - centre
            a, b, c = float(d @ d), 2.0 * float(f @ d), float(f @ f) - reach * reach
            disc = b * b - 4.0 * a * c
            if a > 0 and disc >= 0:
                s_exit = min(s_exit, (-b + math.sqrt(disc)) / (2.0 * a))
        return max(0.0, s_exit)

    def _check_line_ends(self, p0: np.ndarray, p1: np.ndarray, what: str) -> None:
        """The target of a straight line; when it is outside, name where the line leaves (first check
        point beyond the edge, at ``path_check_step`` spacing)."""
        if self.margin(p1) >= 0:
            self.check_point(p1, f"{what} target")
            return
        d = p1 - p0
        lo_s = self._exit_fraction(p0, d)
        dist = float(np.linalg.norm(d))
        n = max(1, math.ceil(dist / self.limits.path_check_step)) if dist < 1e6 else 1
        for s in (math.ceil(lo_s * n + 1e-12) / n, 1.0):
            s = min(1.0, max(s, lo_s))
            self.check_point(p0 + s * d, f"{what} at {100.0 * s:.0f}% of the path")
        self.check_point(p1, f"{what} target")

    def check_joint_move(self, q0, q1, T_flange_tcp, speed, accel, what="joint move") -> np.ndarray:
        """A straight joint-space move ``q0 -> q1``: caps, limits, and the TCP provably inside the box and
        reach all along (chain bound between checks). Returns ``q1`` validated."""
        with self.refusing(what):
            speed, _ = self.check_joint_speed(speed, accel)
            hw = None if self.model is None else getattr(self.model, "joint_speed_limits", None)
            if hw is not None and speed > float(np.min(hw)):
                raise SafetyError(
                    f"joint speed {speed:.4g} rad/s is over the {self.model.name}'s slowest joint's hardware "
                    f"limit of {float(np.min(hw)):.4g} rad/s (the leading joint may be any joint)",
                    "lower the joint speed",
                )
            n = None if self.model is None else len(np.asarray(self.model.joint_limits))
            q1 = as_joints(q1, n, f"{what} target")
            self.check_joints(q1, f"{what} target")
            if self.model is None:
                return q1
            q0 = as_joints(q0, n, f"{what} start joints")
            T_ft = as_pose(T_flange_tcp, "tool offset (T_flange_tcp)")
            r = float(np.linalg.norm(T_ft[:3, 3]))
            lever_fn = getattr(self.model, "joint_lever_bounds", None)
            if lever_fn is not None:
                lever = np.asarray(lever_fn(), dtype=float) + r
            else:  # no chain bound: the model's reach bound for every joint (conservative)
                lever = np.full(n, float(getattr(self.model, "max_reach_bound", 2.0 * self.model.reach)) + r)
            dq = q1 - q0
            L = float(np.sum(np.abs(dq) * lever))
            self._sweep(
                lambda s: (self.model.fk(q0 + s * dq) @ T_ft)[:3, 3],
                L,
                lambda s: f"{what} at {100.0 * s:.0f}% of the motion",
            )
            return q1

    def check_path(self, T_start_tcp, poses, T_flange_tcp, speed, accel, blend, q_seed=None, what="path"):
        """A path of straight segments through ``poses`` (K, 4, 4) from the current TCP pose, blended by
        ``blend`` m (finite, >= 0; clipped per waypoint by :func:`path_blends`). Returns the final joints."""
        with self.refusing(what):
            try:
                P = np.array(poses, dtype=float)
            except (TypeError, ValueError, OverflowError):
                P = None
            if (P is None or P.ndim != 3) and isinstance(poses, list | tuple):
                for i, T in enumerate(poses):  # name the pose that is wrong
                    as_pose(T, f"{what} pose {i}")
            if P is None:
                raise SafetyError(f"{what} is not an array of 4x4 poses", "pass a (K, 4, 4) array")
            if P.ndim != 3 or P.shape[1:] != (4, 4) or not 0 < len(P) <= MAX_PATH_POSES:
                raise SafetyError(
                    f"{what} must be (K, 4, 4) TCP poses with 1 <= K <= {MAX_PATH_POSES}, got {P.shape}",
                    "pass a stack of 4x4 poses",
                )
            blend = as_number(blend, "blend radius", unit="m", positive=False)
            self.check_speed(speed, accel)
            for i, T in enumerate(P):
                as_pose(T, f"{what} pose {i}")
            for i, T in enumerate(P):
                self.check_point(T[:3, 3], f"{what} pose {i}")  # every waypoint first: cheap, bounds the work
            T_prev, q = T_start_tcp, q_seed
            for i, T in enumerate(P):
                q = self.check_linear(T_prev, T, T_flange_tcp, speed, accel, q, f"{what} segment {i}")
                T_prev = T
            return q

    def check_twist(self, twist: np.ndarray, accel: float, T_base_tcp: np.ndarray, horizon: float) -> None:
        """Quick check of a TCP velocity command ``[vx, vy, vz, wx, wy, wz]`` (for servo loops): inputs,
        caps, and the TCP moving at ``v`` for ``horizon`` s inside the box. ``Robot.speed_linear`` checks the
        full motion (:meth:`check_servo`)."""
        with self.refusing("velocity command"):
            tw = self._twist_caps(twist, accel)
            horizon = as_number(horizon, "velocity command duration", unit="s")
            p = as_pose(T_base_tcp, "current TCP pose")[:3, 3]
            self.check_point(p + tw[:3] * horizon, f"velocity command (TCP after {horizon:.3g} s)")

    def _twist_caps(self, twist: Any, accel: Any) -> np.ndarray:
        tw = as_twist(twist)
        accel = as_number(accel, "acceleration", unit="m/s^2", positive=False)
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
        return tw

    def _servo_tcp_speed(self, ftw: np.ndarray, r: np.ndarray, duration: float) -> None:
        """The TCP speed ``|v + w x r(t)|`` stays under the cap while the tool offset ``r`` turns (it is the
        commanded speed only at t = 0). Sampled over the swept angle with the sampling error added."""
        v, w = ftw[:3], ftw[3:]
        wn = float(np.linalg.norm(w))
        k = w / wn
        swept = min(wn * duration, 2.0 * math.pi)
        n = 2000
        phi = np.linspace(0.0, swept, n + 1)
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        rs = r[None] + np.sin(phi)[:, None] * (K @ r)[None] + (1.0 - np.cos(phi))[:, None] * (K @ K @ r)[None]
        speeds = np.linalg.norm(v[None] + np.cross(w[None], rs), axis=1)
        c = wn * float(np.linalg.norm(np.cross(k, r)))  # |d speed / d phi| <= c
        peak = float(speeds.max()) + c * swept / n / 2.0
        if peak > self.limits.max_linear_speed:
            raise SafetyError(
                f"velocity command: the TCP would reach {peak:.4g} m/s while the tool turns (cap "
                f"{self.limits.max_linear_speed:.4g} m/s): the command fixes the flange's twist, so the tool "
                "offset swings round",
                "shorten the command's duration (re-send it every cycle), or lower the angular velocity",
            )

    def check_servo(self, twist, accel, T_base_flange, q, T_flange_tcp, duration) -> np.ndarray:
        """A TCP twist ``[v, w]`` (base frame, ``v`` the TCP's velocity now) held for ``duration`` s.

        The driver receives the equivalent constant **flange** twist ``[v - w x r, w]`` (returned): its
        origin moves on a line while the orientation turns, so the TCP sweeps a curve. That curve is
        checked over the actual duration: the TCP provably inside box and reach (speed bound between
        checks), joints tracked inside their limits and under their speed limits.
        """
        with self.refusing("velocity command"):
            tw = self._twist_caps(twist, accel)
            duration = as_number(duration, "velocity command duration", unit="s")
            F0 = as_pose(T_base_flange, "current flange pose")
            T_ft = as_pose(T_flange_tcp, "tool offset (T_flange_tcp)")
            r = F0[:3, :3] @ T_ft[:3, 3]
            ftw = tw.copy()
            ftw[:3] = tw[:3] - np.cross(tw[3:], r)  # the TCP's twist expressed at the flange
            v, w = float(np.linalg.norm(ftw[:3])), float(np.linalg.norm(ftw[3:]))
            tcp_speed = v + w * float(np.linalg.norm(r))  # bound on the TCP speed along the whole motion
            if tcp_speed > self.limits.max_linear_speed:
                self._servo_tcp_speed(ftw, r, duration)

            def label(s: float) -> str:
                return f"velocity command (TCP after {s * duration:.3g} s of {duration:.3g} s)"

            self._sweep(
                lambda s: (servo_flange_pose(F0, ftw, s * duration) @ T_ft)[:3, 3],
                tcp_speed * duration,
                label,
            )
            if self.model is not None and (v > 0 or w > 0):
                n = len(np.asarray(self.model.joint_limits))
                q = as_joints(q, n, "current joints")
                h0 = min(
                    1.0,
                    self.limits.path_check_step / max(tcp_speed * duration, 1e-12),
                    ROT_STEP / max(w * duration, 1e-12),
                )
                self._track(
                    lambda s: servo_flange_pose(F0, ftw, s * duration),
                    lambda s, F: ftw * duration,
                    q,
                    h0,
                    1.0 / duration,
                    tcp_speed * duration + 0.1 * w * duration,
                    label,
                )
            return ftw
