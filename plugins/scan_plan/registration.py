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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid, orthonormalize

from .denoise import as_points, pca_normals

ROBUST_KERNELS = (None, "huber", "tukey")
UPDATES = ("exact", "linear")


@dataclass
class IcpResult:
    """Outcome of :func:`linear_icp`.

    ``T`` is ``T_target_source`` (maps source points onto the target). ``fitness`` is eq. 20
    (inlier source points / target points), ``inlier_fraction`` the share of source points with a
    correspondence (Open3D's "fitness"), ``inlier_rmse`` the RMS point-to-point distance of the inlier
    pairs (m). ``history`` has one dict per iteration with the values before that iteration's update
    (``fitness``, ``inlier_fraction``, ``inlier_rmse``, ``plane_rmse``, ``n_inliers``) and the update size
    (``step_rotation`` rad, ``step_translation`` m).
    """

    T: np.ndarray
    fitness: float
    inlier_rmse: float
    iterations: int
    converged: bool
    inlier_fraction: float = 0.0
    plane_rmse: float = 0.0
    history: list[dict] = field(default_factory=list)


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
    A = np.empty((len(src), 6))
    A[:, :3] = np.cross(src, nrm)
    A[:, 3:] = nrm
    b = np.einsum("ij,ij->i", tgt - src, nrm)
    if weights is not None:
        Aw = A * weights[:, None]
        H, g = Aw.T @ A, Aw.T @ b
    else:
        H, g = A.T @ A, A.T @ b
    return np.linalg.pinv(H, rcond=rcond, hermitian=True) @ g


def _step_matrix(x: np.ndarray, update: str) -> np.ndarray:
    alpha, beta, gamma = x[:3]
    M = np.eye(4)
    if update == "exact":
        # the exact rotation with the solved angles, R = Rz(gamma) Ry(beta) Rx(alpha) (Low 2004)
        M[:3, :3] = Rotation.from_euler("xyz", [alpha, beta, gamma]).as_matrix()
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


class NearestCache:
    """Exact nearest-target look-up for a moving source that re-queries only the points that may have
    changed neighbour.

    After a k=2 query a source point s with nearest target distances d1 <= d2 keeps the same nearest
    neighbour while it moves by less than (d2 - d1) / 2 (triangle inequality), so only points that
    moved further since their last query are searched again; the distance to the kept neighbour is
    recomputed exactly. Queries use the bound ``B = margin * d_max``: a point with no target within B
    stays without a correspondence within ``d_max`` while it moves by less than ``B - d_max``.
    The result equals a full nearest-neighbour query every iteration (up to exact ties).
    """

    def __init__(self, tree: cKDTree, target: np.ndarray, d_max: float, n_source: int, margin: float = 1.5):
        self.tree, self.target, self.d_max = tree, target, d_max
        self.bound = margin * d_max
        self.idx = np.full(n_source, -1, dtype=np.int64)
        self.gap = np.full(n_source, -1.0)
        self.anchor = np.zeros((n_source, 3))
        self.n_queries = 0
        self.typical_gap = 0.0

    def _query(self, pts: np.ndarray, sel: np.ndarray | None, pairs: bool) -> None:
        q = pts if sel is None else pts[sel]
        workers = -1 if len(q) > 4000 else 1  # thread start-up costs more than it saves on small batches
        self.n_queries += len(q)
        if pairs:
            d, i = self.tree.query(q, k=2, distance_upper_bound=self.bound, workers=workers)
            d1, d2 = d[:, 0], np.minimum(d[:, 1], self.bound)
            found = np.isfinite(d1)
            gap = np.where(found, 0.5 * (d2 - np.where(found, d1, 0.0)), self.bound - self.d_max)
            idx = np.where(found, i[:, 0], -1)
        else:  # large motion: the neighbour will change anyway, a cheaper k=1 query (no gap) is enough
            d1, i1 = self.tree.query(q, k=1, distance_upper_bound=self.d_max, workers=workers)
            found = np.isfinite(d1)
            idx = np.where(found, i1, -1)
            gap = np.full(len(q), -1.0)
        if sel is None:
            self.idx, self.gap, self.anchor = idx, gap, pts.copy()
        else:
            self.idx[sel], self.gap[sel], self.anchor[sel] = idx, gap, q
        if pairs and self.typical_gap == 0.0:
            self.typical_gap = float(np.median(gap))

    def query(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices) of the nearest target within ``d_max`` (inf / -1 where none)."""
        if self.n_queries == 0:
            self._query(pts, None, pairs=True)
        else:
            moved = np.einsum("ij,ij->i", pts - self.anchor, pts - self.anchor)
            stale = np.flatnonzero(moved >= self.gap * np.abs(self.gap))
            if len(stale):
                # motion shrinks from step to step: once it is below the typical gap, keep gaps
                small = float(np.sqrt(np.median(moved[stale]))) < self.typical_gap
                self._query(pts, stale, pairs=small)
        has = self.idx >= 0
        dist = np.full(len(pts), np.inf)
        diff = pts[has] - self.target[self.idx[has]]
        dist[has] = np.sqrt(np.einsum("ij,ij->i", diff, diff))
        inl = dist <= self.d_max
        dist[~inl] = np.inf
        return dist, np.where(inl, self.idx, -1)


def linear_icp(
    source: np.ndarray,
    target: np.ndarray,
    target_normals: np.ndarray | None = None,
    init: np.ndarray = np.eye(4),
    *,
    max_correspondence_distance: float,
    max_iterations: int = 50,
    tolerance: float = 1e-6,
    robust: str | None = None,
    robust_scale: float | None = None,
    update: str = "exact",
    normal_k: int = 20,
    target_tree: cKDTree | None = None,
) -> IcpResult:
    """Register ``source`` onto ``target`` by linear point-to-plane ICP (paper 000, eqs. 2-8).

    ``init`` is the initial ``T_target_source`` (the kinematics + hand-eye guess, eq. 1).
    ``target_normals`` default to PCA normals of the ``normal_k`` nearest target points (eq. 9).
    Stops when the change of the fitness (a ratio) and of the inlier RMSE (m) from one iteration to
    the next both fall below ``tolerance`` (Open3D's criterion), when the update is smaller than
    ``tolerance`` (rad and m), or after ``max_iterations``.
    ``robust`` = "huber" | "tukey" re-weights the residuals (scale ``robust_scale`` m, or adaptive).
    ``target_tree`` lets a caller reuse a ``cKDTree`` of ``target``.
    """
    S = as_points(source, "ICP source", min_points=3)
    Tg = as_points(target, "ICP target", min_points=3)
    d_max = float(max_correspondence_distance)
    if not np.isfinite(d_max) or d_max <= 0:
        raise DataError(
            f"max_correspondence_distance must be > 0 m, got {max_correspondence_distance}",
            "use a few times the expected pose error (e.g. 3x the voxel size)",
        )
    if robust not in ROBUST_KERNELS:
        raise DataError(f"unknown robust kernel '{robust}'", "use robust=None, 'huber' or 'tukey'")
    if update not in UPDATES:
        raise DataError(f"unknown update '{update}'", "use update='exact' or 'linear'")
    if max_iterations < 1:
        raise DataError(f"max_iterations must be >= 1, got {max_iterations}", "pass max_iterations >= 1")
    T = _check_transform(init, "ICP initial transform").copy()
    if target_normals is None:
        Nt = pca_normals(Tg, k=normal_k)
    else:
        Nt = np.asarray(target_normals, dtype=float)
        if Nt.shape != Tg.shape or not np.all(np.isfinite(Nt)):
            raise DataError(
                f"target normals must be a finite {Tg.shape} array, got shape {Nt.shape}",
                "pass one normal per target point, or target_normals=None to estimate them",
            )
    tree = target_tree if target_tree is not None else cKDTree(Tg, leafsize=32)
    cache = NearestCache(tree, Tg, d_max, len(S))
    n_target = len(Tg)

    history: list[dict] = []
    converged = False
    prev: tuple[float, float] | None = None
    last = None
    for it in range(max_iterations + 1):
        Ss = S @ T[:3, :3].T + T[:3, 3]
        dist, idx = cache.query(Ss)
        inl = np.isfinite(dist)
        n_in = int(inl.sum())
        fit = n_in / n_target
        frac = n_in / len(S)
        rmse = float(np.sqrt(np.mean(dist[inl] ** 2))) if n_in else 0.0
        if n_in:
            s_in, t_in, n_in_ = Ss[inl], Tg[idx[inl]], Nt[idx[inl]]
            res = np.einsum("ij,ij->i", s_in - t_in, n_in_)
            prmse = float(np.sqrt(np.mean(res**2)))
        last = (fit, frac, rmse, prmse if n_in else 0.0)
        if prev is not None:
            # as Open3D: changes of the fitness (a ratio) and of the inlier RMSE (m) both below tolerance
            if abs(fit - prev[0]) < tolerance and abs(rmse - prev[1]) < tolerance:
                converged = True
        if converged or it == max_iterations or n_in < 6:
            break
        w = _robust_weights(res, robust, robust_scale) if robust else None
        x = point_to_plane_step(s_in, t_in, n_in_, w)
        step = _step_matrix(x, update)
        T = step @ T
        T[:3, :3] = orthonormalize(T[:3, :3])
        d_rot, d_tr = float(np.linalg.norm(x[:3])), float(np.linalg.norm(x[3:]))
        history.append(
            dict(
                iteration=it + 1,
                fitness=fit,
                inlier_fraction=frac,
                inlier_rmse=rmse,
                plane_rmse=last[3],
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
    return IcpResult(
        T=T,
        fitness=fit,
        inlier_rmse=rmse,
        iterations=len(history),
        converged=converged,
        inlier_fraction=frac,
        plane_rmse=prmse,
        history=history,
    )
