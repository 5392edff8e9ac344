"""Linear point-to-plane ICP of the scan-and-plan method (paper 000, section II-C, eqs. 2-8, 20).

Each iteration pairs every source point with its nearest target point (KD-tree, within
``max_correspondence_distance``), linearises the rotation for small angles (eq. 4, sin t ~ t,
cos t ~ 1), stacks one row per pair into ``A x = b`` (eq. 7) with x = (alpha, beta, gamma, px, py, pz)
and solves it in the least-squares sense through an SVD pseudo-inverse (eq. 8). The problem is
re-linearised about the updated transform every iteration.

Beyond the paper (see docs/methods/reconstruction.md): optional robust weights (Huber or Tukey on the
point-to-plane residuals, iteratively re-weighted), and the update applied as an exact rotation
(``update="exact"``, the default) and re-orthonormalised, so the estimate stays a rigid transform.
``update="linear"`` applies the paper's matrix M^ of eq. 5 and projects it onto SO(3).

Speed (same result as a plain implementation): the nearest-neighbour search re-queries only the source
points that may have changed neighbour (:class:`NearestCache`) and runs in Morton order of the source
points (cache-friendly), target normals are estimated only for the target points that become
correspondences (:class:`LazyNormals`), and each iteration forms the 6x6 normal equations with one
(N, 7) matrix product, in row blocks small enough that OpenBLAS stays on one thread. The searches
use :class:`~.nearest.PointTree` (pykdtree, OpenMP).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from weldcell.sdk.arrays import col_max, col_min, row_dot
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid, orthonormalize

from .denoise import _knn_normals, as_points
from .nearest import PointTree

ROBUST_KERNELS = (None, "huber", "tukey")
UPDATES = ("exact", "linear")
#: below this many query points one thread is faster than starting worker threads
_THREADED_QUERY = 4000
#: rows per BLAS call: small enough that OpenBLAS stays on one thread (its idle threads keep spinning
#: after a threaded call and slow down the KD-tree's query threads on 2 cores)
_BLAS_ROWS = 4096


@dataclass(frozen=True)
class IcpOptions:
    """What :func:`linear_icp` does and when it stops (in the spirit of Open3D's ``ICPConvergenceCriteria``
    with the correspondence distance and the estimation's options beside it). Checked when made.

    ``max_correspondence_distance`` (m): pairs farther apart are not used. Stops when the changes of the
    fitness (a ratio) and of the inlier RMSE (m) from one iteration to the next both fall below
    ``tolerance`` (Open3D's criterion), when the update is smaller than ``tolerance`` (rad and m), or
    after ``max_iterations``. ``robust`` = "huber" | "tukey" re-weights the residuals (scale
    ``robust_scale`` m, or adaptive). ``update``: "exact" (rotation) or "linear" (the paper's eq. 5).
    ``normal_k``: neighbours of the PCA target normals (eq. 9) when none are given.
    ``prior = (sigma_t, sigma_r)`` (m, rad): how far the initial guess may be off (e.g. kinematics +
    hand-eye). The correction then minimises the point-to-plane sum of squares plus a Gaussian prior on
    the correction (MAP instead of least squares): directions the data hardly constrain (rotation about
    a cylinder's axis, sliding along a plane) stay near the initial guess instead of drifting; well
    constrained ones are unaffected. None (the default, the paper) adds nothing.
    """

    max_correspondence_distance: float
    max_iterations: int = 50
    tolerance: float = 1e-6
    robust: str | None = None
    robust_scale: float | None = None
    update: str = "exact"
    normal_k: int = 20
    prior: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        d_max = float(self.max_correspondence_distance)
        if not np.isfinite(d_max) or d_max <= 0:
            raise DataError(
                f"max_correspondence_distance must be > 0 m, got {self.max_correspondence_distance}",
                "use a few times the expected pose error (e.g. 3x the voxel size)",
            )
        if self.robust not in ROBUST_KERNELS:
            raise DataError(f"unknown robust kernel '{self.robust}'", "use robust=None, 'huber' or 'tukey'")
        if self.update not in UPDATES:
            raise DataError(f"unknown update '{self.update}'", "use update='exact' or 'linear'")
        if self.max_iterations < 1:
            raise DataError(
                f"max_iterations must be >= 1, got {self.max_iterations}", "pass max_iterations >= 1"
            )
        object.__setattr__(self, "max_correspondence_distance", d_max)
        if self.prior is not None:
            try:
                sig = np.asarray(self.prior, dtype=float)
            except (TypeError, ValueError):
                sig = np.array([np.nan])
            if sig.shape != (2,) or not np.all(np.isfinite(sig) & (sig > 0)):
                raise DataError(
                    f"prior must be (sigma_t > 0 m, sigma_r > 0 rad), got {self.prior!r}",
                    "e.g. prior=(0.002, 0.01)",
                )
            object.__setattr__(self, "prior", (float(sig[0]), float(sig[1])))


@dataclass
class IcpResult:
    """Outcome of :func:`linear_icp`.

    ``T`` is ``T_target_source`` (maps source points onto the target). ``fitness`` is eq. 20
    (inlier source points / target points), ``inlier_fraction`` the share of source points with a
    correspondence (Open3D's "fitness"), ``inlier_rmse`` the RMS point-to-point distance of the inlier
    pairs (m). ``history`` has one dict per iteration with the values before that iteration's update
    (``fitness``, ``inlier_fraction``, ``inlier_rmse``, ``plane_rmse``, ``n_inliers``) and the update size
    (``step_rotation`` rad, ``step_translation`` m). ``distances`` / ``initial_distances``: each source
    point's distance to its nearest target point at ``T`` / at the initial guess (inf where farther than
    ``max_correspondence_distance``), e.g. for eq. 20 at a tighter inlier distance without a new search.
    ``information``: the (robustly weighted) point-to-plane normal matrix ``A^T W A / n_inliers`` of the
    last solved iteration, for a correction twist ``(omega, p)`` about the target frame's origin: how
    well each direction of the correction is constrained (zeros if no iteration was solved).
    """

    T: np.ndarray
    fitness: float
    inlier_rmse: float
    iterations: int
    converged: bool
    inlier_fraction: float = 0.0
    plane_rmse: float = 0.0
    history: list[dict] = field(default_factory=list)
    distances: np.ndarray | None = field(default=None, repr=False)
    initial_distances: np.ndarray | None = field(default=None, repr=False)
    information: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)), repr=False)


def _robust_weights(r: np.ndarray, kernel: str | None, scale: float | None) -> np.ndarray:
    """IRLS weights for residuals ``r``; ``scale`` None -> 1.4826 MAD (x1.345 Huber, x4.685 Tukey)."""
    if kernel is None:
        return np.ones_like(r)
    a = np.abs(r)
    if scale is None:
        mad = 1.4826 * float(np.median(a))
        scale = (1.345 if kernel == "huber" else 4.685) * max(mad, 1e-12)
    if kernel == "huber":
        return np.where(a <= scale, 1.0, scale / np.maximum(a, 1e-300))
    u = a / scale
    return np.where(u < 1.0, (1.0 - u * u) ** 2, 0.0)


def _gram(J: np.ndarray) -> np.ndarray:
    """``J J^T`` of the (7, N) rows summed over column blocks of :data:`_BLAS_ROWS` (one-thread BLAS)."""
    G = J[:, :_BLAS_ROWS] @ J[:, :_BLAS_ROWS].T
    for a in range(_BLAS_ROWS, J.shape[1], _BLAS_ROWS):
        blk = J[:, a : a + _BLAS_ROWS]
        G += blk @ blk.T
    return G


def _rigid_apply(P: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``P R^T + t`` for (N, 3) points, in row blocks of :data:`_BLAS_ROWS` (see :func:`_gram`)."""
    out = np.empty_like(P)
    Rt = np.ascontiguousarray(T[:3, :3].T)
    for a in range(0, len(P), _BLAS_ROWS):
        np.matmul(P[a : a + _BLAS_ROWS], Rt, out=out[a : a + _BLAS_ROWS])
    for k in range(3):  # column by column: broadcasting a (3,) row over (N, 3) is ~8x slower
        out[:, k] += T[k, 3]
    return out


def _morton_order(P: np.ndarray) -> np.ndarray:
    """Indices that sort ``P`` along a 30-bit Morton (Z-order) curve over its bounding cube.

    Queries in this order visit the KD-tree's nodes in nearly the same sequence from one point to
    the next, which keeps them in cache (10-20 % faster searches on unordered clouds).
    """

    def spread(v: np.ndarray) -> np.ndarray:  # 10 bits -> every third bit
        v = v.astype(np.uint32)
        v = (v | (v << 16)) & np.uint32(0x030000FF)
        v = (v | (v << 8)) & np.uint32(0x0300F00F)
        v = (v | (v << 4)) & np.uint32(0x030C30C3)
        return (v | (v << 2)) & np.uint32(0x09249249)

    lo = col_min(P)
    ext = float((col_max(P) - lo).max())
    q = ((P - lo) * (1023.0 / max(ext, 1e-300))).astype(np.uint32)
    return np.argsort(spread(q[:, 0]) | (spread(q[:, 1]) << 1) | (spread(q[:, 2]) << 2))


def _system_rows(src: np.ndarray, nrm: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rows ``[s x n, n | b]`` of eq. 7, stored transposed as one (7, N) array (contiguous writes)."""
    J = np.empty((7, len(src)))
    s0, s1, s2 = src.T
    n0, n1, n2 = nrm.T
    np.subtract(s1 * n2, s2 * n1, out=J[0])
    np.subtract(s2 * n0, s0 * n2, out=J[1])
    np.subtract(s0 * n1, s1 * n0, out=J[2])
    J[3:6] = nrm.T
    J[6] = b
    return J


def _normal_matrix(J: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """``[A b]^T W [A b]`` (7x7) of the rows ``J = [A | b]^T`` in one product."""
    if weights is not None:
        J = J * np.sqrt(weights)[None, :]
    return _gram(J)


def _solve(
    J: np.ndarray | None,
    weights: np.ndarray | None,
    rcond: float,
    prior: tuple[np.ndarray, np.ndarray] | None = None,
    G: np.ndarray | None = None,
) -> np.ndarray:
    """Eq. 8 on the rows ``J = [A | b]^T``: ``[A b]^T W [A b]`` in one product, then the 6x6 pseudo-inverse.

    The pseudo-inverse of the symmetric 6x6 ``A^T A`` is taken through its eigen-decomposition (as
    ``pinv(..., hermitian=True)``: eigenvalues below ``rcond`` x the largest count as zero).
    ``prior = (lam, c)`` adds ``sum lam_j (x_j + c_j)^2`` (a diagonal Gaussian prior pulling the total
    correction ``x + c`` towards zero) to the least-squares cost. ``G``: the 7x7 normal matrix when the
    caller has formed it already (:func:`_normal_matrix`).
    """
    if G is None:
        G = _normal_matrix(J, weights)
    H, g = G[:6, :6], G[:6, 6]
    if prior is not None:
        lam, c = prior
        H = H + np.diag(lam)
        g = g - lam * c
    w, V = np.linalg.eigh(H)
    keep = np.abs(w) > rcond * np.abs(w).max()
    Vk = V[:, keep]
    return Vk @ ((Vk.T @ g) / w[keep])


def point_to_plane_information(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``A^T A / N`` (6x6) of eq. 7's rows ``[s x n, n]``: how well the points with these normals
    constrain each direction of a correction twist ``(omega, p)`` about the frame's origin (the
    unweighted counterpart of :attr:`IcpResult.information`)."""
    P = as_points(points, "points", min_points=1)
    J = _system_rows(P, np.asarray(normals, dtype=float), np.zeros(len(P)))
    return _gram(J)[:6, :6] / len(P)


def point_to_plane_step(
    src: np.ndarray, tgt: np.ndarray, nrm: np.ndarray, weights: np.ndarray | None = None, rcond: float = 1e-10
) -> np.ndarray:
    """One linear least-squares solve of eqs. 6-8 -> x = (alpha, beta, gamma, px, py, pz).

    With R^ of eq. 4, ``(M^ s - t) . n = (s - t) . n + (omega x s) . n + p . n`` and
    ``(omega x s) . n = omega . (s x n)``, so each pair gives the row ``[s x n, n]`` and right-hand side
    ``(t - s) . n``. The (weighted) normal equations are solved with the SVD pseudo-inverse, which
    gives the same minimiser as ``pinv(A) b`` (eq. 8) at a 6x6 cost and returns the minimum-norm
    solution along degenerate directions (e.g. sliding along a plane).
    """
    b = np.einsum("ij,ij->i", tgt - src, nrm)
    return _solve(_system_rows(src, nrm, b), weights, rcond)


def _rotation_xyz(alpha: float, beta: float, gamma: float) -> np.ndarray:
    """``Rz(gamma) Ry(beta) Rx(alpha)``: the exact rotation with the solved angles (Low 2004)."""
    ca, sa, cb, sb, cg, sg = (
        np.cos(alpha),
        np.sin(alpha),
        np.cos(beta),
        np.sin(beta),
        np.cos(gamma),
        np.sin(gamma),
    )
    return np.array(
        [
            [cg * cb, cg * sb * sa - sg * ca, cg * sb * ca + sg * sa],
            [sg * cb, sg * sb * sa + cg * ca, sg * sb * ca - cg * sa],
            [-sb, cb * sa, cb * ca],
        ]
    )


def _step_matrix(x: np.ndarray, update: str) -> np.ndarray:
    alpha, beta, gamma = (float(v) for v in x[:3])
    M = np.eye(4)
    if update == "exact":
        M[:3, :3] = _rotation_xyz(alpha, beta, gamma)
    else:
        M[:3, :3] = orthonormalize(np.array([[1.0, -gamma, beta], [gamma, 1.0, -alpha], [-beta, alpha, 1.0]]))
    M[:3, 3] = x[3:]
    return M


def _check_transform(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not is_rigid(T, tol=1e-5):
        raise DataError(
            f"{what} is not a rigid 4x4 transform", "pass a 4x4 matrix with an orthonormal rotation"
        )
    return T


def _query(tree: PointTree | cKDTree, q: np.ndarray, k: int, bound: float) -> tuple[np.ndarray, np.ndarray]:
    workers = -1 if len(q) > _THREADED_QUERY else 1  # thread start-up costs more than it saves on few points
    return tree.query(q, k=k, distance_upper_bound=bound, workers=workers)


class NearestCache:
    """Exact nearest-target look-up for a moving source that re-queries only the points that may have
    changed neighbour.

    After a k=2 query a source point s with nearest target distances d1 <= d2 keeps the same nearest
    neighbour while it moves by less than (d2 - d1) / 2 (triangle inequality), so only points that
    moved further since their last query are searched again; the distance to the kept neighbour is
    recomputed exactly. Pair queries use the bound ``B = margin * d_max``: a point with no target within
    B stays without a correspondence within ``d_max`` while it moves by less than ``B - d_max``.
    The result equals a full nearest-neighbour query every iteration (up to exact ties).

    A k=2 query costs ~1.3 k=1 queries and pays off only if the points then move less than their gaps,
    so while the motion is large (the first ICP iterations) plain k=1 queries are made; pair queries
    start once the motion predicted for the next step (ICP converges about geometrically: the last
    step's motion times its ratio to the step before) falls below twice the typical gap.
    Searches run in Morton order of the first query's points (:func:`_morton_order`); the results come
    back in the caller's order. ``query`` must be called with the source points in the same order every
    time.
    """

    def __init__(
        self, tree: PointTree | cKDTree, target: np.ndarray, d_max: float, n_source: int, margin: float = 1.5
    ):
        self.tree, self.target, self.d_max = tree, target, float(d_max)
        self.bound = margin * self.d_max
        self.idx = np.full(n_source, -1, dtype=np.int64)
        self.gap = np.full(n_source, -1.0)
        self.anchor: np.ndarray | None = None
        self.n_queries = 0
        self.typical_gap = 0.0  # median gap (m) after pair queries; 0 until the first one
        self._prev: np.ndarray | None = None
        self._moves: list[float] = []
        self._scale = 0.0  # median nearest distance of the last full query (m)
        self._own_anchor = False  # the anchor array is the caller's until the first partial update
        self.order: np.ndarray | None = None  # search order (Morton) of the source points
        self._reordered = False  # False: the search order is the caller's order

    def _step_motion(self, pts: np.ndarray) -> float:
        """Median motion of the points since the previous call (on ~1000 of them)."""
        step = max(1, len(pts) // 1024)
        d = pts[::step] - self._prev[::step]
        return float(np.sqrt(np.median(row_dot(d, d))))

    def _want_pairs(self) -> bool:
        if len(self._moves) < 2:
            return False
        last, before = self._moves[-1], self._moves[-2]
        predicted = last * min(1.0, last / max(before, 1e-300))
        gap = self.typical_gap if self.typical_gap > 0 else 0.15 * self._scale
        return predicted < 2.0 * gap

    def _full(self, pts: np.ndarray) -> np.ndarray:
        """A plain k=1 query of all points (in search order) -> distances; sets ``idx``."""
        if self.order is None:
            self._reordered = len(pts) > _THREADED_QUERY
            self.order = _morton_order(pts) if self._reordered else np.arange(len(pts))
        if self._reordered:
            d, i = _query(self.tree, pts[self.order], 1, self.d_max)
            dist = np.empty(len(pts))
            dist[self.order] = d
            self.idx[self.order] = np.where(np.isfinite(d), i, -1)
        else:
            dist, i = _query(self.tree, pts, 1, self.d_max)
            self.idx[:] = np.where(np.isfinite(dist), i, -1)
            d = dist
        self.n_queries += len(pts)
        found = d[::8][np.isfinite(d[::8])]  # every 8th point is plenty for a typical distance
        self._scale = float(np.median(found)) if len(found) else self.d_max
        return dist

    def query(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices) of the nearest target within ``d_max`` (inf / -1 where none)."""
        if self.anchor is None:  # first call: a plain full query
            dist = self._full(pts)
            self.anchor, self._prev, self._own_anchor = pts, pts, False
            return dist, self.idx.copy()
        self._moves.append(self._step_motion(pts))
        self._prev = pts
        diff = pts - self.anchor
        moved = row_dot(diff, diff)
        is_stale = moved >= self.gap * np.abs(self.gap)
        stale = self.order[is_stale[self.order]] if self._reordered else np.flatnonzero(is_stale)
        pairs = self._want_pairs()
        if len(stale) == len(pts) and not pairs:  # everything moved far: a plain full query
            dist = self._full(pts)
            self.gap.fill(-1.0)
            self.anchor, self._own_anchor = pts, False
            return dist, self.idx.copy()
        if len(stale):
            q = pts[stale]
            self.n_queries += len(q)
            if pairs:
                d, i = _query(self.tree, q, 2, self.bound)
                d1, d2 = d[:, 0], np.minimum(d[:, 1], self.bound)
                found = np.isfinite(d1)
                gap = np.where(found, 0.5 * (d2 - np.where(found, d1, 0.0)), self.bound - self.d_max)
                idx = np.where(found, i[:, 0], -1)
            else:
                d1, i1 = _query(self.tree, q, 1, self.d_max)
                idx = np.where(np.isfinite(d1), i1, -1)
                gap = np.full(len(q), -1.0)
            if not self._own_anchor:
                self.anchor, self._own_anchor = self.anchor.copy(), True
            self.idx[stale], self.gap[stale], self.anchor[stale] = idx, gap, q
            if pairs:
                g = self.gap[:: max(1, len(self.gap) // 1024)]
                g = g[g >= 0]
                self.typical_gap = float(np.median(g)) if len(g) else self.typical_gap
        out = self.idx.copy()
        diff = pts - np.take(self.target, out, axis=0, mode="clip")  # -1 clips to 0: masked below
        dist = np.sqrt(row_dot(diff, diff))
        far = np.flatnonzero((dist > self.d_max) | (out < 0))
        dist[far], out[far] = np.inf, -1
        return dist, out


class LazyNormals:
    """Target normals (eq. 9: PCA of the ``k`` nearest target points) estimated on first use.

    ICP needs the normals of the target points that become correspondences only, often a fraction of
    the target (e.g. the part of a growing model a new view overlaps); each is computed once, with the
    same neighbours and eigen-solver as :func:`~.denoise.pca_normals`. ``table[j]`` is
    ``(n_j, n_j . t_j)`` for the points estimated so far.
    """

    def __init__(self, target: np.ndarray, tree: PointTree | cKDTree, k: int = 20):
        self.target, self.tree, self.k = target, tree, min(int(k), len(target))
        self.table = np.empty((len(target), 4))
        self.known = np.zeros(len(target), dtype=bool)
        self.n_estimated = 0

    def ensure(self, j: np.ndarray) -> None:
        need = np.zeros(len(self.target), dtype=bool)
        need[j] = True
        need &= ~self.known
        miss = np.flatnonzero(need)
        if len(miss) > _THREADED_QUERY:
            n = _knn_normals(self.target, self.tree, self.k, miss)
        elif len(miss):  # the same estimate without starting query threads for a few points
            _, nb = self.tree.query(self.target[miss], k=max(self.k, 3), workers=1)
            Q = self.target[nb]
            D = Q - Q.mean(axis=1, keepdims=True)
            n = np.linalg.eigh(np.einsum("nki,nkj->nij", D, D))[1][:, :, 0]
        if len(miss):
            self.table[miss, :3] = n
            self.table[miss, 3] = np.einsum("ij,ij->i", n, self.target[miss])
            self.known[miss] = True
            self.n_estimated += len(miss)


def _prior_terms(
    prior: tuple[float, float], T: np.ndarray, init_inv: np.ndarray, res: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(lam, c) of :func:`_solve` for a prior of standard deviations ``prior = (sigma_t m, sigma_r rad)``
    on the correction ``T init^-1``: ``c`` its rotation vector and translation, ``lam`` the prior's
    information scaled by the residuals' variance (robust: 1.4826 MAD) so that it weighs against the
    point-to-plane sum of squares in the same units."""
    C = T @ init_inv
    c = np.concatenate([Rotation.from_matrix(C[:3, :3]).as_rotvec(), C[:3, 3]])
    mad = 1.4826 * float(np.median(np.abs(res))) if len(res) else 0.0
    var = max(mad * mad, 1e-12)
    sigma_t, sigma_r = prior
    lam = np.array([var / sigma_r**2] * 3 + [var / sigma_t**2] * 3)
    return lam, c


def _normal_table(Tg: np.ndarray, Nt: np.ndarray) -> np.ndarray:
    table = np.empty((len(Tg), 4))
    table[:, :3] = Nt
    table[:, 3] = np.einsum("ij,ij->i", Nt, Tg)
    return table


def linear_icp(
    source: np.ndarray,
    target: np.ndarray,
    options: IcpOptions,
    *,
    target_normals: np.ndarray | None = None,
    init: np.ndarray = np.eye(4),
    target_tree: PointTree | cKDTree | None = None,
) -> IcpResult:
    """Register ``source`` onto ``target`` by linear point-to-plane ICP (paper 000, eqs. 2-8) with the
    distance, stopping rule, kernel, update and prior of ``options`` (:class:`IcpOptions`).

    ``init`` is the initial ``T_target_source`` (the kinematics + hand-eye guess, eq. 1).
    ``target_normals`` default to PCA normals of the ``options.normal_k`` nearest target points (eq. 9),
    estimated only for the target points that become correspondences.
    ``target_tree`` lets a caller reuse a :class:`~.nearest.PointTree` (or ``cKDTree``) of ``target``.
    """
    S = np.ascontiguousarray(as_points(source, "ICP source", min_points=3))
    Tg = as_points(target, "ICP target", min_points=3)
    o = options
    d_max, tolerance, prior = o.max_correspondence_distance, o.tolerance, o.prior
    T = _check_transform(init, "ICP initial transform").copy()
    init_inv = None if prior is None else np.linalg.inv(T)
    if target_tree is not None and target_tree.n != len(Tg):
        raise DataError(
            f"target_tree holds {target_tree.n} points, the target {len(Tg)}",
            "pass a PointTree built on this target, or target_tree=None",
        )
    tree = target_tree if target_tree is not None else PointTree(Tg)
    lazy = None
    if target_normals is None:
        lazy = LazyNormals(Tg, tree, o.normal_k)
        table = lazy.table
    else:
        Nt = np.asarray(target_normals, dtype=float)
        if Nt.shape != Tg.shape or not np.all(np.isfinite(Nt)):
            raise DataError(
                f"target normals must be a finite {Tg.shape} array, got shape {Nt.shape}",
                "pass one normal per target point, or target_normals=None to estimate them",
            )
        table = _normal_table(Tg, Nt)  # (n, n . t) per target point: one gather per iteration
    cache = NearestCache(tree, Tg, d_max, len(S))
    n_target, n_source = len(Tg), len(S)

    history: list[dict] = []
    converged = False
    prev: tuple[float, float] | None = None
    last = None
    dist0 = dist = None
    info = np.zeros((6, 6))
    for it in range(o.max_iterations + 1):
        Ss = _rigid_apply(S, T)
        dist, idx = cache.query(Ss)
        dist0 = dist if dist0 is None else dist0
        if (idx >= 0).all():
            n_in, s_in, j, d_in = n_source, Ss, idx, dist
        else:
            sel = np.flatnonzero(idx >= 0)
            n_in, s_in, j, d_in = len(sel), np.take(Ss, sel, axis=0), np.take(idx, sel), np.take(dist, sel)
        fit, frac = n_in / n_target, n_in / n_source
        rmse = float(np.sqrt(np.einsum("i,i", d_in, d_in) / n_in)) if n_in else 0.0
        prmse = 0.0
        if n_in:
            if lazy is not None:
                lazy.ensure(j)
            nc = np.take(table, j, axis=0)
            res = row_dot(s_in, nc)
            res -= nc[:, 3]  # (s - t) . n, the point-to-plane residual
            prmse = float(np.sqrt(np.einsum("i,i", res, res) / n_in))
        last = (fit, frac, rmse, prmse)
        if prev is not None:
            # as Open3D: changes of the fitness (a ratio) and of the inlier RMSE (m) both below tolerance
            if abs(fit - prev[0]) < tolerance and abs(rmse - prev[1]) < tolerance:
                converged = True
        if converged or it == o.max_iterations or n_in < 6:
            break
        w = _robust_weights(res, o.robust, o.robust_scale) if o.robust else None
        pr = _prior_terms(prior, T, init_inv, res) if prior is not None else None
        G = _normal_matrix(_system_rows(s_in, nc[:, :3], -res), w)
        info = G[:6, :6] / n_in
        x = _solve(None, None, 1e-10, pr, G)
        T = _step_matrix(x, o.update) @ T
        if o.update == "linear" or it % 8 == 7:  # exact steps are rotations: re-orthonormalise now and then
            T[:3, :3] = orthonormalize(T[:3, :3])
        d_rot, d_tr = float(np.linalg.norm(x[:3])), float(np.linalg.norm(x[3:]))
        history.append(
            dict(
                iteration=it + 1,
                fitness=fit,
                inlier_fraction=frac,
                inlier_rmse=rmse,
                plane_rmse=prmse,
                n_inliers=n_in,
                step_rotation=d_rot,
                step_translation=d_tr,
            )
        )
        prev = (fit, rmse)
        if d_rot < tolerance and d_tr < tolerance:
            converged = True
    if last is None or last[0] == 0.0:
        raise DataError(
            f"ICP found no correspondences within {d_max:g} m",
            "check the initial pose (kinematics + hand-eye) or raise max_correspondence_distance",
        )
    fit, frac, rmse, prmse = last
    T[:3, :3] = orthonormalize(T[:3, :3])
    return IcpResult(
        T=T,
        fitness=fit,
        inlier_rmse=rmse,
        iterations=len(history),
        converged=converged,
        inlier_fraction=frac,
        plane_rmse=prmse,
        history=history,
        distances=dist,
        initial_distances=dist0,
        information=info,
    )
