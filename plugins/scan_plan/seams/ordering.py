"""Smoothing and ordering of a chained seam: positions (quadratic Savitzky-Golay), approach
directions (robust local quadratic), approach made orthogonal to travel."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import savgol_filter

from .model import _unit


def _smooth_positions(X: np.ndarray, window: int, closed: bool) -> np.ndarray:
    """Savitzky-Golay (quadratic) smoothing over ``window`` nodes: no shrinkage on curved seams."""
    n = len(X)
    w = min(int(window) | 1, n if closed else n - (1 - n % 2))
    if w < 5:
        return X
    if closed and w > n:
        w = n - (1 - n % 2)
    return savgol_filter(X, w, 2, axis=0, mode="wrap" if closed else "interp")


def _smooth_approach(
    A: np.ndarray, ok: np.ndarray, window: int, closed: bool, curved: bool = True
) -> np.ndarray:
    """Robust smoothing of the approach directions along a seam.

    A weighted moving average over ``window`` nodes (weight 0 where the side-plane fit failed) gives a
    reference; nodes further than 3x the median deviation (at least 2 deg) from it are dropped and the
    reference is taken again. On a ``curved`` seam the result is a local quadratic fit of the kept
    directions (a box average of a direction that turns along the seam is biased: by up to 2 deg on
    the Y-pipe's flanks); on a straight one, whose approach hardly turns, a quadratic Savitzky-Golay
    pass over the reference (the box average halves the noise a quadratic fit leaves: T-fillet 0.85
    vs 1.18 deg)."""
    if len(A) < 3:
        return _unit(A)
    mode = "wrap" if closed else "nearest"
    w = np.where(ok, 1.0, 1e-6)
    size = max(1, min(int(window), len(A)))
    for _ in range(2):
        num = uniform_filter1d(A * w[:, None], size=size, axis=0, mode=mode)
        den = uniform_filter1d(w, size=size, mode=mode)
        ref = _unit(num / np.maximum(den, 1e-12)[:, None])
        dev = np.arccos(np.clip(np.einsum("ij,ij->i", A, ref), -1.0, 1.0))
        lim = max(3.0 * float(np.median(dev[ok])) if ok.any() else 0.0, np.deg2rad(2.0))
        w = np.where(ok & (dev <= lim), 1.0, 1e-6)
    if not curved:
        return _unit(_smooth_positions(ref, window, closed))
    return _unit(_local_quadratic(A, w, window, closed))


def _local_quadratic(V: np.ndarray, w: np.ndarray, window: int, closed: bool) -> np.ndarray:
    """Weighted local quadratic regression of the rows of ``V`` (K, D) over ``window`` nodes (weights
    ``w``): a Savitzky-Golay filter that skips the down-weighted nodes. Open runs keep a full window at
    their ends (shifted inwards, as ``savgol_filter``'s ``interp`` mode)."""
    n = len(V)
    h = max(1, min(int(window), n) // 2)
    if not closed and n < 2 * h + 1:
        h = max(1, (n - 1) // 2)
    span = np.arange(-h, h + 1)
    if closed:
        idx = (np.arange(n)[:, None] + span[None, :]) % n
        s = np.broadcast_to(span.astype(float), idx.shape)
    else:
        lo = np.clip(np.arange(n) - h, 0, n - 2 * h - 1)
        idx = lo[:, None] + np.arange(2 * h + 1)[None, :]
        s = (idx - np.arange(n)[:, None]).astype(float)
    F = np.stack([np.ones_like(s), s, s * s], axis=-1)
    Fw = F * w[idx][..., None]
    M = np.matmul(Fw.transpose(0, 2, 1), F) + 1e-9 * np.eye(3)
    coef = np.linalg.solve(M, np.matmul(Fw.transpose(0, 2, 1), V[idx]))
    return coef[:, 0, :]


def _straight(X: np.ndarray, tol: float = 0.01) -> bool:
    """Whether the polyline ``X`` stays within ``tol`` x its length of its principal line."""
    C = X - X.mean(axis=0)
    u = np.linalg.svd(C, full_matrices=False)[2][0]
    off = np.linalg.norm(C - np.outer(C @ u, u), axis=1)
    return float(off.max()) <= tol * float(np.ptp(C @ u))


def _orthogonal_to_travel(X: np.ndarray, A: np.ndarray, closed: bool) -> np.ndarray:
    """The approach directions ``A`` without their component along the seam polyline ``X`` (central
    differences). Both side normals of a joint are perpendicular to its line, so their bisector is too;
    the fitted bisector is only perpendicular to the *fitted* crease line, whose direction is poorly
    determined where the side planes differ little or curve (the ~145 deg flanks and the acute toe of a
    pipe junction: 4-20 deg along the seam), while the smoothed polyline's is not. An open seam that
    stays within 1 % of its length of a straight line keeps its approach: its fitted crease direction is
    well determined, and the polyline's sub-millimetre steps (where pieces were joined) would tilt it by
    degrees (the demo job's V-groove: 0.67 -> 2.2 deg)."""
    if len(X) < 3 or (not closed and _straight(X)):
        return A
    T = (np.roll(X, -1, axis=0) - np.roll(X, 1, axis=0)) if closed else np.gradient(X, axis=0)
    T = _unit(T)
    return _unit(A - np.einsum("ij,ij->i", A, T)[:, None] * T)
