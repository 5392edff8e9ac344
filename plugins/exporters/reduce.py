"""Fewest torch poses whose interpolated path stays within a tolerance of the planned one.

A controller moves the TCP on a straight line between two programmed poses and turns the torch by a
slerp with the same path fraction. :func:`reduce_poses` keeps the fewest poses (a Douglas-Peucker split
on the largest combined deviation) such that every planned pose, and three samples inside every planned
segment, lie within ``tol_pos`` of the reduced path's line and within ``tol_ang`` of its orientation at
the closest point of that line. The achieved deviation is returned with the poses so it can be written
into the program and reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import interpolate_poses

SUB_SAMPLES = 3  # samples checked inside every planned segment, besides its end poses


@dataclass(frozen=True)
class Reduction:
    """The kept poses of one seam and how far the interpolated path between them strays from the plan."""

    poses: np.ndarray  # (K, 4, 4) kept poses, first and last always kept
    indices: np.ndarray  # (K,) their indices in the planned poses
    max_position_error: float  # m, over every checked sample
    max_angle_error: float  # rad, over every checked sample
    n_planned: int


def densify(poses: np.ndarray, per_segment: int = SUB_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """The planned path sampled at its poses and ``per_segment`` interior points of every segment:
    (N, 4, 4) poses and (N,) fractional pose index (sample j lies between poses floor(j) and ceil(j))."""
    P = np.asarray(poses, dtype=float)
    if len(P) < 2:
        return P.copy(), np.arange(len(P), dtype=float)
    s = np.arange(1, per_segment + 2) / (per_segment + 1)  # interior samples and the segment's end
    R = Rotation.from_matrix(P[:, :3, :3])
    rv = (R[:-1].inv() * R[1:]).as_rotvec()  # (M-1, 3) per-segment turn, the short way (as slerp)
    m = len(P) - 1
    frac = np.tile(s, m)
    seg = np.repeat(np.arange(m), len(s))
    out = np.tile(np.eye(4), (len(frac) + 1, 1, 1))
    out[0] = P[0]
    out[1:, :3, :3] = (R[seg] * Rotation.from_rotvec(rv[seg] * frac[:, None])).as_matrix()
    out[1:, :3, 3] = P[seg, :3, 3] + frac[:, None] * (P[seg + 1, :3, 3] - P[seg, :3, 3])
    return out, np.concatenate([[0.0], seg + frac])


def _angles(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle (rad) between rotation stacks (N, 3, 3)."""
    c = (np.einsum("nij,nij->n", Ra, Rb) - 1.0) / 2.0
    return np.arccos(np.clip(c, -1.0, 1.0))


def _slerp_many(R0: np.ndarray, R1: np.ndarray, s: np.ndarray) -> np.ndarray:
    """R0 exp(s log(R0^T R1)) for many fractions, vectorised (Rodrigues)."""
    R = R0.T @ R1
    c = min(1.0, max(-1.0, (float(np.trace(R)) - 1.0) / 2.0))
    th = math.acos(c)
    if th < 1e-12:
        return np.broadcast_to(R0, (len(s), 3, 3)).copy()
    if math.pi - th < 1e-6:  # the slerp is ambiguous: use scipy's choice via interpolate_poses
        T0, T1 = np.eye(4), np.eye(4)
        T0[:3, :3], T1[:3, :3] = R0, R1
        return interpolate_poses(T0, T1, s)[:, :3, :3]
    k = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2.0 * math.sin(th))
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    a = th * np.asarray(s, dtype=float)
    E = np.eye(3) + np.sin(a)[:, None, None] * K + (1.0 - np.cos(a))[:, None, None] * (K @ K)
    return R0 @ E


def deviation(T0: np.ndarray, T1: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position (m) and angle (rad) deviation of ``samples`` (N, 4, 4) from the move ``T0 -> T1``.

    Each sample is matched to the closest point of the straight line (fraction ``s`` clamped to [0, 1]);
    for a pure reorientation (no travel) the fraction comes from the angle instead. The angle error is
    then measured against the slerped orientation at that fraction, as the controller turns the torch.
    """
    p0, p1 = T0[:3, 3], T1[:3, 3]
    d = p1 - p0
    L2 = float(d @ d)
    P = samples[:, :3, 3]
    if L2 > 1e-16:
        s = np.clip((P - p0) @ d / L2, 0.0, 1.0)
    else:
        total = _angles(T0[None, :3, :3], T1[None, :3, :3])[0]
        to_s = _angles(np.broadcast_to(T0[:3, :3], (len(samples), 3, 3)), samples[:, :3, :3])
        s = np.clip(to_s / total, 0.0, 1.0) if total > 1e-12 else np.zeros(len(samples))
    dpos = np.linalg.norm(P - (p0 + s[:, None] * d), axis=1)
    dang = _angles(_slerp_many(T0[:3, :3], T1[:3, :3], s), samples[:, :3, :3])
    return dpos, dang


def reduce_poses(poses: np.ndarray, tol_pos: float = 1e-4, tol_ang: float = math.radians(0.5)) -> Reduction:
    """Keep the fewest poses such that the path interpolated between them stays within ``tol_pos`` (m) and
    ``tol_ang`` (rad) of the planned path (Douglas-Peucker on ``max(dpos / tol_pos, dang / tol_ang)``)."""
    P = np.asarray(poses, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4):
        raise DataError(f"poses must be (K, 4, 4), got {P.shape}", "pass a stack of 4x4 torch poses")
    if not (tol_pos > 0 and tol_ang > 0 and math.isfinite(tol_pos) and math.isfinite(tol_ang)):
        raise DataError(
            f"reduction tolerances must be positive and finite, got {tol_pos} m and {tol_ang} rad",
            "set tolerance (e.g. '0.1 mm') and angle_tolerance (e.g. '0.5 deg')",
        )
    n = len(P)
    if n <= 2:
        return Reduction(P.copy(), np.arange(n), 0.0, 0.0, n)
    dense, where = densify(P)
    keep = {0, n - 1}
    stack = [(0, n - 1)]
    worst_pos, worst_ang = 0.0, 0.0
    while stack:
        i, j = stack.pop()
        inside = (where > i) & (where < j)
        if not np.any(inside):
            continue
        dpos, dang = deviation(P[i], P[j], dense[inside])
        score = np.maximum(dpos / tol_pos, dang / tol_ang)
        k = int(np.argmax(score))
        if score[k] <= 1.0 or j - i < 2:
            worst_pos, worst_ang = max(worst_pos, float(dpos.max())), max(worst_ang, float(dang.max()))
            continue
        # split at the planned pose nearest the worst sample (strictly inside the span)
        m = int(np.clip(round(float(where[inside][k])), i + 1, j - 1))
        keep.add(m)
        stack += [(i, m), (m, j)]
    idx = np.array(sorted(keep))
    return Reduction(P[idx], idx, worst_pos, worst_ang, n)
