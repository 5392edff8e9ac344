"""The correspondence search of the scan-and-plan ICP (:func:`~.registration.linear_icp`): nearest
target points re-queried only where they may have changed (:class:`NearestCache`), in Morton order of
the source points, and target normals estimated only where they are needed (:class:`LazyNormals`)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from weldcell.sdk.arrays import col_max, col_min, row_dot

from .cloud_numerics import knn_normals
from .nearest import PointTree

#: below this many query points one thread is faster than starting worker threads
_THREADED_QUERY = 4000


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
            n = knn_normals(self.target, self.tree, self.k, miss)
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
