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
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from weldcell.hal.robot_models import ROBOT_TABLES
from weldcell.sdk.errors import DataError, SafetyError, UsageError
from weldcell.sdk.geometry import interpolate_poses, pose_error, rotation_angle

_TWO_PI = 2.0 * math.pi


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


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross is slow for single vectors)."""
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def _rot(k: np.ndarray, t: float) -> np.ndarray:
    """Rodrigues rotation about unit axis ``k`` by ``t``."""
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(t) * K + (1.0 - math.cos(t)) * (K @ K)


# ------------------------------------------------------------------------------------ Paden-Kahan subproblems
def _sp1(k: np.ndarray, p: np.ndarray, q: np.ndarray, eps: float = 1e-9) -> float | None:
    """Subproblem 1: angle ``t`` with ``rot(k, t) p = q``; None if ``p`` or ``q`` is on ``k``."""
    pp = p - k * (k @ p)
    qq = q - k * (k @ q)
    if np.linalg.norm(pp) < eps or np.linalg.norm(qq) < eps:
        return None
    return math.atan2(float(k @ _cross(pp, qq)), float(pp @ qq))


def _sp4(h: np.ndarray, k: np.ndarray, p: np.ndarray, d: float, tol: float = 1e-9) -> list[float] | None:
    """Subproblem 4: angles ``t`` with ``h^T rot(k, t) p = d``: [] if none, None if every ``t`` solves it."""
    kp = k @ p
    A = float(h @ p - (h @ k) * kp)
    B = float(h @ _cross(k, p))
    C = float((h @ k) * kp)
    r = math.hypot(A, B)
    if r < 1e-10:
        return None if abs(d - C) < 1e-9 else []
    x = (d - C) / r
    if abs(x) > 1.0 + tol:
        return []
    phi = math.atan2(B, A)
    dt = math.acos(max(-1.0, min(1.0, x)))
    return [phi + dt, phi - dt]


def _perp(v: np.ndarray, k: np.ndarray) -> np.ndarray:
    return v - k * (k @ v)


def _wrap(a: np.ndarray | float) -> Any:
    """Angles wrapped to (-pi, pi]."""
    return -((-np.asarray(a) + math.pi) % _TWO_PI - math.pi)


@dataclass(frozen=True, eq=False)
class _Screws:
    """Product of exponentials at ``q = 0``: unit axes ``h`` through points ``p``, flange pose ``M``."""

    h: np.ndarray
    p: np.ndarray
    M: np.ndarray


def _closest_points(
    p1: np.ndarray, h1: np.ndarray, p2: np.ndarray, h2: np.ndarray
) -> tuple[np.ndarray, float]:
    """Midpoint of the closest points of two lines and their distance (parallel lines: point on line 1)."""
    w = p1 - p2
    b = float(h1 @ h2)
    den = 1.0 - b * b
    if den < 1e-12:
        return p1, float(np.linalg.norm(_perp(w, h1)))
    dw1, dw2 = float(h1 @ w), float(h2 @ w)
    s = (b * dw2 - dw1) / den
    t = (dw2 - b * dw1) / den
    c1, c2 = p1 + s * h1, p2 + t * h2
    return 0.5 * (c1 + c2), float(np.linalg.norm(c1 - c2))


def _closest_on_first(p1: np.ndarray, h1: np.ndarray, p2: np.ndarray, h2: np.ndarray) -> np.ndarray:
    """Point of line 1 closest to line 2 (``p1`` when they are parallel)."""
    b = float(h1 @ h2)
    den = 1.0 - b * b
    if den < 1e-12:
        return p1
    w = p1 - p2
    return p1 + (b * float(h2 @ w) - float(h1 @ w)) / den * h1


def _classify(s: _Screws) -> tuple[str, dict[str, np.ndarray]]:
    """Which closed form fits this chain: ``three-parallel``, ``spherical-wrist`` or ``numeric``."""
    h, p = s.h, s.p
    if len(h) != 6:
        return "numeric", {}

    def par(i: int, j: int) -> bool:
        return bool(np.linalg.norm(np.cross(h[i], h[j])) < 1e-9)

    if par(1, 2) and par(2, 3):
        c56, dist = _closest_points(p[4], h[4], p[5], h[5])
        if dist < 1e-9 and not par(4, 5):
            return "three-parallel", {"O5": c56}
    if par(1, 2) and not par(3, 4) and not par(4, 5):
        c45, d45 = _closest_points(p[3], h[3], p[4], h[4])
        c56, d56 = _closest_points(p[4], h[4], p[5], h[5])
        if d45 < 1e-9 and d56 < 1e-9 and np.linalg.norm(c45 - c56) < 1e-9:
            return "spherical-wrist", {"W": c45}
    return "numeric", {}


def _ik_three_parallel(s: _Screws, W0: np.ndarray, T: np.ndarray, seed: np.ndarray) -> list[np.ndarray]:
    """All closed-form solutions for axes 2 || 3 || 4 and axes 5, 6 intersecting at ``W0`` (UR type).

    Order of the solution: q1 (SP4 on the h2-component of the wrist point), q5 (SP4 on h2 . z6),
    q6 (SP1), q2 + q3 + q4 (SP1), q3 (law of cosines, SP4), q2 (SP1), q4 by difference.
    """
    h, P, M = s.h, s.p, s.M
    s3, s4 = float(np.sign(h[2] @ h[1])), float(np.sign(h[3] @ h[1]))  # parallel or antiparallel axes
    R06 = T[:3, :3] @ M[:3, :3].T
    O5 = T[:3, 3] - R06 @ (M[:3, 3] - W0)
    a = _perp(P[2] - P[1], h[1])
    b = _perp(P[3] - P[2], h[1])
    sols: list[np.ndarray] = []
    r1 = _sp4(O5 - P[0], h[0], h[1], float(h[1] @ (W0 - P[0])))
    q1s = [seed[0]] if r1 is None else r1
    for q1 in q1s:
        R1 = _rot(h[0], q1)
        r5 = _sp4(h[1], h[4], h[5], float(h[1] @ (R1.T @ R06 @ h[5])))
        q5s = [seed[4]] if r5 is None else r5
        for q5 in q5s:
            R5 = _rot(h[4], q5)
            u = _unit_perp(h[1])
            X = R1.T @ (O5 - P[0]) + P[0]
            q6 = _sp1(h[5], R06.T @ R1 @ h[1], R5.T @ h[1], eps=1e-7)
            if q6 is None:  # wrist singularity: axis 6 || axis 4, only q234 +- q6 is fixed
                q234 = _singular_q234(
                    h[1],
                    R1.T @ R06 @ R5.T,
                    float(np.sign(h[1] @ R5 @ h[5])),
                    seed[5],
                    X - P[1],
                    W0 - P[3],
                    a,
                    b,
                    u,
                )
                if q234 is None:
                    continue
                q6 = _sp1(h[5], u6 := _unit_perp(h[5]), R5.T @ _rot(h[1], q234).T @ R1.T @ R06 @ u6)
                if q6 is None:
                    continue
            else:
                R234 = R1.T @ R06 @ _rot(h[5], q6).T @ R5.T
                q234 = _sp1(h[1], u, R234 @ u)  # = q2 + s3 q3 + s4 q4
                if q234 is None:
                    continue
            Y = X - P[1] - _rot(h[1], q234) @ (W0 - P[3])
            y = _perp(Y, h[1])
            r3 = _sp4(a, h[1], b, 0.5 * float(y @ y - a @ a - b @ b), tol=1e-7)
            q3s = [s3 * seed[2]] if r3 is None else r3  # angles about h2
            for q3 in q3s:
                v = a + _rot(h[1], q3) @ b
                q2 = _sp1(h[1], v, y)
                if q2 is None:
                    q2 = float(seed[1])
                sols.append(np.array([q1, q2, s3 * q3, s4 * (q234 - q2 - q3), q5, q6]))
    return sols


def _singular_q234(
    h2: np.ndarray,
    R: np.ndarray,
    sigma: float,
    q6_seed: float,
    x: np.ndarray,
    w: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    u: np.ndarray,
) -> float | None:
    """q2 + q3 + q4 at a UR-type wrist singularity (axis 6 parallel to axes 2-4).

    There ``rot(h2, q234 + sigma q6) = R`` fixes only ``psi = q234 + sigma q6``, but q234 also places
    axis 4 on a circle about the wrist point, which the 2-link arm (a, b) must reach:
    ``|perp(x - rot(h2, q234) w)|`` in ``[| |a|-|b| |, |a|+|b|]``. Take the q234 implied by the seed's q6
    when feasible, else the nearest feasible one (SP4 on the interval ends).
    """
    psi = _sp1(h2, u, R @ u)
    if psi is None:
        return None
    t_seed = psi - sigma * q6_seed
    x0, v = _perp(x, h2), _perp(w, h2)
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    base = float(x0 @ x0 + v @ v)
    lo, hi = 0.5 * (base - (na + nb) ** 2), 0.5 * (base - (na - nb) ** 2)
    g = float(x0 @ _rot(h2, t_seed) @ v)
    if lo - 1e-12 <= g <= hi + 1e-12:
        return t_seed
    cands = [t for bound in (lo, hi) for t in (_sp4(x0, h2, v, bound) or [])]
    if not cands:
        return None
    return min(cands, key=lambda t: abs(float(_wrap(t - t_seed))))


def _ik_spherical_wrist(s: _Screws, W0: np.ndarray, T: np.ndarray, seed: np.ndarray) -> list[np.ndarray]:
    """All closed-form solutions for axes 2 || 3 and a spherical wrist centred at ``W0`` (ABB type).

    Position: q1 (SP4), q3 (law of cosines, SP4), q2 (SP1). Orientation: q5 (SP4), q4 (SP1), q6 (SP1).
    """
    h, P, M = s.h, s.p, s.M
    s3 = float(np.sign(h[2] @ h[1]))
    R06 = T[:3, :3] @ M[:3, :3].T
    W = T[:3, 3] - R06 @ (M[:3, 3] - W0)
    sols: list[np.ndarray] = []
    r1 = _sp4(W - P[0], h[0], h[1], float(h[1] @ (W0 - P[0])))
    q1s = [seed[0]] if r1 is None else r1
    a = _perp(P[2] - P[1], h[1])
    b = _perp(W0 - P[2], h[1])
    for q1 in q1s:
        R1 = _rot(h[0], q1)
        y = _perp(R1.T @ (W - P[0]) + P[0] - P[1], h[1])
        r3 = _sp4(a, h[1], b, 0.5 * float(y @ y - a @ a - b @ b))
        q3s = [s3 * seed[2]] if r3 is None else r3  # angles about h2
        for q3h in q3s:
            q2 = _sp1(h[1], a + _rot(h[1], q3h) @ b, y)
            if q2 is None:
                q2 = float(seed[1])
            q3 = s3 * q3h
            Rw = (R1 @ _rot(h[1], q2) @ _rot(h[2], q3)).T @ R06
            z = Rw @ h[5]
            r5 = _sp4(h[3], h[4], h[5], float(h[3] @ z))
            q5s = [seed[4]] if r5 is None else r5
            for q5 in q5s:
                R5 = _rot(h[4], q5)
                q4 = _sp1(h[3], R5 @ h[5], z)
                if q4 is None:
                    q4 = float(seed[3])
                R45 = _rot(h[3], q4) @ R5
                u = _unit_perp(h[5])
                q6 = _sp1(h[5], u, R45.T @ Rw @ u)
                if q6 is None:
                    continue
                sols.append(np.array([q1, q2, q3, q4, q5, q6]))
    return sols


def _unit_perp(k: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to ``k``."""
    e = np.eye(3)[int(np.argmin(np.abs(k)))]
    u = _cross(k, e)
    return u / np.linalg.norm(u)


# ------------------------------------------------------------------------------------------ motion profile
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


# --------------------------------------------------------------------------------------------- the model
@dataclass(frozen=True, eq=False)
class RobotModel:
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
    _screws: _Screws = field(init=False, repr=False)
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
        screws = _Screws(
            axes_frames[0, :, :3, 2].copy(), axes_frames[0, :, :3, 3].copy(), frames[0, -1].copy()
        )
        object.__setattr__(self, "_screws", screws)
        method, extra = _classify(screws)
        object.__setattr__(self, "ik_method", method)
        object.__setattr__(self, "_ik_point", extra.get("O5", extra.get("W")))
        shoulder = _closest_on_first(screws.p[0], screws.h[0], screws.p[1], screws.h[1])
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
        solver = _ik_three_parallel if self.ik_method == "three-parallel" else _ik_spherical_wrist
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
            if not any(np.all(np.abs(_wrap(q - u)) < 1e-6) for u in uniq):
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
                out.append(_wrap(q))
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
            detail = self.limit_violations(_wrap(raw[0]))
            raise self._unreachable(T, f"; all {len(raw)} solutions violate limits, e.g. {detail[0]}")
        return min(cands, key=lambda c: float(np.sum((c - seed) ** 2)))

    # numeric IK (redundant arms) ----------------------------------------------------------------
    def _numeric_seeds(self, n: int) -> np.ndarray:
        rng = np.random.default_rng(12345)
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        return lo + (hi - lo) * (0.1 + 0.8 * rng.random((n, self.dof)))

    def _dls(
        self,
        T: np.ndarray,
        q0: np.ndarray,
        tol_pos: float,
        tol_rot: float,
        *,
        clamp: bool = True,
        max_iter: int = 150,
    ) -> np.ndarray | None:
        """Damped least squares with LM damping ``lambda^2 = E + 1e-9`` and a null-space pull toward home.

        ``dq = J^T (J J^T + lambda^2 I)^-1 e + (I - J^+ J) k (q_home - q)``; joints clamped to the limits.
        The pull stops once the pose error is below 1e-4 so the final steps converge quadratically.
        """
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        q = np.clip(q0, lo, hi) if clamp else np.array(q0, dtype=float)
        eye6 = np.eye(6)
        for _ in range(max_iter):
            frames, axes = self._chain(q[None])
            e = _pose_residual(frames[0, -1], T)
            ep, er = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
            if ep < tol_pos * 1e-3 and er < tol_rot * 1e-3:
                break
            z, o = axes[0, :, :3, 2], axes[0, :, :3, 3]
            J = np.concatenate([np.cross(z, frames[0, -1, :3, 3] - o), z], axis=1).T
            lam2 = 0.5 * float(e @ e) + 1e-9
            JJt = J @ J.T
            dq = J.T @ np.linalg.solve(JJt + lam2 * eye6, e)
            if self.dof > 6 and ep + er > 1e-4:  # pull off at the end so the last steps converge exactly
                dq = dq + (np.eye(self.dof) - np.linalg.pinv(J, rcond=1e-6) @ J) @ (0.2 * (self.home - q))
            step = float(np.max(np.abs(dq)))
            if step > 0.5:
                dq *= 0.5 / step
            q = q + dq
            if clamp:
                q = np.clip(q, lo, hi)
        dp, dr = pose_error(self.fk(q), T)
        return q if (dp <= 1e-2 * tol_pos and dr <= 1e-2 * tol_rot) else None

    def _bounded_lsq(
        self, T: np.ndarray, q0: np.ndarray, tol_pos: float, tol_rot: float, *, bounded: bool = True
    ) -> np.ndarray | None:
        """Trust-region reflective least squares on the pose residual with the joint limits as bounds."""
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        x0 = np.clip(q0, lo + 1e-9, hi - 1e-9) if bounded else np.asarray(q0, dtype=float)
        res = least_squares(
            lambda q: -_pose_residual(self.fk(q), T),
            x0,
            jac=self.jacobian,
            bounds=(lo, hi) if bounded else (-np.inf, np.inf),
            method="trf",
            xtol=1e-10,
            ftol=1e-12,
            gtol=1e-12,
            max_nfev=100,
        )
        q = res.x
        if bounded:
            polished = self._polish(q, T, iters=4)
            if self.within_limits(polished):
                q = polished
        dp, dr = pose_error(self.fk(q), T)
        return q if (dp <= tol_pos and dr <= tol_rot) else None

    def _ik_numeric(self, T: np.ndarray, seed: np.ndarray, tol_pos: float, tol_rot: float) -> np.ndarray:
        """DLS from the seed (fast, continuous along paths); else bounded least squares from more seeds."""
        q = self._dls(T, seed, tol_pos, tol_rot, max_iter=60)
        if q is not None:
            return q
        for s in [seed, self.home, *self._numeric_seeds(24)]:
            q = self._bounded_lsq(T, s, tol_pos, tol_rot)
            if q is not None:
                return q
        # distinguish "outside the joint limits" from "outside the workspace"
        for s in [seed, self.home, *self._numeric_seeds(6)]:
            q = self._bounded_lsq(T, s, tol_pos, tol_rot, bounded=False)
            if q is not None:
                detail = self.limit_violations(_wrap(q)) or ["(a solution lies on a limit)"]
                raise self._unreachable(T, f"; e.g. {detail[0]}")
        raise self._unreachable(T, "reach")

    # ------------------------------------------------------------------ motion times
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


def _pose_residual(T: np.ndarray, T_target: np.ndarray) -> np.ndarray:
    """6-vector (position error, rotation-vector error) from ``T`` to ``T_target``, base frame."""
    dR = T_target[:3, :3] @ T[:3, :3].T
    return np.concatenate([T_target[:3, 3] - T[:3, 3], Rotation.from_matrix(dR).as_rotvec()])


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
