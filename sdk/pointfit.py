"""Point-set registration: the least-squares rigid (or similarity) transform between matched point
sets, by the SVD of their cross-covariance (Umeyama 1991; paper 003 §2.1.3, eqs. 9-12), one fit, a
batch of fits, and a robust (outlier-rejecting) fit.

Used by flange-based hand-eye calibration (the flange centre is known in the base from the controller
and measured in the camera from the point cloud: eq. 9 ``dst_i = H @ src_i``) and by anything else
that aligns matched points (e.g. scoring a calibration against samples).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from weldcell.sdk.errors import DataError


@dataclass
class PointFit:
    """A fitted transform ``T_dst_src`` (rigid, 4x4), the similarity scale ``c`` of eq. 11 and the
    per-pair residuals ``|T src_i - dst_i|`` in the units of the input."""

    T: np.ndarray
    scale: float
    residuals: np.ndarray
    reflection_guarded: bool


def scaled_svd_fit(src: np.ndarray, dst: np.ndarray, with_scale: bool = False) -> PointFit:
    """Least-squares transform with ``dst_i ~ c R src_i + t`` (paper eqs. 10-12).

    ``R = U S V^T`` (eq. 10a) from the SVD ``U D V^T`` of the cross-covariance Σ (eq. 11); ``S``
    flips the last axis when the best orthogonal matrix would be a reflection (eq. 12). Unlike
    eq. 12's ``det(Σ) < 0`` test, the sign is taken from ``det(U) det(V)``, which equals it for
    full-rank Σ and stays right for coplanar points (det Σ = 0), where eq. 12 would let a reflection
    through. ``c = tr(D S) / var(src)`` (eq. 11) is always computed and returned; it is applied to
    the translation (eq. 10b) only with ``with_scale=True``. A hand-eye transform is rigid, so the
    default keeps ``c = 1`` in ``T`` and reports the estimate (``c`` far from 1 means unit mix-up).
    """
    src = np.asarray(src, dtype=float).reshape(-1, 3)
    dst = np.asarray(dst, dtype=float).reshape(-1, 3)
    if len(src) != len(dst):
        raise DataError(f"{len(src)} source points but {len(dst)} target points", "pass matched pairs")
    if len(src) < 3:
        raise DataError(
            f"{len(src)} point pairs; a rigid fit needs at least 3 non-collinear ones",
            "collect more robot poses",
        )
    if not (np.all(np.isfinite(src)) and np.all(np.isfinite(dst))):
        raise DataError("point pairs contain NaN or infinite values", "drop the failed measurements")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    S0, D0 = src - mu_s, dst - mu_d
    sigma = D0.T @ S0 / len(src)  # eq. 11, Σ = 1/n Σ (dst - μ)(src - μ)^T
    U, d, Vt = np.linalg.svd(sigma)
    s = np.ones(3)
    guarded = bool(np.linalg.det(U) * np.linalg.det(Vt) < 0)
    if guarded:
        s[2] = -1.0  # eq. 12
    R = U @ np.diag(s) @ Vt  # eq. 10a
    var_src = float(np.mean(np.sum(S0**2, axis=1)))
    c = float(np.sum(d * s) / var_src) if var_src > 0 else float("nan")  # eq. 11
    c_t = c if with_scale else 1.0
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = mu_d - c_t * R @ mu_s  # eq. 10b
    res = np.linalg.norm(c_t * src @ R.T + T[:3, 3] - dst, axis=1)
    if with_scale:
        T[:3, :3] = c_t * R
    return PointFit(T, c, res, guarded)


def rigid_fit_batch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rigid fits (eqs. 10-12 with c = 1) for a batch: ``src``, ``dst`` (B, k, 3) -> (B, 4, 4)."""
    src = np.asarray(src, dtype=float)
    dst = np.asarray(dst, dtype=float)
    mu_s, mu_d = src.mean(1, keepdims=True), dst.mean(1, keepdims=True)
    sigma = np.einsum("bki,bkj->bij", dst - mu_d, src - mu_s)
    U, _, Vt = np.linalg.svd(sigma)
    sign = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    sign[sign == 0] = 1.0
    U = U.copy()
    U[:, :, 2] *= sign[:, None]
    R = U @ Vt
    T = np.tile(np.eye(4), (len(src), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = mu_d[:, 0] - np.einsum("bij,bj->bi", R, mu_s[:, 0])
    return T


def batch_residuals(T: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Residuals ``|T_b src_i - dst_i|`` for transforms (B, 4, 4) on all pairs (n, 3) -> (B, n)."""
    pred = np.einsum("bij,nj->bni", T[:, :3, :3], src) + T[:, None, :3, 3]
    return np.linalg.norm(pred - dst[None], axis=2)


@dataclass
class RobustFit:
    """Least-median-of-squares fit refined by least squares on its inliers."""

    T: np.ndarray
    residuals: np.ndarray
    inliers: np.ndarray
    threshold: float
    sigma: float


def robust_point_fit(
    src: np.ndarray,
    dst: np.ndarray,
    threshold: float | None = None,
    n_sigma: float = 3.0,
    min_threshold: float = 0.0,
    trials: int = 500,
    rng: np.random.Generator | int | None = 0,
) -> RobustFit:
    """Outlier-proof rigid fit: least median of squares over random 4-pair subsets, then a
    robust scale ``σ = 1.4826 (1 + 5/(n-4)) sqrt(med r²)`` (Rousseeuw), inliers ``r <= n_sigma σ``
    (or ``r <= threshold`` when given), and eqs. 10-12 on the inliers, repeated until the inlier set
    is stable. Tolerates up to half the pairs being wrong (e.g. false flange segmentations)."""
    src = np.asarray(src, dtype=float).reshape(-1, 3)
    dst = np.asarray(dst, dtype=float).reshape(-1, 3)
    n = len(src)
    if n < 5:
        fit = scaled_svd_fit(src, dst)
        return RobustFit(fit.T, fit.residuals, np.ones(n, bool), float("inf"), float("nan"))
    rng = np.random.default_rng(rng)
    idx = np.argsort(rng.random((trials, n)), axis=1)[:, :4]
    T = rigid_fit_batch(src[idx], dst[idx])
    r = batch_residuals(T, src, dst)
    med = np.median(r**2, axis=1)
    best = int(np.argmin(med))
    sigma = 1.4826 * (1.0 + 5.0 / (n - 4)) * float(np.sqrt(med[best]))
    thr = threshold if threshold is not None else max(n_sigma * sigma, min_threshold)
    inl = r[best] <= thr
    Tb = T[best]
    for _ in range(10):
        if inl.sum() < 3:
            break
        fit = scaled_svd_fit(src[inl], dst[inl])
        Tb = fit.T
        res = np.linalg.norm(src @ Tb[:3, :3].T + Tb[:3, 3] - dst, axis=1)
        if threshold is None:
            sigma = 1.4826 * float(np.sqrt(np.median(res[inl] ** 2)))
            thr = max(n_sigma * sigma, min_threshold)
        new = res <= thr
        if np.array_equal(new, inl):
            break
        inl = new
    res = np.linalg.norm(src @ Tb[:3, :3].T + Tb[:3, 3] - dst, axis=1)
    return RobustFit(Tb, res, inl, float(thr), float(sigma))
