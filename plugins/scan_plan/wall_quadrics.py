"""Curved-wall seam nodes: each side of a crease fitted as a quadric height field, intersected at the
crease as tangent planes.

A plane fitted to a curved wall has the normal and the height of the patch's centroid, not of the
crease: over an 8 mm patch of a 40 mm pipe it is tilted by ~2 deg about the seam, and walls that curve
*along* the seam (the main pipe under a branch's toe) sink both planes below the crease, so their
intersection lies up to 1.5 mm too deep (measured on the Y-pipe, noise-free, docs/methods/seams-and-
paths.md). Here each wall is the height ``h(u, t)`` above its fitted plane, ``u`` across the crease
(from the crease line, in the plane), ``t`` along it, modelled as the full quadric
``c0 + c1 u + c2 u^2 + c3 t + c4 t u + c5 t^2``. The wall's tangent plane at the node (u = t = 0) has
the height ``c0`` and the slopes ``c1``, ``c3``; two tangent planes meet in the corrected crease.

Noise: the fit uses every point of the wall within the patch radius with Gaussian weights
(``sigma``), so the slopes at the crease are averaged over thousands of points; on a strongly curved
wall, which a quadric follows over a short distance only, sigma shrinks with the curvature of a first
fit (``CURVATURE_SIGMA``); points closer than
``u_min`` to the crease are left out (the sensor and the bilateral filter round the crease over about
the filter radius, which would read as the wall bending towards the other side), and one robust pass
drops points further than ``tol`` from the first fit (a third surface, stray points).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the Gaussian weight's sigma as a fraction of the patch radius (a patch of 4 sigma: the weights are
#: not cut off; sigma 8 mm at the default 32 mm patch: noise averaged over ~2000 points per wall, while
#: the quartic terms of a 30 mm pipe wall, which a quadric cannot follow, still bias the slope < 0.2 deg)
SIGMA_FRACTION = 0.25
#: on a wall of curvature kappa (1/m, from a first fit) the Gaussian's sigma is at most
#: CURVATURE_SIGMA / kappa -- the Y-pipe's 30-40 mm walls keep the full 8 mm, a 20 mm post gets 6 mm
#: (its root 0.115 -> 0.028 mm off, noise-free) -- but not below MIN_SIGMA_FRACTION of the default
CURVATURE_SIGMA = 0.3
MIN_SIGMA_FRACTION = 0.4
#: at least this many points per wall, else the wall keeps its plane
MIN_WALL_POINTS = 20


@dataclass(frozen=True)
class TangentPlanes:
    """Per node (B,): the two walls' unit normals at the crease, a point of each tangent plane (relative
    to the node, m) and whether both walls had enough points for the quadric."""

    n_a: np.ndarray
    p_a: np.ndarray
    n_b: np.ndarray
    p_b: np.ndarray
    ok: np.ndarray


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _dot(Q: tuple[np.ndarray, ...], v: np.ndarray) -> np.ndarray:
    return Q[0] * v[:, 0:1] + Q[1] * v[:, 1:2] + Q[2] * v[:, 2:3]


def _weighted_lstsq(F: np.ndarray, h: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row: coefficients minimising ``sum w (F c - h)^2`` (F (B, K, p), h and w (B, K)) and a mask of
    the rows with at least ``MIN_WALL_POINTS`` weighted points."""
    Fw = F * w[..., None]
    M = np.matmul(Fw.transpose(0, 2, 1), F)
    rhs = np.matmul(Fw.transpose(0, 2, 1), h[..., None])[..., 0]
    good = (w > 0).sum(axis=1) >= MIN_WALL_POINTS
    M[~good] = np.eye(F.shape[-1])
    rhs[~good] = 0.0
    return np.linalg.solve(M + 1e-12 * np.eye(F.shape[-1]), rhs[..., None])[..., 0], good


def _wall(
    Q: tuple[np.ndarray, ...],
    side: np.ndarray,
    n: np.ndarray,
    d: np.ndarray,
    t: np.ndarray,
    c: np.ndarray,
    u_min: float,
    sigma: float,
    band: float,
    tol: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tangent plane at the crease of one wall: unit normal, point (relative to the node) and mask."""
    u_dir = _unit(np.cross(t, n))
    U = _dot(Q, u_dir) - np.einsum("ij,ij->i", c, u_dir)[:, None]
    flip = np.where(side, U, 0.0).sum(axis=1) < 0  # u grows away from the crease, into the wall
    u_dir[flip] *= -1.0
    U[flip] *= -1.0
    T = _dot(Q, t) - np.einsum("ij,ij->i", c, t)[:, None]
    h = _dot(Q, n) - d[:, None]
    use = side & (U > u_min) & (np.abs(h) < band)

    def fit(sig: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        s = (1.0 / sig)[:, None]  # features in units of sigma: a well-conditioned system at any scale
        us, ts = U * s, T * s
        F = np.stack([np.ones_like(U), us, us * us, ts, ts * us, ts * ts], axis=-1)
        coef, good = _weighted_lstsq(F, h, np.where(keep, np.exp(-0.5 * (us * us + ts * ts)), 0.0))
        return coef, good, F, s[:, 0]

    sig = np.full(len(U), sigma)
    coef, good, F, s = fit(sig, use)
    # a strongly curved wall (a small pipe) leaves the quadric within the patch: shrink sigma to
    # CURVATURE_SIGMA / curvature (principal curvature of the first fit, 1/m)
    H = np.stack([2 * coef[:, 2], coef[:, 4], coef[:, 4], 2 * coef[:, 5]], axis=1).reshape(-1, 2, 2)
    kappa = np.abs(np.linalg.eigvalsh(H)).max(axis=1) * s * s
    sig = np.clip(CURVATURE_SIGMA / np.maximum(kappa, 1e-9), MIN_SIGMA_FRACTION * sigma, sigma)
    coef, good2, F, s = fit(sig, use)
    resid = h - np.einsum("bki,bi->bk", F, coef)
    coef, good3, F, s = fit(sig, use & (np.abs(resid) < tol))
    good &= good2 & good3
    slope_u = np.where(good, coef[:, 1] * s, 0.0)
    slope_t = np.where(good, coef[:, 3] * s, 0.0)
    normal = _unit(n - slope_u[:, None] * u_dir - slope_t[:, None] * t)
    point = c + np.where(good, coef[:, 0], 0.0)[:, None] * n
    return normal, point, good


def tangent_planes(
    Q: tuple[np.ndarray, ...],
    valid: np.ndarray,
    n_a: np.ndarray,
    d_a: np.ndarray,
    n_b: np.ndarray,
    d_b: np.ndarray,
    *,
    radius: float,
    u_min: float,
    band: float,
    tol: float,
) -> TangentPlanes:
    """The two walls' tangent planes at the crease of each node.

    ``Q`` = (x, y, z) offsets (each (B, K)) of the points around each node, ``valid`` (B, K) those to
    use (within ``radius``); ``n_a . q = d_a`` and ``n_b . q = d_b`` the two side planes fitted around
    the node (normals pointing into the air). Points are split between the walls by the plane that
    bisects the crease (robust where a curved wall strays from its plane); ``band`` (m): farther than
    this from a wall's plane a point is not on that wall; ``u_min``, ``tol``: see the module docstring.
    """
    t = _unit(np.cross(n_a, n_b))
    c = _line_point(n_a, d_a, n_b, d_b)
    m = _unit(n_a - n_b)
    bis = _dot(Q, m) - np.einsum("ij,ij->i", c, m)[:, None]
    sigma = SIGMA_FRACTION * radius
    na2, pa, ok_a = _wall(Q, valid & (bis < 0), n_a, d_a, t, c, u_min, sigma, band, tol)
    nb2, pb, ok_b = _wall(Q, valid & (bis > 0), n_b, d_b, t, c, u_min, sigma, band, tol)
    return TangentPlanes(na2, pa, nb2, pb, ok_a & ok_b)


def crease_point(tp: TangentPlanes) -> np.ndarray:
    """The point of the two tangent planes' intersection line nearest the node (B, 3), relative to it."""
    d_a = np.einsum("ij,ij->i", tp.n_a, tp.p_a)
    d_b = np.einsum("ij,ij->i", tp.n_b, tp.p_b)
    return _line_point(tp.n_a, d_a, tp.n_b, d_b)


def _line_point(n_a: np.ndarray, d_a: np.ndarray, n_b: np.ndarray, d_b: np.ndarray) -> np.ndarray:
    """Per row, the point of the line where the planes ``n_a . x = d_a`` and ``n_b . x = d_b`` meet that
    is nearest the origin (the minimum-norm solution; the origin where the planes are parallel)."""
    A = np.stack([n_a, n_b], axis=1)
    G = np.matmul(A, A.transpose(0, 2, 1))
    G[np.abs(np.linalg.det(G)) < 1e-9] = np.eye(2)
    return np.einsum("bij,bi->bj", A, np.linalg.solve(G, np.stack([d_a, d_b], axis=1)[..., None])[..., 0])
