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
points that may have changed neighbour (:class:`~.icp_search.NearestCache`) and runs in Morton order of
the source points (cache-friendly), target normals are estimated only for the target points that become
correspondences (:class:`~.icp_search.LazyNormals`), and each iteration forms the 6x6 normal equations
with one (N, 7) matrix product, in row blocks small enough that OpenBLAS stays on one thread. The searches
use :class:`~.nearest.PointTree` (pykdtree, OpenMP).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from weldcell.sdk.arrays import row_dot
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid, orthonormalize

from .cloud_numerics import as_points
from .icp_search import LazyNormals, NearestCache
from .nearest import PointTree

ROBUST_KERNELS = (None, "huber", "tukey")
UPDATES = ("exact", "linear")
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
    T = _check_transform(init, "ICP initial transform").copy()
    init_inv = None if o.prior is None else np.linalg.inv(T)
    tree, planes = _target_planes(Tg, o, target_normals, target_tree)
    cache = NearestCache(tree, Tg, o.max_correspondence_distance, len(S))
    history: list[dict] = []
    converged = False
    prev: _Pairs | None = None
    pairs = dist0 = None
    info = np.zeros((6, 6))
    for it in range(o.max_iterations + 1):
        pairs = _pairs_at(S, T, cache, planes, len(Tg))
        dist0 = pairs.dist if dist0 is None else dist0
        # as Open3D: changes of the fitness (a ratio) and of the inlier RMSE (m) both below tolerance
        if prev is not None and pairs.settled_since(prev, o.tolerance):
            converged = True
        if converged or it == o.max_iterations or pairs.n_in < 6:
            break
        x, info = _step(pairs, T, o, init_inv)
        T = _step_matrix(x, o.update) @ T
        if o.update == "linear" or it % 8 == 7:  # exact steps are rotations: re-orthonormalise now and then
            T[:3, :3] = orthonormalize(T[:3, :3])
        d_rot, d_tr = float(np.linalg.norm(x[:3])), float(np.linalg.norm(x[3:]))
        history.append(pairs.record(it + 1, d_rot, d_tr))
        prev = pairs
        if d_rot < o.tolerance and d_tr < o.tolerance:
            converged = True
    if pairs is None or pairs.fit == 0.0:
        raise DataError(
            f"ICP found no correspondences within {o.max_correspondence_distance:g} m",
            "check the initial pose (kinematics + hand-eye) or raise max_correspondence_distance",
        )
    T[:3, :3] = orthonormalize(T[:3, :3])
    return IcpResult(
        T=T,
        fitness=pairs.fit,
        inlier_rmse=pairs.rmse,
        iterations=len(history),
        converged=converged,
        inlier_fraction=pairs.frac,
        plane_rmse=pairs.prmse,
        history=history,
        distances=pairs.dist,
        initial_distances=dist0,
        information=info,
    )


def _target_planes(
    Tg: np.ndarray,
    o: IcpOptions,
    target_normals: np.ndarray | None,
    target_tree: PointTree | cKDTree | None,
) -> tuple[PointTree | cKDTree, Callable[[np.ndarray], np.ndarray]]:
    """The target's KD-tree and ``planes(j)``: rows ``(n_j, n_j . t_j)`` of target points ``j``, from
    the given normals or estimated on first use (:class:`LazyNormals`)."""
    if target_tree is not None and target_tree.n != len(Tg):
        raise DataError(
            f"target_tree holds {target_tree.n} points, the target {len(Tg)}",
            "pass a PointTree built on this target, or target_tree=None",
        )
    tree = target_tree if target_tree is not None else PointTree(Tg)
    if target_normals is None:
        lazy = LazyNormals(Tg, tree, o.normal_k)

        def planes(j: np.ndarray) -> np.ndarray:
            lazy.ensure(j)
            return np.take(lazy.table, j, axis=0)

        return tree, planes
    Nt = np.asarray(target_normals, dtype=float)
    if Nt.shape != Tg.shape or not np.all(np.isfinite(Nt)):
        raise DataError(
            f"target normals must be a finite {Tg.shape} array, got shape {Nt.shape}",
            "pass one normal per target point, or target_normals=None to estimate them",
        )
    table = _normal_table(Tg, Nt)  # (n, n . t) per target point: one gather per iteration
    return tree, lambda j: np.take(table, j, axis=0)


@dataclass
class _Pairs:
    """One ICP iteration's correspondences: the source points with a target within the distance
    (``s_in``), their target planes ``nc`` (n, n . t) and point-to-plane residuals ``res``, every source
    point's nearest distance ``dist``, and eq. 20's fitness, the inlier fraction and RMSEs."""

    n_in: int
    s_in: np.ndarray
    nc: np.ndarray | None
    res: np.ndarray | None
    dist: np.ndarray
    fit: float
    frac: float
    rmse: float
    prmse: float

    def settled_since(self, prev: _Pairs, tolerance: float) -> bool:
        return abs(self.fit - prev.fit) < tolerance and abs(self.rmse - prev.rmse) < tolerance

    def record(self, iteration: int, d_rot: float, d_tr: float) -> dict:
        return dict(
            iteration=iteration,
            fitness=self.fit,
            inlier_fraction=self.frac,
            inlier_rmse=self.rmse,
            plane_rmse=self.prmse,
            n_inliers=self.n_in,
            step_rotation=d_rot,
            step_translation=d_tr,
        )


def _pairs_at(
    S: np.ndarray,
    T: np.ndarray,
    cache: NearestCache,
    planes: Callable[[np.ndarray], np.ndarray],
    n_target: int,
) -> _Pairs:
    """The correspondences of source ``S`` moved by ``T`` (eqs. 2-3) and their residuals."""
    Ss = _rigid_apply(S, T)
    dist, idx = cache.query(Ss)
    n_source = len(S)
    if (idx >= 0).all():
        n_in, s_in, j, d_in = n_source, Ss, idx, dist
    else:
        sel = np.flatnonzero(idx >= 0)
        n_in, s_in, j, d_in = len(sel), np.take(Ss, sel, axis=0), np.take(idx, sel), np.take(dist, sel)
    rmse = float(np.sqrt(np.einsum("i,i", d_in, d_in) / n_in)) if n_in else 0.0
    nc = res = None
    prmse = 0.0
    if n_in:
        nc = planes(j)
        res = row_dot(s_in, nc)
        res -= nc[:, 3]  # (s - t) . n, the point-to-plane residual
        prmse = float(np.sqrt(np.einsum("i,i", res, res) / n_in))
    return _Pairs(n_in, s_in, nc, res, dist, n_in / n_target, n_in / n_source, rmse, prmse)


def _step(
    pairs: _Pairs, T: np.ndarray, o: IcpOptions, init_inv: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """One linearised solve (eqs. 4-8, robust weights and the pose prior when asked): the step x =
    (alpha, beta, gamma, px, py, pz) and the information (6x6 normal matrix per pair)."""
    w = _robust_weights(pairs.res, o.robust, o.robust_scale) if o.robust else None
    pr = _prior_terms(o.prior, T, init_inv, pairs.res) if o.prior is not None else None
    G = _normal_matrix(_system_rows(pairs.s_in, pairs.nc[:, :3], -pairs.res), w)
    return _solve(None, None, 1e-10, pr, G), G[:6, :6] / pairs.n_in
