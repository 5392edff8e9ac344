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

When the feature is the centre of a plane face (a flange plate), its measured face normal ``n_i``
(camera frame) can weight the refinement: the component of each residual along the normal counts
``normal_weight`` times the in-plane ones. The face plane is measured from thousands of points with
no edge effects, while the circle centre of an obliquely seen rim drifts within the plane; an
in-plane drift that grows with the viewing angle is otherwise indistinguishable from ``q`` lying off
the face, and moves ``t_X`` along the optical axis.
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
    normals: np.ndarray | None = None  # per-sample face normals (camera) the refinement weighted
    normal_weight: float = 1.0


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


def rotation_diversity(R: np.ndarray) -> float:
    """How well (n, 3, 3) rotations ``R_i`` separate a point ``q`` from a translation in
    ``t + R_i q``: the rms of ``|R_i v - mean_i R_i v|`` over the samples for the worst unit vector
    ``v`` (about the rms rotation angle away from ``v``'s axis, rad for small angles). Rotations about
    one axis only score 0: ``q`` along that axis cannot be told from ``t``."""
    R = np.asarray(R, float).reshape(-1, 3, 3)
    D = R - R.mean(axis=0)
    M = np.einsum("nji,njk->ik", D, D) / max(len(R), 1)
    return float(np.sqrt(max(np.linalg.eigvalsh(M)[0], 0.0)))


def translation_sigma(c: np.ndarray, B: np.ndarray, fit: FeatureFit) -> float:
    """Predicted 1-sigma error (m) of ``X``'s translation from the fit's covariance on its inliers:
    ``sqrt(trace(cov_t))`` with ``cov = s^2 (J^T J)^-1`` and ``s^2`` the (weighted) residual variance."""
    c = np.asarray(c, float).reshape(-1, 3)[fit.inliers]
    B = np.asarray(B, float).reshape(-1, 4, 4)[fit.inliers]
    f = _residual_fn(c, B, _rows(fit.normals, fit.inliers), fit.normal_weight)
    x = np.concatenate([Rotation.from_matrix(fit.T[:3, :3]).as_rotvec(), fit.T[:3, 3], fit.q])
    h = 1e-6
    J = np.stack([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(9)], axis=1)
    dof = J.shape[0] - 9
    if dof <= 0:
        return float("inf")
    s2 = float(np.sum(f(x) ** 2)) / dof
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return float("inf")
    return float(np.sqrt(max(np.trace(cov[3:6, 3:6]), 0.0)))


def _rows(a: np.ndarray | None, idx) -> np.ndarray | None:
    return None if a is None else a[idx]


def _residual_fn(c: np.ndarray, B: np.ndarray, N: np.ndarray | None = None, w: float = 1.0):
    """Stacked residuals ``X c_i - B_i q`` of the parameters (rotvec of R_X, t_X, q); with normals
    ``N`` (camera frame) the component along ``R_X n_i`` is scaled by ``w``."""

    def f(x: np.ndarray) -> np.ndarray:
        Rx = Rotation.from_rotvec(x[:3]).as_matrix()
        r = c @ Rx.T + x[3:6] - (B[:, :3, :3] @ x[6:9] + B[:, :3, 3])
        if N is not None and w != 1.0:
            nf = N @ Rx.T
            r = r + (w - 1.0) * nf * np.sum(nf * r, axis=1, keepdims=True)
        return r.ravel()

    return f


def _resid(c, B, R, t, q):
    return np.linalg.norm(c @ R.T + t - (B[:, :3, :3] @ q + B[:, :3, 3]), axis=1)


def _refine(c, B, R, t, q, N=None, w=1.0):
    x0 = np.concatenate([Rotation.from_matrix(R).as_rotvec(), t, q])
    sol = least_squares(_residual_fn(c, B, N, w), x0, method="lm")
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
    normals: np.ndarray | None = None,
    normal_weight: float = 1.0,
) -> FeatureFit:
    """Solve ``X c_i = B_i q`` for ``X`` and ``q`` (see module doc); robust to outliers by least
    median of squares over 6-sample subsets when ``robust``. Raises DataError when the rotations of
    ``B_i`` are too similar to separate ``q`` from ``X``'s translation. ``normals`` (n, 3, camera
    frame) with ``normal_weight`` > 1 weight the refinement along each face normal (module doc)."""
    c = np.asarray(c, dtype=float).reshape(-1, 3)
    B = np.asarray(B, dtype=float).reshape(-1, 4, 4)
    n = len(c)
    N = None
    if normals is not None:
        N = np.asarray(normals, dtype=float).reshape(-1, 3)
        if len(N) != n or not np.all(np.isfinite(N)) or np.any(np.linalg.norm(N, axis=1) < 1e-9):
            raise DataError(
                f"{len(N)} face normals for {n} samples (or zero/NaN normals)",
                "give one finite face normal (camera frame) per sample, or none",
            )
        N = N / np.linalg.norm(N, axis=1, keepdims=True)
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
            R, t, q = _refine(c[inl], B[inl], R, t, q, _rows(N, inl), normal_weight)
            sigma = 1.4826 * np.sqrt(np.median(_resid(c[inl], B[inl], R, t, q) ** 2))
    else:
        R, t, q = _refine(c, B, R, t, q, N, normal_weight)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return FeatureFit(T, q, _resid(c, B, R, t, q), inl, cond, N, float(normal_weight))
