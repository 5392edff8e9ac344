"""Camera-frame poses between IMU poses (paper 004 eq. 2): the paper's linear interpolation of the
rotation matrix and the rotation-group (SO(3) slerp) alternative, plus the trajectory metrics.

The paper's ``R_k = R_i + (k - i)(R_j - R_i)/(j - i)`` leaves SO(3): the result is not orthonormal
(it shrinks vectors by up to cos(θ/2) at mid-interval for a rotation θ between the two poses).
:func:`interpolate_pose` ``method="linear"`` reproduces it faithfully (then projects the matrix
back to the nearest rotation by SVD so that the pose can be used at all); ``method="slerp"``
interpolates on the group. Translation is linear in both.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp


def interpolate_pose(
    T_i: np.ndarray,
    T_j: np.ndarray,
    t_i: float,
    t_j: float,
    t_k: float,
    method: str = "slerp",
    project: bool = True,
) -> np.ndarray:
    """The pose at ``t_k`` in [t_i, t_j] between ``T_i`` and ``T_j`` (eq. 2)."""
    s = 0.0 if t_j == t_i else float(np.clip((t_k - t_i) / (t_j - t_i), 0.0, 1.0))
    T = np.eye(4)
    T[:3, 3] = T_i[:3, 3] + s * (T_j[:3, 3] - T_i[:3, 3])
    if method == "linear":
        R = T_i[:3, :3] + s * (T_j[:3, :3] - T_i[:3, :3])
        if project:
            U, _, Vt = np.linalg.svd(R)
            R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        T[:3, :3] = R
    elif method == "slerp":
        rots = Rotation.from_matrix(np.stack([T_i[:3, :3], T_j[:3, :3]]))
        T[:3, :3] = Slerp([0.0, 1.0], rots)([s]).as_matrix()[0]
    else:
        from weldcell.sdk.errors import DataError

        raise DataError(f"unknown interpolation '{method}'", "use 'slerp' or 'linear'")
    return T


def interpolate_trajectory(
    times: np.ndarray, poses: np.ndarray, t_query: np.ndarray, method: str = "slerp"
) -> np.ndarray:
    """(M, 4, 4) poses at ``t_query`` interpolated between the bracketing ``poses`` at ``times``."""
    times = np.asarray(times, float)
    out = np.empty((len(t_query), 4, 4))
    idx = np.clip(np.searchsorted(times, t_query, side="right") - 1, 0, len(times) - 2)
    for n, (k, t) in enumerate(zip(idx, t_query, strict=False)):
        out[n] = interpolate_pose(poses[k], poses[k + 1], times[k], times[k + 1], t, method)
    return out


def umeyama(src: np.ndarray, dst: np.ndarray, scale: bool = False) -> tuple[np.ndarray, float]:
    """Least-squares similarity (Umeyama 1991) mapping ``src`` (N,3) onto ``dst``: (T 4x4, s)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    A, B = src - mu_s, dst - mu_d
    C = B.T @ A / len(src)
    U, D, Vt = np.linalg.svd(C)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / A.var(0).sum()) if scale else 1.0
    T = np.eye(4)
    T[:3, :3] = s * R
    T[:3, 3] = mu_d - s * R @ mu_s
    return T, s


def ate_rmse(est: np.ndarray, ref: np.ndarray, scale: bool = False) -> tuple[float, np.ndarray]:
    """Absolute trajectory error (RMSE of positions, m) after SE(3) (or Sim(3)) Umeyama alignment of
    the estimated positions (N,3) onto the reference; returns it and the alignment ``T_ref_est``."""
    est, ref = np.asarray(est, float), np.asarray(ref, float)
    T, _ = umeyama(est, ref, scale)
    aligned = est @ T[:3, :3].T + T[:3, 3]
    return float(np.sqrt(np.mean(np.sum((aligned - ref) ** 2, axis=1)))), T
