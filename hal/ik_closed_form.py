"""Closed-form inverse kinematics of 6-axis arms by Paden-Kahan subproblems on the joint screws.

:class:`weldcell.hal.kinematics.RobotModel` rewrites its DH chain as screws (:class:`Screws`), asks
:func:`classify_chain` which closed form fits, and calls :func:`solve_three_parallel` (UR, AUBO) or
:func:`solve_spherical_wrist` (ABB). Subproblems as in Murray, Li & Sastry 1994, sec. 3.2.2, and
Elias & Wen, "IK-Geo", 2022; see the module docstring of :mod:`weldcell.hal.kinematics`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

_TWO_PI = 2.0 * math.pi


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


def wrap_angle(a: np.ndarray | float) -> Any:
    """Angles wrapped to (-pi, pi]."""
    return -((-np.asarray(a) + math.pi) % _TWO_PI - math.pi)


@dataclass(frozen=True, eq=False)
class Screws:
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


def closest_on_first(p1: np.ndarray, h1: np.ndarray, p2: np.ndarray, h2: np.ndarray) -> np.ndarray:
    """Point of line 1 closest to line 2 (``p1`` when they are parallel)."""
    b = float(h1 @ h2)
    den = 1.0 - b * b
    if den < 1e-12:
        return p1
    w = p1 - p2
    return p1 + (b * float(h2 @ w) - float(h1 @ w)) / den * h1


def classify_chain(s: Screws) -> tuple[str, dict[str, np.ndarray]]:
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


def solve_three_parallel(s: Screws, W0: np.ndarray, T: np.ndarray, seed: np.ndarray) -> list[np.ndarray]:
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
    return min(cands, key=lambda t: abs(float(wrap_angle(t - t_seed))))


def solve_spherical_wrist(s: Screws, W0: np.ndarray, T: np.ndarray, seed: np.ndarray) -> list[np.ndarray]:
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
