"""Hand-eye fit when the feature point's position on its carrier is unknown.

The flange method (eq. 9) needs the reference point in the robot frame. When it is not exactly the
TCP (the wrist circle used with the Kinect in §4.2, a feature on the base mounting flange in §4.1,
robot 2's flange in co-manipulation, eq. 6a), the point ``q`` is a second unknown::

    X c_i = B_i q        (c_i: point in camera, B_i: known 4x4 per sample)

eye-on-base: ``X = T_base_camera``, ``B_i = T_base_flange_i``, ``q`` = feature in the flange frame;
eye-in-hand: ``X = T_flange_camera``, ``B_i = T_flange_base_i``, ``q`` = feature in the base frame.
It is linear in ``(M = R_X, t_X, q)``: ``M c_i + t_X - R_Bi q = t_Bi``; we solve that, project
``M`` onto SO(3) and refine ``(R_X, t_X, q)`` by nonlinear least squares. It needs rotation
diversity in ``B_i`` (else ``q`` cannot be told from ``t_X``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import orthonormalize


@dataclass
class FeatureFit:
    T: np.ndarray  # X (4x4)
    q: np.ndarray  # feature point on its carrier (3,)
    residuals: np.ndarray
    inliers: np.ndarray
    condition: float


def _linear(c: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    n = len(c)
    A = np.zeros((3 * n, 15))
    eye = np.eye(3)
    for k in range(3):  # M c = sum_k c_k * M[:, k]; vec(M) column-major
        A[:, 3 * k : 3 * k + 3] = (c[:, k, None, None] * eye).reshape(3 * n, 3)
    A[:, 9:12] = np.tile(eye, (n, 1))
    A[:, 12:15] = -B[:, :3, :3].reshape(3 * n, 3)
    b = B[:, :3, 3].reshape(3 * n)
    s = np.linalg.svd(A, compute_uv=False)
    cond = float(s[0] / max(s[-1], 1e-300))
    sol = np.linalg.lstsq(A, b, rcond=None)[0]
    M = sol[:9].reshape(3, 3, order="F")
    return orthonormalize(M), sol[9:12], cond if np.isfinite(cond) else float("inf")


def rotation_spread(R: np.ndarray) -> float:
    """Largest rotation angle (rad) between any sample's rotation and the mean rotation, times 2 (an
    estimate of the widest pairwise spread) for (n, 3, 3) rotations."""
    rot = Rotation.from_matrix(np.asarray(R).reshape(-1, 3, 3))
    ang = (rot.mean().inv() * rot).magnitude()
    return float(2.0 * np.max(ang)) if len(ang) else 0.0


def _resid(c, B, R, t, q):
    return np.linalg.norm(c @ R.T + t - (B[:, :3, :3] @ q + B[:, :3, 3]), axis=1)


def _refine(c, B, R, t, q):
    x0 = np.concatenate([Rotation.from_matrix(R).as_rotvec(), t, q])

    def f(x):
        Rx = Rotation.from_rotvec(x[:3]).as_matrix()
        return (c @ Rx.T + x[3:6] - (B[:, :3, :3] @ x[6:9] + B[:, :3, 3])).ravel()

    sol = least_squares(f, x0, method="lm")
    return Rotation.from_rotvec(sol.x[:3]).as_matrix(), sol.x[3:6], sol.x[6:9]


def fit_with_unknown_point(
    c: np.ndarray,
    B: np.ndarray,
    robust: bool = True,
    n_sigma: float = 3.0,
    min_threshold: float = 0.0,
    trials: int = 300,
    min_rotation: float = np.radians(5.0),
    rng: np.random.Generator | int | None = 0,
) -> FeatureFit:
    """Solve ``X c_i = B_i q`` for ``X`` and ``q`` (see module doc); robust to outliers by least
    median of squares over 6-sample subsets when ``robust``. Raises DataError when the rotations of
    ``B_i`` are too similar to separate ``q`` from ``X``'s translation."""
    c = np.asarray(c, dtype=float).reshape(-1, 3)
    B = np.asarray(B, dtype=float).reshape(-1, 4, 4)
    n = len(c)
    if n < 5:
        raise DataError(
            f"{n} samples; estimating the feature offset too needs at least 5",
            "collect more poses with different orientations",
        )
    spread = rotation_spread(B[:, :3, :3])
    if spread < min_rotation:
        raise DataError(
            f"the carrier orientations differ by at most {np.degrees(spread):.2f} deg; the feature offset "
            "cannot be separated from the camera translation",
            "rotate the flange between samples (tens of degrees about two axes) or give the feature position",
        )
    R, t, cond = _linear(c, B)
    q = np.linalg.lstsq(np.concatenate(B[:, :3, :3]), np.concatenate(c @ R.T + t - B[:, :3, 3]), rcond=None)[
        0
    ]
    inl = np.ones(n, bool)
    if robust and n >= 8:
        rng = np.random.default_rng(rng)
        best, best_med = None, np.inf
        for _ in range(trials):
            sub = rng.choice(n, 6, replace=False)
            try:
                Rs, ts, _ = _linear(c[sub], B[sub])
            except np.linalg.LinAlgError:
                continue
            qs = np.linalg.lstsq(
                np.concatenate(B[sub, :3, :3]), np.concatenate(c[sub] @ Rs.T + ts - B[sub, :3, 3]), rcond=None
            )[0]
            med = float(np.median(_resid(c, B, Rs, ts, qs) ** 2))
            if med < best_med:
                best, best_med = (Rs, ts, qs), med
        R, t, q = best
        sigma = 1.4826 * (1 + 5 / (n - 6)) * np.sqrt(best_med)
        for _ in range(5):
            r = _resid(c, B, R, t, q)
            new = r <= max(n_sigma * sigma, min_threshold)
            if new.sum() < 5:
                break
            inl = new
            R, t, q = _refine(c[inl], B[inl], R, t, q)
            sigma = 1.4826 * np.sqrt(np.median(_resid(c[inl], B[inl], R, t, q) ** 2))
    else:
        R, t, q = _refine(c, B, R, t, q)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return FeatureFit(T, q, _resid(c, B, R, t, q), inl, cond)
