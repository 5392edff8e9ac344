"""Point-cloud numerics of the scan-and-plan package: one home for what every step shares.

* :func:`as_points` -- the (N, 3) finite-array check every entry point runs;
* :func:`radius_pairs` -- all neighbour pairs within a radius, as flat (COO) arrays, built in C by
  scipy's ``cKDTree.sparse_distance_matrix`` in chunks (bounded memory, no per-point Python loop);
* :func:`pca_normals` -- eq. 9: the normal of the least-squares plane through each point's neighbours
  (:func:`knn_normals`: with the k nearest, for all points or a subset);
* :func:`mean_spacing` / :func:`noise_level` -- the cloud's own scale and noise (what the stages derive
  their radii and thresholds from);
* :func:`voxel_downsample` -- the down-sampling on a tilted voxel grid;
* :func:`knn_table` -- one k-nearest-neighbour query, a :class:`weldcell.sdk.cloud.NeighbourTable` the
  bilateral filter and the seam stage share (the denoiser attaches it to its output cloud);
  :func:`offsets` / :func:`masked_covariance` over its rows;
* :func:`sym3_eigvals` / :func:`smallest_eigvec` / :func:`largest_eigvec` -- a closed-form 3x3 symmetric
  eigen-solver for the many small covariance matrices (eq. 9 and the seam stage's plane fits).

Data flows one way: capture -> reconstruct -> denoise -> seams -> paths -> metrics all import from here,
and this module imports none of them.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.spatial import cKDTree
from weldcell.sdk.arrays import col_max, col_min, row_sums
from weldcell.sdk.cloud import NeighbourTable  # the table type lives in the sdk: clouds carry it
from weldcell.sdk.errors import DataError

#: rows of query points per chunk of the radius search (bounds the memory of the pair arrays)
PAIR_CHUNK = 100_000
#: axes of the voxel grid of :func:`voxel_downsample`: a fixed, generic rotation of the cloud's frame
#: (0.61 rad about (0.3, -0.5, 0.7)), so that no surface a cell commonly presents (a table, a plate, a wall
#: along x, y or z) lies parallel to a grid plane. On an axis-aligned grid the noise of such a surface
#: (a D415: +-0.8 mm) straddles the grid planes at one phase everywhere, and the voxel centroids form
#: layers whose mean is off the surface: the Table I cylinder's plate came out 0.23 mm high and its seam
#: 0.28 mm off. On a tilted grid the phase varies along the surface and the bias averages out (0.09 mm).
_GRID_AXES = np.array(
    [
        [0.839204256874283, -0.47275634152539187, -0.2687706397499727],
        [0.4075688780960471, 0.8739709040366003, -0.2646931591578772],
        [0.36003308855105526, 0.11258907782273948, 0.926120874780076],
    ]
)


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
    evals = sym3_eigvals(C)
    return sym3_eigvec(C, evals[:, 0]), evals, cnt


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
            normals[few] = knn_normals(P, tree, min(k, len(P)), few)
    else:
        normals = knn_normals(P, tree, min(k, len(P)), None)
    return orient_normals(normals, P, viewpoint)


def knn_normals(P: np.ndarray, tree: cKDTree, k: int, subset: np.ndarray | None) -> np.ndarray:
    """Eq. 9 with the ``k`` nearest points: the PCA normal (unoriented) of every point of ``P`` (or of
    the points ``subset``), neighbours searched in ``tree`` (a KD-tree of ``P``)."""
    Xq = P if subset is None else P[subset]
    _, idx = tree.query(Xq, k=max(k, 3), workers=-1)
    Q = P[idx]
    D = Q - Q.mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", D, D)
    return smallest_eigvec(C)


_knn_normals = knn_normals  # the former private name (denoise re-exports it)


def mean_spacing(
    points: np.ndarray, sample: int | None = None, seed: int = 0, tree: cKDTree | None = None
) -> float:
    """Mean distance from each point to its nearest other point (the paper's "average distance").

    With ``sample``, the mean over that many randomly chosen points (seeded; their nearest neighbours
    are searched in the whole cloud): an unbiased estimate at a fraction of the cost for big clouds.
    ``tree``: a KD-tree of ``points`` to reuse.
    """
    P = as_points(points, min_points=2)
    q = P
    if sample is not None and len(P) > sample:
        q = P[np.random.default_rng(seed).choice(len(P), int(sample), replace=False)]
    tree = tree if tree is not None else cKDTree(P, balanced_tree=False, compact_nodes=False)
    d, _ = tree.query(q, k=2, workers=-1)
    return float(np.mean(d[:, 1]))


def knn_table(
    points: np.ndarray, k: int, radius: float = float("inf"), tree: cKDTree | None = None
) -> NeighbourTable:
    """One query for the (at most) ``k`` nearest neighbours within ``radius`` of every point, plus the
    point itself (2 threads): :meth:`weldcell.sdk.cloud.NeighbourTable.search` after this package's point
    check. A finite ``radius`` makes the search ~2-3x faster than an unbounded one."""
    return NeighbourTable.search(as_points(points, min_points=2), k, radius, tree)


def offsets(P: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Neighbour offsets ``q - p`` as three (N, K) arrays (x, y, z) for neighbour indices ``idx`` (N, K).

    One contiguous gather per coordinate is ~4x faster than gathering (N, K, 3) rows.
    """
    Pt = np.ascontiguousarray(np.asarray(P, dtype=float).T)
    return tuple(Pt[j][idx] - Pt[j][:, None] for j in range(3))


def masked_covariance(D: tuple[np.ndarray, ...], w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Covariance (N, 3, 3) of the rows of offsets ``D`` = (x, y, z), each (N, K), weighted by ``w``
    (N, K; a boolean mask or weights), and the weight sums (N,)."""
    wf = np.asarray(w, dtype=float)
    cnt = row_sums(wf)
    inv = 1.0 / np.maximum(cnt, 1e-300)
    Dw = [d * wf for d in D]
    mean = [row_sums(dw) * inv for dw in Dw]
    C = np.empty((len(wf), 3, 3))
    for a in range(3):
        for b in range(a, 3):
            C[:, a, b] = C[:, b, a] = np.einsum("nk,nk->n", Dw[a], D[b]) * inv - mean[a] * mean[b]
    return C, cnt


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
    # a grid anchored at the origin (re-voxelising is stable), tilted by _GRID_AXES
    keys = np.floor((P @ _GRID_AXES) / v).astype(np.int64)
    keys -= col_min(keys)
    dims = col_max(keys) + 1
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


# ----------------------------------------------------------------------------- 3x3 symmetric eigen-solver


def sym3_eigvals(C: np.ndarray) -> np.ndarray:
    """Eigenvalues (..., 3), ascending, of symmetric 3x3 matrices (..., 3, 3) in closed form.

    The trigonometric solution of the characteristic cubic (Smith 1961): with ``q = tr(C)/3``,
    ``p = sqrt(tr((C - qI)^2)/6)`` and ``r = det((C - qI)/p)/2``, the eigenvalues are
    ``q + 2p cos(arccos(r)/3 + 2 pi k/3)``. About 10x faster than ``np.linalg.eigh`` on many small
    matrices; the absolute error is ~1e-15 x the largest eigenvalue (float64).
    """
    C = np.asarray(C, dtype=float)
    a00, a11, a22 = C[..., 0, 0], C[..., 1, 1], C[..., 2, 2]
    a01, a02, a12 = C[..., 0, 1], C[..., 0, 2], C[..., 1, 2]
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1) / 6.0)
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(p > 0, det / (2.0 * p**3), 0.0)
    phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0
    hi = q + 2.0 * p * np.cos(phi)
    lo = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    return np.stack([lo, 3.0 * q - lo - hi, hi], axis=-1)


def sym3_eigvec(C: np.ndarray, lam: np.ndarray, min_gap: float = 1e-5) -> np.ndarray:
    """Unit eigenvectors (N, 3) of symmetric ``C`` (N, 3, 3) for the eigenvalues ``lam`` (N,).

    The eigenvector is orthogonal to the rows of ``C - lam I``: the longest cross product of two rows.
    Where ``lam`` is (nearly) a double eigenvalue (the longest cross product is below ``min_gap`` times
    the squared spread of the eigenvalues) the vector is ill-defined by the closed form and is taken
    from ``np.linalg.eigh`` for those rows only. The sign is arbitrary (as with eigh).
    """
    C = np.asarray(C, dtype=float)
    M = C - lam[:, None, None] * np.eye(3)
    r0, r1, r2 = M[:, 0], M[:, 1], M[:, 2]
    cands = np.stack([np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2)], axis=1)
    n2 = np.einsum("nkj,nkj->nk", cands, cands)
    best = n2.argmax(axis=1)
    v = cands[np.arange(len(C)), best]
    nrm = np.sqrt(n2[np.arange(len(C)), best])
    scale = np.einsum("nij,nij->n", C, C)  # |C|_F^2 >= (largest eigenvalue)^2
    bad = nrm <= min_gap * np.maximum(scale, 1e-300) ** 0.5 * np.sqrt(
        np.maximum(np.einsum("nij,nij->n", M, M), 0.0)
    )
    v = v / np.where(nrm > 0, nrm, 1.0)[:, None]
    if bad.any():
        w, V = np.linalg.eigh(C[bad])
        k = np.abs(w - lam[bad, None]).argmin(axis=1)
        v[bad] = np.take_along_axis(V, k[:, None, None], axis=2)[:, :, 0]
    return v


def smallest_eigvec(C: np.ndarray) -> np.ndarray:
    """Unit eigenvector (N, 3) of the smallest eigenvalue of each symmetric 3x3 ``C`` (N, 3, 3): the
    normal of a point neighbourhood's least-squares plane when ``C`` is its covariance (eq. 9)."""
    C = np.asarray(C, dtype=float).reshape(-1, 3, 3)
    return sym3_eigvec(C, sym3_eigvals(C)[:, 0])


def largest_eigvec(C: np.ndarray) -> np.ndarray:
    """Unit eigenvector (N, 3) of the largest eigenvalue of each symmetric 3x3 ``C`` (N, 3, 3)."""
    C = np.asarray(C, dtype=float).reshape(-1, 3, 3)
    return sym3_eigvec(C, sym3_eigvals(C)[:, 2])


def sampling_spacings(
    points: np.ndarray, tree: cKDTree | None = None, k: int = 32, sample: int = 4000, seed: int = 0
) -> tuple[float, float]:
    """The cloud's point spacing along its finest and its coarsest sampling direction (m): ``(fine,
    coarse)``, medians over (at most ``sample``) points.

    ``fine`` is the nearest-neighbour distance; ``coarse`` the distance to the nearest neighbour more than
    60 deg off the local line through the point's 4 nearest neighbours. On an area scan or a voxelised
    cloud both are alike (coarse 1.2-1.7 x fine after the denoiser's voxel grid); a laser line profiler
    swept by a robot has ``fine`` ~1 mm along a line and ``coarse`` the 5-7 mm between lines (2-6 x): a
    neighbourhood must reach ``coarse`` to hold surface rather than one line. Where no neighbour among the
    ``k`` nearest is off the line, the ``k``-th distance counts (a lower bound).
    """
    P = as_points(points, min_points=6)
    tree = tree if tree is not None else cKDTree(P)
    q = P
    if len(P) > sample:
        q = P[np.random.default_rng(seed).choice(len(P), sample, replace=False)]
    k = int(min(k, len(P) - 1))
    d, idx = tree.query(q, k=k + 1, workers=-1)
    D = P[idx[:, 1:]] - q[:, None, :]
    near = D[:, :4]
    t = largest_eigvec(np.einsum("nki,nkj->nij", near, near))
    dist = d[:, 1:]
    cos = np.abs(np.einsum("nkj,nj->nk", D, t)) / np.maximum(dist, 1e-15)
    off = np.where(cos < 0.5, dist, np.inf)
    coarse = np.min(off, axis=1)
    coarse = np.where(np.isfinite(coarse), coarse, dist[:, -1])
    return float(np.median(dist[:, 0])), float(np.median(coarse))
