"""Point-cloud denoising of the scan-and-plan method (paper 000, section II-D, eqs. 9-10).

* :func:`radius_pairs` -- all neighbour pairs within a radius, as flat (COO) arrays, built in C by
  scipy's ``cKDTree.sparse_distance_matrix`` in chunks (bounded memory, no per-point Python loop);
* :func:`pca_normals` -- eq. 9: the normal of the least-squares plane through each point's neighbours;
* :func:`bilateral_filter` -- eq. 10: each point moved along its normal by the bilateral-weighted mean
  of its neighbours' normal offsets;
* :func:`voxel_downsample` / :func:`mean_spacing` -- the down-sampling with a voxel size that is a
  multiple of the mean point spacing.

Every per-neighbour sum is a ``np.bincount`` over the flat pair arrays.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.spatial import cKDTree
from weldcell.sdk.errors import DataError

#: rows of query points per chunk of the radius search (bounds the memory of the pair arrays)
PAIR_CHUNK = 100_000


def as_points(points: np.ndarray, what: str = "points", min_points: int = 1) -> np.ndarray:
    """``points`` as a finite float (N, 3) array, or :class:`DataError` saying what is wrong."""
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3:
        raise DataError(
            f"{what} must be an (N, 3) array, got shape {P.shape}", "pass x, y, z columns in metres"
        )
    if len(P) < min_points:
        raise DataError(
            f"{what} has {len(P)} points; at least {min_points} are needed",
            "check that the scan saw the workpiece and that cropping kept it",
        )
    if not np.all(np.isfinite(P)):
        bad = int((~np.all(np.isfinite(P), axis=1)).sum())
        raise DataError(
            f"{what} has {bad} points with NaN or infinite coordinates",
            "drop invalid points first (weldcell.sdk.cloud.drop_invalid)",
        )
    return P


def _check_positive(value: float, name: str) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0.0:
        raise DataError(f"{name} must be a positive number of metres, got {value}", f"pass a {name} > 0")
    return value


def _pairs(query: np.ndarray, tree: cKDTree, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(rows, cols, dist)`` of all pairs ``|query[rows] - tree.data[cols]| <= radius`` (rows local)."""
    rec = cKDTree(query).sparse_distance_matrix(tree, radius, output_type="ndarray")
    return rec["i"], rec["j"], rec["v"]


def _chunks(n: int) -> Iterator[slice]:
    for start in range(0, n, PAIR_CHUNK):
        yield slice(start, min(start + PAIR_CHUNK, n))


def radius_pairs(
    points: np.ndarray, radius: float, tree: cKDTree | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All ordered neighbour pairs within ``radius`` (each point is its own neighbour).

    Returns flat arrays ``rows, cols, dist`` (unsorted COO form of the neighbourhoods N_r(p)).
    """
    P = as_points(points)
    radius = _check_positive(radius, "radius")
    tree = tree if tree is not None else cKDTree(P)
    parts = [_pairs(P[sl], tree, radius) for sl in _chunks(len(P))]
    offs = [sl.start for sl in _chunks(len(P))]
    rows = np.concatenate([p[0] + o for p, o in zip(parts, offs, strict=True)])
    cols = np.concatenate([p[1] for p in parts])
    dist = np.concatenate([p[2] for p in parts])
    return rows, cols, dist


def _covariance_normals(
    P: np.ndarray, rows: np.ndarray, cols: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Covariance of the neighbours ``P[cols]`` of each of ``n`` query rows (eq. 9).

    Returns (normals = eigenvector of the smallest eigenvalue, eigenvalues ascending (n, 3), counts).
    """
    cnt = np.bincount(rows, minlength=n)
    Q = P[cols]
    safe = np.maximum(cnt, 1).astype(float)[:, None]
    mean = np.stack([np.bincount(rows, weights=Q[:, k], minlength=n) for k in range(3)], axis=1) / safe
    D = Q - mean[rows]
    C = np.empty((n, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            C[:, a, b] = C[:, b, a] = np.bincount(rows, weights=D[:, a] * D[:, b], minlength=n)
    C /= safe[:, :, None]
    evals, evecs = np.linalg.eigh(C)
    return evecs[:, :, 0], evals, cnt


def orient_normals(normals: np.ndarray, points: np.ndarray, viewpoint: np.ndarray | None) -> np.ndarray:
    """Flip normals to face ``viewpoint`` (e.g. the camera centre); unchanged when it is None."""
    if viewpoint is None:
        return normals
    flip = np.einsum("ij,ij->i", normals, np.asarray(viewpoint, dtype=float) - points) < 0
    normals = normals.copy()
    normals[flip] *= -1.0
    return normals


def pca_normals(
    points: np.ndarray,
    *,
    radius: float | None = None,
    k: int = 20,
    viewpoint: np.ndarray | None = None,
    min_neighbors: int = 3,
) -> np.ndarray:
    """Unit normals by PCA of each point's neighbourhood, eq. 9 (paper 000).

    ``n_p = argmin_n sum_i ((q_i - p_c)^T n)^2`` is the eigenvector of the smallest eigenvalue of the
    neighbourhood covariance. Neighbours are the points within ``radius`` (the paper's N_r(p)) or,
    when ``radius`` is None, the ``k`` nearest. Points with fewer than ``min_neighbors`` neighbours fall
    back to their ``k`` nearest. Normals are flipped towards ``viewpoint`` when given.
    """
    P = as_points(points, min_points=3)
    tree = cKDTree(P)
    if radius is not None:
        radius = _check_positive(radius, "radius")
        normals = np.empty_like(P)
        counts = np.empty(len(P), dtype=np.int64)
        for sl in _chunks(len(P)):
            rows, cols, _ = _pairs(P[sl], tree, radius)
            normals[sl], _, counts[sl] = _covariance_normals(P, rows, cols, sl.stop - sl.start)
        few = np.flatnonzero(counts < min_neighbors)
        if len(few):
            normals[few] = _knn_normals(P, tree, min(k, len(P)), few)
    else:
        normals = _knn_normals(P, tree, min(k, len(P)), None)
    return orient_normals(normals, P, viewpoint)


def _knn_normals(P: np.ndarray, tree: cKDTree, k: int, subset: np.ndarray | None) -> np.ndarray:
    Xq = P if subset is None else P[subset]
    _, idx = tree.query(Xq, k=max(k, 3), workers=-1)
    Q = P[idx]
    D = Q - Q.mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", D, D)
    return np.linalg.eigh(C)[1][:, :, 0]


def mean_spacing(points: np.ndarray) -> float:
    """Mean distance from each point to its nearest other point (the paper's "average distance")."""
    P = as_points(points, min_points=2)
    d, _ = cKDTree(P).query(P, k=2, workers=-1)
    return float(np.mean(d[:, 1]))


def noise_level(points: np.ndarray, radius: float, sample: int = 20_000, seed: int = 0) -> float:
    """Robust estimate (m) of the scan noise: median over points of the RMS distance of their
    neighbours within ``radius`` to the PCA plane (sqrt of the smallest covariance eigenvalue).
    At most ``sample`` query points are used (neighbours come from the whole cloud)."""
    P = as_points(points, min_points=3)
    radius = _check_positive(radius, "radius")
    q = P
    if len(P) > sample:
        q = P[np.random.default_rng(seed).choice(len(P), sample, replace=False)]
    rows, cols, _ = _pairs(q, cKDTree(P), radius)
    _, evals, counts = _covariance_normals(P, rows, cols, len(q))
    ok = counts >= 4
    if not ok.any():
        raise DataError(
            f"no point has 4 neighbours within radius {radius:g} m",
            "increase the radius to a few times the point spacing (see mean_spacing)",
        )
    return float(np.median(np.sqrt(np.maximum(evals[ok, 0], 0.0))))


def bilateral_filter(
    points: np.ndarray,
    radius: float,
    sigma_c: float | None = None,
    sigma_s: float | None = None,
    normals: np.ndarray | None = None,
    iterations: int = 1,
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
    for it in range(iterations):
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


def voxel_downsample(
    points: np.ndarray,
    factor: float = 2.0,
    spacing: float | None = None,
    *,
    voxel_size: float | None = None,
    normals: np.ndarray | None = None,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Voxel-grid down-sampling with a voxel ``factor`` x the mean point spacing (paper 000, II-D).

    ``spacing`` overrides the measured mean spacing; ``voxel_size`` (m) overrides both. Each occupied
    voxel is replaced by the centroid of its points (normals, when given, are averaged and
    re-normalised and returned as a second array).
    """
    P = as_points(points)
    if voxel_size is None:
        _check_positive(factor, "factor")
        sp = mean_spacing(P) if spacing is None else _check_positive(spacing, "spacing")
        voxel_size = factor * sp
    v = _check_positive(voxel_size, "voxel_size")
    keys = np.floor(P / v).astype(np.int64)  # a grid anchored at the origin: re-voxelising is stable
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    if float(np.prod(dims.astype(float))) < 2**62:
        flat = np.ravel_multi_index(keys.T, dims)
        _, inv = np.unique(flat, return_inverse=True)
    else:
        _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    m = int(inv.max()) + 1
    cnt = np.bincount(inv, minlength=m).astype(float)
    out = np.stack([np.bincount(inv, weights=P[:, k], minlength=m) for k in range(3)], axis=1) / cnt[:, None]
    if normals is None:
        return out
    Nrm = np.asarray(normals, dtype=float)
    if Nrm.shape != P.shape:
        raise DataError(
            f"normals shape {Nrm.shape} does not match points {P.shape}", "pass one normal per point"
        )
    nout = np.stack([np.bincount(inv, weights=Nrm[:, k], minlength=m) for k in range(3)], axis=1)
    nout /= np.maximum(np.linalg.norm(nout, axis=1, keepdims=True), 1e-12)
    return out, nout
