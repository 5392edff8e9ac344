"""Point-cloud denoising of the scan-and-plan method (paper 000, section II-D, eqs. 9-10).

:func:`bilateral_filter` -- eq. 10: each point moved along its normal by the bilateral-weighted mean of
its neighbours' normal offsets (normals of eq. 9 from :func:`~.cloud_numerics.pca_normals`).

The shared numerics (neighbour tables, spacing, noise, voxel grid, the 3x3 eigen-solver) live in
:mod:`~weldcell.plugins.scan_plan.cloud_numerics`; they are re-exported here for existing callers.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from weldcell.sdk.arrays import row_sums
from weldcell.sdk.errors import DataError

from .cloud_numerics import (  # noqa: F401  (re-exported for callers of the former module)
    PAIR_CHUNK,
    NeighbourTable,
    _check_positive,
    _chunks,
    _covariance_normals,
    _knn_normals,
    _pairs,
    as_points,
    knn_table,
    largest_eigvec,
    masked_covariance,
    mean_spacing,
    noise_level,
    offsets,
    orient_normals,
    pca_normals,
    radius_pairs,
    smallest_eigvec,
    sym3_eigvals,
    sym3_eigvec,
    voxel_downsample,
)


def bilateral_filter(
    points: np.ndarray,
    radius: float,
    sigma_c: float | None = None,
    sigma_s: float | None = None,
    normals: np.ndarray | None = None,
    iterations: int = 1,
    neighbours: NeighbourTable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Point-cloud bilateral filter, eqs. 9-10 (paper 000).

    For every point p with neighbours N_r(p) (distance <= ``radius``, p included) and unit normal n_p
    (PCA over N_r(p), eq. 9, unless ``normals`` are given for the first iteration)::

        dp = sum_q w_c(|q - p|) w_s(|<n_p, q - p>|) <n_p, q - p>  /  sum_q w_c(|q - p|) w_s(|<n_p, q - p>|)
        p' = p + dp * n_p

    with Gaussian weights ``w_c(x) = exp(-x^2 / (2 sigma_c^2))`` (spatial closeness) and
    ``w_s(x) = exp(-x^2 / (2 sigma_s^2))`` (normal distance, which keeps points across an edge from
    pulling p). Defaults: ``sigma_c = radius / 2``; ``sigma_s`` = 2x the current scan noise
    (:func:`noise_level`), re-estimated each iteration so it tightens as the cloud gets
    smoother. All points move simultaneously; normals are re-estimated every iteration.

    ``neighbours`` (a :func:`knn_table` of ``points``) replaces the radius search of the first
    iteration: N_r(p) is then the table's neighbours within ``radius``, and the noise level is the
    median over all points instead of a sample. Identical to the radius search where the table is wide
    enough (the k-th neighbour lies beyond ``radius``); rows where it does not are cut to the k nearest.
    Returns ``(points, normals)`` (the normals used in the last iteration).
    """
    P = as_points(points, min_points=3).copy()
    radius = _check_positive(radius, "radius")
    if iterations < 1:
        raise DataError(f"iterations must be >= 1, got {iterations}", "pass iterations=1 or more")
    sc = radius / 2.0 if sigma_c is None else _check_positive(sigma_c, "sigma_c")
    ss = None if sigma_s is None else _check_positive(sigma_s, "sigma_s")
    given = None
    if normals is not None:
        given = np.asarray(normals, dtype=float)
        if given.shape != P.shape or not np.all(np.isfinite(given)):
            raise DataError(
                f"normals must be a finite array of shape {P.shape}, got {given.shape}",
                "pass one unit normal per point, or normals=None to estimate them",
            )
        given = given / np.maximum(np.linalg.norm(given, axis=1, keepdims=True), 1e-12)
    N_out = np.empty_like(P)
    start = 0
    if neighbours is not None:
        if not neighbours.matches(points) and (
            neighbours.idx.shape[0] != len(P) or not np.array_equal(neighbours.points, P)
        ):
            raise DataError(
                "the neighbour table belongs to another cloud", "build it with knn_table(points, k)"
            )
        P, N_out = _bilateral_table(P, neighbours, radius, sc, ss, given)
        start = 1
    for it in range(start, iterations):
        tree = cKDTree(P)
        ss_it = max(2.0 * noise_level(P, radius), 1e-9) if ss is None else ss
        P_new = np.empty_like(P)
        for sl in _chunks(len(P)):
            m = sl.stop - sl.start
            rows, cols, dist = _pairs(P[sl], tree, radius)
            N = _covariance_normals(P, rows, cols, m)[0] if (it > 0 or given is None) else given[sl]
            h = np.einsum("ij,ij->i", N[rows], P[cols] - P[sl][rows])  # <n_p, q - p>
            w = np.exp(-(dist * dist) / (2.0 * sc * sc) - (h * h) / (2.0 * ss_it * ss_it))
            num = np.bincount(rows, weights=w * h, minlength=m)
            den = np.bincount(rows, weights=w, minlength=m)  # > 0: p is its own neighbour
            P_new[sl] = P[sl] + (num / den)[:, None] * N
            N_out[sl] = N
        P = P_new
    return P, N_out


def _bilateral_table(
    P: np.ndarray,
    nb: NeighbourTable,
    radius: float,
    sc: float,
    ss: float | None,
    given: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    """One pass of eq. 10 over the neighbours within ``radius`` of a :class:`NeighbourTable`."""
    if nb.radius < radius:
        raise DataError(
            f"the neighbour table reaches {nb.radius:g} m only, the filter needs {radius:g} m",
            "build the table with knn_table(points, k, radius) for at least the filter radius",
        )
    w = nb.dist <= radius
    w[:, 0] = True
    D = offsets(P, nb.idx)  # q - p (0 in the self column)
    C, cnt = masked_covariance(D, w)
    evals = sym3_eigvals(C)
    N = sym3_eigvec(C, evals[:, 0]) if given is None else given
    if ss is None:
        ok = cnt >= 4
        if not ok.any():
            raise DataError(
                f"no point has 4 neighbours within radius {radius:g} m",
                "increase the radius to a few times the point spacing (see mean_spacing)",
            )
        ss = max(2.0 * float(np.median(np.sqrt(np.maximum(evals[ok, 0], 0.0)))), 1e-9)
    h = D[0] * N[:, :1] + D[1] * N[:, 1:2] + D[2] * N[:, 2:]  # <n_p, q - p>
    d2 = np.where(w, nb.dist, 0.0) ** 2
    wt = np.exp(-d2 / (2.0 * sc * sc) - (h * h) / (2.0 * ss * ss)) * w
    dp = np.einsum("nk,nk->n", wt, h) / row_sums(wt)  # > 0: p is its own neighbour
    return P + dp[:, None] * N, N
