"""Kinematic models of the robot arms weldcell knows: FK, Jacobian, IK, limits and motion times.

Real robots' safety gates (:mod:`weldcell.hal.safety`) and the simulated cell use the same models.

Models are built from the published parameter tables in :mod:`weldcell.hal.robot_models`
(UR5, UR10e, Franka Emika Panda, AUBO i5, ABB IRB 2600-12/1.65).

Inverse kinematics
------------------
Every chain is first rewritten in product-of-exponentials form, ``T(q) = e^[xi_1] q_1 ... e^[xi_n] q_n M``
(Lynch & Park, *Modern Robotics*, eq. 4.14), with joint axes ``h_i`` through points ``p_i`` taken from the DH
frames at ``q = 0``. Closed forms then come from the Paden-Kahan subproblems (Murray, Li & Sastry 1994,
sec. 3.2.2; generalised as in Elias & Wen, "IK-Geo", 2022):

* SP1: the angle that rotates ``p`` onto ``q`` about ``k``;
* SP3 (written as SP4 on the law of cosines): ``|a + rot(k, t) b| = |y|``;
* SP4: ``h^T rot(k, t) p = d`` (two roots).

Two geometry families are solved in closed form with up to 8 solutions:

* ``three-parallel`` (UR5, UR10e, AUBO i5): axes 2, 3, 4 parallel, axes 5 and 6 intersecting;
* ``spherical-wrist`` (ABB IRB 2600): axes 2, 3 parallel, axes 4, 5, 6 meeting at the wrist centre.

The family is detected from the geometry, not assumed from the name. Anything else (the 7-DOF Panda)
is solved numerically by damped least squares (Levenberg-Marquardt damping as in Sugihara 2011) from
several seeds, with the null space pulled toward ``home``.

Where the code is: the chain, FK, Jacobian, limits, IK dispatch and the model registry here; the closed
forms in :mod:`weldcell.hal.ik_closed_form`; the numeric solver in :mod:`weldcell.hal.ik_numeric`; move
durations and straight-line joint paths in :mod:`weldcell.hal.motion_profile`.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from weldcell.hal.ik_closed_form import (
    Screws,
    classify_chain,
    closest_on_first,
    solve_spherical_wrist,
    solve_three_parallel,
    wrap_angle,
)
from weldcell.hal.ik_numeric import NumericIK
from weldcell.hal.ik_numeric import pose_residual as _pose_residual
from weldcell.hal.motion_profile import MotionTimes, trapezoid_position, trapezoid_time
from weldcell.hal.robot_models import ROBOT_TABLES
from weldcell.sdk.errors import DataError, SafetyError, UsageError

_TWO_PI = 2.0 * math.pi

__all__ = [
    "MODELS",
    "DHTable",
    "RobotModel",
    "build_model",
    "get_model",
    "trapezoid_position",
    "trapezoid_time",
]


# --------------------------------------------------------------------------------------------------- DH chain
@dataclass(frozen=True, eq=False)
class DHTable:
    """A DH chain. Rows are ``(a, alpha, d, offset)``; see :mod:`robot_models` for the two conventions.

    ``flange`` is the fixed transform from the last DH frame to the tool flange.
    """

    convention: str
    a: np.ndarray
    alpha: np.ndarray
    d: np.ndarray
    offset: np.ndarray
    flange: np.ndarray

    @classmethod
    def from_rows(
        cls, convention: str, rows: Sequence[Sequence[float]], flange: np.ndarray | None = None
    ) -> DHTable:
        if convention not in ("standard", "modified"):
            raise DataError(f"unknown DH convention {convention!r}", "use 'standard' or 'modified'")
        r = np.asarray(rows, dtype=float)
        return cls(convention, r[:, 0], r[:, 1], r[:, 2], r[:, 3], np.eye(4) if flange is None else flange)

    def fixed_parts(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-joint constant transforms ``pre`` and ``post`` with ``A_i = pre_i Rz(theta_i) post_i``."""
        n = len(self.a)
        pre = np.tile(np.eye(4), (n, 1, 1))
        post = np.tile(np.eye(4), (n, 1, 1))
        for i in range(n):
            tx, rx = _trans_x(self.a[i]), _rot_x(self.alpha[i])
            if self.convention == "standard":
                post[i] = _trans_z(self.d[i]) @ tx @ rx
            else:
                pre[i] = rx @ tx
                post[i] = _trans_z(self.d[i])
        return pre, post


def _rot_x(t: float) -> np.ndarray:
    c, s = math.cos(t), math.sin(t)
    return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])


def _trans_x(a: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = a
    return T


def _trans_z(d: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = d
    return T


def _rot_z_batch(theta: np.ndarray) -> np.ndarray:
    """(N,) angles -> (N, 4, 4) rotations about z."""
    c, s = np.cos(theta), np.sin(theta)
    out = np.zeros((len(theta), 4, 4))
    out[:, 0, 0] = c
    out[:, 0, 1] = -s
    out[:, 1, 0] = s
    out[:, 1, 1] = c
    out[:, 2, 2] = 1.0
    out[:, 3, 3] = 1.0
    return out


# --------------------------------------------------------------------------------------------- the model
@dataclass(frozen=True, eq=False)
class RobotModel(NumericIK, MotionTimes):
    """Kinematic model of one robot arm (SI units, base frame at the mounting flange of the base).

    ``joint_limits`` (dof, 2) rad, ``joint_speed_limits`` (dof,) rad/s, ``joint_accel_limits`` (dof,) rad/s^2,
    ``max_tcp_speed`` m/s, ``max_tcp_rot_speed`` rad/s, ``reach`` m (published, measured from the shoulder),
    ``payload`` kg, ``home`` (dof,) rad: a ready configuration with the flange pointing down at a table
    in front of the robot.
    """

    name: str
    dof: int
    dh: DHTable
    joint_limits: np.ndarray
    joint_speed_limits: np.ndarray
    joint_accel_limits: np.ndarray
    max_tcp_speed: float
    reach: float
    payload: float
    home: np.ndarray
    max_tcp_rot_speed: float = math.pi
    aliases: tuple[str, ...] = ()
    sources: str = ""
    _pre: np.ndarray = field(init=False, repr=False)
    _post: np.ndarray = field(init=False, repr=False)
    _screws: Screws = field(init=False, repr=False)
    ik_method: str = field(init=False)
    _ik_point: np.ndarray | None = field(init=False, repr=False)
    shoulder: np.ndarray = field(init=False, repr=False)
    max_reach_bound: float = field(init=False)

    def __post_init__(self) -> None:
        for key in ("joint_limits", "joint_speed_limits", "joint_accel_limits", "home"):
            arr = np.asarray(getattr(self, key), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, key, arr)
        if len(self.dh.a) != self.dof or self.joint_limits.shape != (self.dof, 2):
            raise DataError(f"robot model {self.name!r}: DH table / limits do not match dof={self.dof}")
        pre, post = self.dh.fixed_parts()
        object.__setattr__(self, "_pre", pre)
        object.__setattr__(self, "_post", post)
        frames, axes_frames = self._chain(np.zeros((1, self.dof)))
        screws = Screws(
            axes_frames[0, :, :3, 2].copy(), axes_frames[0, :, :3, 3].copy(), frames[0, -1].copy()
        )
        object.__setattr__(self, "_screws", screws)
        method, extra = classify_chain(screws)
        object.__setattr__(self, "ik_method", method)
        object.__setattr__(self, "_ik_point", extra.get("O5", extra.get("W")))
        shoulder = closest_on_first(screws.p[0], screws.h[0], screws.p[1], screws.h[1])
        object.__setattr__(self, "shoulder", shoulder)
        # Triangle inequality along the chain of frame origins (each consecutive pair is rigidly linked):
        # no flange position can be farther from the shoulder than this.
        o = frames[0, 1:, :3, 3]
        bound = float(np.linalg.norm(o[0] - shoulder) + np.sum(np.linalg.norm(np.diff(o, axis=0), axis=1)))
        object.__setattr__(self, "max_reach_bound", bound)
        if not self.within_limits(self.home):
            raise DataError(f"robot model {self.name!r}: home configuration is outside the joint limits")

    # ------------------------------------------------------------------ forward kinematics
    def _as_q(self, q: Any) -> np.ndarray:
        Q = np.asarray(q, dtype=float)
        if Q.shape[-1:] != (self.dof,) or Q.ndim > 2:
            raise UsageError(
                f"{self.name}: joint vector has shape {Q.shape}, expected ({self.dof},) or (N, {self.dof})",
                f"pass {self.dof} joint angles in radians",
            )
        if not np.all(np.isfinite(Q)):
            raise UsageError(f"{self.name}: joint vector contains NaN or inf", "pass finite joint angles")
        return Q

    def _chain(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Frames (N, dof+2, 4, 4) [base, links, flange] and joint-axis frames (N, dof, 4, 4) of (N, dof)."""
        N = Q.shape[0]
        T = np.tile(np.eye(4), (N, 1, 1))
        frames = np.empty((N, self.dof + 2, 4, 4))
        axes = np.empty((N, self.dof, 4, 4))
        frames[:, 0] = T
        theta = Q + self.dh.offset
        for i in range(self.dof):
            A = T @ self._pre[i]
            axes[:, i] = A
            T = A @ _rot_z_batch(theta[:, i]) @ self._post[i]
            frames[:, i + 1] = T
        frames[:, -1] = T @ self.dh.flange
        return frames, axes

    def fk(self, q: Any) -> np.ndarray:
        """Flange pose ``T_base_flange`` (4, 4) for joints ``q`` (dof,); (N, 4, 4) for (N, dof)."""
        Q = self._as_q(q)
        frames, _ = self._chain(np.atleast_2d(Q))
        return frames[0, -1] if Q.ndim == 1 else frames[:, -1]

    def fk_all(self, q: Any) -> np.ndarray:
        """Frames of the base, every link and the flange, (dof + 2, 4, 4), in the base frame (for drawing)."""
        Q = self._as_q(q)
        frames, _ = self._chain(np.atleast_2d(Q))
        return frames[0] if Q.ndim == 1 else frames

    def jacobian(self, q: Any) -> np.ndarray:
        """Geometric Jacobian (6, dof), base frame: rows 0-2 flange-origin velocity, 3-5 angular velocity."""
        Q = self._as_q(q)
        frames, axes = self._chain(np.atleast_2d(Q))
        z = axes[:, :, :3, 2]
        o = axes[:, :, :3, 3]
        pe = frames[:, -1, :3, 3][:, None, :]
        J = np.concatenate([np.cross(z, pe - o), z], axis=2).transpose(0, 2, 1)
        return J[0] if Q.ndim == 1 else J

    def fk_jacobian(self, q: Any) -> tuple[np.ndarray, np.ndarray]:
        """Flange pose (4, 4) and geometric Jacobian (6, dof) of ``q`` (dof,) from one pass of the chain."""
        theta = self._as_q(q).reshape(self.dof) + self.dh.offset
        T = np.eye(4)
        z = np.empty((self.dof, 3))
        o = np.empty((self.dof, 3))
        for i in range(self.dof):  # the chain of _chain for one configuration, without batch overhead
            A = T @ self._pre[i]
            z[i], o[i] = A[:3, 2], A[:3, 3]
            c, s = math.cos(theta[i]), math.sin(theta[i])
            B = A.copy()
            B[:, 0] = c * A[:, 0] + s * A[:, 1]
            B[:, 1] = c * A[:, 1] - s * A[:, 0]
            T = B @ self._post[i]
        F = T @ self.dh.flange
        J = np.empty((6, self.dof))
        J[:3] = np.cross(z, F[:3, 3] - o).T
        J[3:] = z.T
        return F, J

    def joint_lever_bounds(self) -> np.ndarray:
        """(dof,) upper bound, over every configuration, of the distance (m) from joint axis ``i`` to the
        flange origin.

        The chain from a point on axis ``i`` to the flange is a sequence of rigidly linked points (axis
        point, link frame origin, next axis point, ...), so the triangle inequality over their constant
        spacings bounds the distance whatever the joint angles. A joint motion ``dq`` therefore moves the
        flange origin by at most ``sum_i |dq_i| * bound_i`` (and a TCP at offset ``r`` from the flange by
        at most ``sum_i |dq_i| * (bound_i + |r|)``): the safety gate uses it to check joint moves
        conservatively between samples.
        """
        dist = [float(np.linalg.norm(self._post[i][:3, 3])) for i in range(self.dof)]  # axis i -> frame i
        hop = [float(np.linalg.norm(self._pre[i][:3, 3])) for i in range(self.dof)]  # frame i-1 -> axis i
        tail = float(np.linalg.norm(self.dh.flange[:3, 3]))  # last frame -> flange
        out = np.empty(self.dof)
        acc = tail
        for i in range(self.dof - 1, -1, -1):
            acc += dist[i]
            out[i] = acc
            acc += hop[i]
        return out

    # ------------------------------------------------------------------ limits and reach
    def within_limits(self, q: Any, margin: float = 0.0) -> bool:
        """True when every joint of ``q`` lies inside its limits (shrunk by ``margin`` rad)."""
        Q = self._as_q(q)
        lo, hi = self.joint_limits[:, 0] + margin, self.joint_limits[:, 1] - margin
        return bool(np.all((Q >= lo - 1e-12) & (Q <= hi + 1e-12)))

    def limit_violations(self, q: Any) -> list[str]:
        """One line per joint of ``q`` outside its limits (empty when all are inside)."""
        Q = self._as_q(q)
        out = []
        for i, (v, (lo, hi)) in enumerate(zip(Q, self.joint_limits, strict=True)):
            if v < lo - 1e-12 or v > hi + 1e-12:
                out.append(
                    f"joint {i + 1} at {math.degrees(v):.1f} deg is outside "
                    f"[{math.degrees(lo):.1f}, {math.degrees(hi):.1f}] deg"
                )
        return out

    def check_limits(self, q: Any) -> None:
        """Raise :class:`SafetyError` naming every joint of ``q`` outside its limits."""
        bad = self.limit_violations(q)
        if bad:
            raise SafetyError(
                f"{self.name}: joint limits violated: " + "; ".join(bad),
                "choose a target the arm can reach inside its joint limits (see docs/robot-models.md)",
            )

    def distance_from_shoulder(self, p: Any) -> float:
        """Distance (m) of point ``p`` (base frame) from the shoulder (axis 1 nearest axis 2)."""
        return float(np.linalg.norm(np.asarray(p, dtype=float).reshape(3) - self.shoulder))

    def in_reach(self, p: Any) -> bool:
        """True when point ``p`` (base frame) lies inside the published reach sphere about the shoulder.

        A quick pre-check only: :meth:`ik` decides whether a full pose is reachable.
        """
        return self.distance_from_shoulder(p) <= self.reach

    # ------------------------------------------------------------------ inverse kinematics
    def _polish(self, q: np.ndarray, T: np.ndarray, iters: int = 3) -> np.ndarray:
        """A few Gauss-Newton steps (removes round-off near singular closed-form branches)."""
        for _ in range(iters):
            e = _pose_residual(self.fk(q), T)
            if np.linalg.norm(e) < 1e-13:
                break
            q = q + np.linalg.lstsq(self.jacobian(q), e, rcond=1e-10)[0]
        return q

    def _shift_into_limits(self, q: np.ndarray, ref: np.ndarray) -> np.ndarray | None:
        """The 2*pi-equivalent of ``q`` nearest ``ref`` joint by joint within the limits, or None."""
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        k = np.round((ref - q) / _TWO_PI)
        out = q + _TWO_PI * k
        # candidates k-1, k, k+1: pick the in-limit one nearest ref
        best = np.full(self.dof, np.nan)
        for dk in (0.0, -1.0, 1.0, -2.0, 2.0):
            cand = out + _TWO_PI * dk
            ok = (cand >= lo - 1e-9) & (cand <= hi + 1e-9)
            better = ok & (np.isnan(best) | (np.abs(cand - ref) < np.abs(best - ref)))
            best = np.where(better, cand, best)
        if np.any(np.isnan(best)):
            return None
        return np.clip(best, lo, hi)

    def _pose_errors(self, Q: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and rotation (rad, ``|R - R_T|_F / sqrt 2``, first-order exact) errors of (N, dof)."""
        F = self._chain(Q)[0][:, -1]
        ep = np.linalg.norm(F[:, :3, 3] - T[:3, 3], axis=1)
        er = np.linalg.norm(F[:, :3, :3] - T[:3, :3], axis=(1, 2)) / math.sqrt(2.0)
        return ep, er

    def _analytic_raw(
        self, T: np.ndarray, seed: np.ndarray, tol_pos: float, tol_rot: float
    ) -> list[np.ndarray]:
        """Distinct closed-form solutions that reproduce ``T`` within the tolerances (polished if needed)."""
        W0 = self._ik_point
        assert W0 is not None
        solver = solve_three_parallel if self.ik_method == "three-parallel" else solve_spherical_wrist
        raw = solver(self._screws, W0, T, seed)
        if not raw:
            return []
        Q = np.array(raw)
        ep, er = self._pose_errors(Q, T)
        rough = (ep > 1e-12) | (er > 1e-12)
        for i in np.flatnonzero(rough):  # near-singular branches: a few Gauss-Newton steps
            Q[i] = self._polish(Q[i], T)
        if np.any(rough):
            ep, er = self._pose_errors(Q, T)
        uniq: list[np.ndarray] = []
        for q in Q[(ep <= tol_pos) & (er <= tol_rot)]:
            if not any(np.all(np.abs(wrap_angle(q - u)) < 1e-6) for u in uniq):
                uniq.append(q)
        return uniq

    def _check_target(self, T: Any) -> np.ndarray:
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise UsageError(
                f"{self.name}: IK target must be a finite 4x4 transform, got shape {T.shape}",
                "pass T_base_flange as a 4x4 numpy array in metres",
            )
        R = T[:3, :3]
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise UsageError(
                f"{self.name}: IK target rotation is not orthonormal",
                "orthonormalize the target (weldcell.sdk.geometry.orthonormalize)",
            )
        return T

    def _unreachable(self, T: np.ndarray, why: str) -> SafetyError:
        dist = self.distance_from_shoulder(T[:3, 3])
        base = float(np.linalg.norm(T[:3, 3]))
        where = (
            f"target at {base:.3f} m from the base ({dist:.3f} m from the shoulder; "
            f"{self.name} reach {self.reach:.3f} m)"
        )
        if why == "reach":
            msg = f"{self.name}: pose out of reach: {where}"
            fix = "move the target closer to the robot or move the workpiece/robot base"
        else:
            msg = f"{self.name}: no IK solution within joint limits: {where}{why}"
            fix = (
                "change the target orientation or the workpiece placement so the arm stays inside its limits"
            )
        return SafetyError(msg, fix)

    def ik_all(
        self,
        T_base_flange: Any,
        *,
        within_limits_only: bool = True,
        q_ref: Any = None,
        tol_pos: float = 1e-5,
        tol_rot: float = 1e-4,
    ) -> np.ndarray:
        """All distinct IK solutions (k, dof) for the flange pose (k = 0 when none).

        Closed form (up to 8) for the 6-DOF arms; for the redundant Panda, the distinct solutions reached
        by damped least squares from a fixed set of seeds. Each solution is shifted by multiples of 2*pi
        to lie inside the limits (nearest to ``q_ref``, default ``home``); with ``within_limits_only`` the
        ones that cannot be are dropped.
        """
        T = self._check_target(T_base_flange)
        ref = self.home if q_ref is None else np.asarray(q_ref, dtype=float)
        if self.ik_method == "numeric":
            seeds = [ref, self.home, *self._numeric_seeds(16)]
            sols = []
            for s in seeds:
                q = self._bounded_lsq(T, s, tol_pos, tol_rot)
                if q is not None and not any(np.linalg.norm(q - u) < 1e-3 for u in sols):
                    sols.append(q)
            return np.array(sols).reshape(-1, self.dof)
        out = []
        for q in self._analytic_raw(T, ref, tol_pos, tol_rot):
            qs = self._shift_into_limits(q, ref)
            if qs is not None:
                out.append(qs)
            elif not within_limits_only:
                out.append(wrap_angle(q))
        return np.array(out).reshape(-1, self.dof)

    def ik(
        self, T_base_flange: Any, q_seed: Any = None, *, tol_pos: float = 1e-5, tol_rot: float = 1e-4
    ) -> np.ndarray:
        """Joint solution within limits nearest ``q_seed`` (default ``home``) for the flange pose.

        Raises :class:`SafetyError` ("out of reach" or "no IK solution within joint limits", with the
        target's distance from the base) when there is none.
        """
        T = self._check_target(T_base_flange)
        seed = self.home if q_seed is None else self._as_q(q_seed)
        if self.distance_from_shoulder(T[:3, 3]) > self.max_reach_bound + 1e-9:
            raise self._unreachable(T, "reach")
        if self.ik_method == "numeric":
            return self._ik_numeric(T, seed, tol_pos, tol_rot)
        raw = self._analytic_raw(T, seed, tol_pos, tol_rot)
        if not raw:
            raise self._unreachable(T, "reach")
        cands = [c for c in (self._shift_into_limits(q, seed) for q in raw) if c is not None]
        if not cands:
            detail = self.limit_violations(wrap_angle(raw[0]))
            raise self._unreachable(T, f"; all {len(raw)} solutions violate limits, e.g. {detail[0]}")
        return min(cands, key=lambda c: float(np.sum((c - seed) ** 2)))


# ----------------------------------------------------------------------------------------- registry
def _deg_pairs(pairs: Sequence[Sequence[float]]) -> np.ndarray:
    return np.radians(np.asarray(pairs, dtype=float))


def build_model(table: dict[str, Any]) -> RobotModel:
    """A :class:`RobotModel` from one parameter table of :mod:`weldcell.hal.robot_models`."""
    flange = None
    if table.get("flange"):
        f = DHTable.from_rows(table["convention"], table["flange"])
        pre, post = f.fixed_parts()
        flange = pre[0] @ _rot_z_batch(f.offset[:1])[0] @ post[0]
    dh = DHTable.from_rows(table["convention"], table["dh"], flange)
    limits = (
        _deg_pairs(table["joint_limits_deg"])
        if "joint_limits_deg" in table
        else np.asarray(table["joint_limits_rad"], dtype=float)
    )
    speeds = (
        np.radians(table["joint_speed_deg"])
        if "joint_speed_deg" in table
        else np.asarray(table["joint_speed_rad"], dtype=float)
    )
    home = (
        np.radians(table["home_deg"]) if "home_deg" in table else np.asarray(table["home_rad"], dtype=float)
    )
    return RobotModel(
        name=table["name"],
        dof=len(table["dh"]),
        dh=dh,
        joint_limits=limits,
        joint_speed_limits=speeds,
        joint_accel_limits=np.asarray(table["joint_accel"], dtype=float),
        max_tcp_speed=table["max_tcp_speed"],
        reach=table["reach"],
        payload=table["payload"],
        home=home,
        max_tcp_rot_speed=table["max_tcp_rot_speed"],
        aliases=tuple(table["aliases"]),
        sources=table["sources"],
    )


MODELS: dict[str, RobotModel] = {m.name: m for m in (build_model(t) for t in ROBOT_TABLES)}
_ALIASES: dict[str, str] = {a: m.name for m in MODELS.values() for a in m.aliases}


def get_model(name: str) -> RobotModel:
    """The robot model called ``name`` (or one of its aliases, case-insensitive)."""
    key = str(name).strip().lower().replace("_", "-")
    if key in MODELS:
        return MODELS[key]
    if key in _ALIASES:
        return MODELS[_ALIASES[key]]
    known = sorted(MODELS)
    close = difflib.get_close_matches(key, known + sorted(_ALIASES), n=1, cutoff=0.5)
    hint = f"did you mean {close[0]!r}? " if close else ""
    raise DataError(
        f"unknown robot model {name!r}; available: {', '.join(known)}",
        f"{hint}use one of: {', '.join(known)}",
    )
