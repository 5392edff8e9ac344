"""Chaining of weldable points into ordered pieces: radius-graph clusters ordered along a minimum
spanning-tree diameter (side rows and spurs cut off), and bridging of collinear pieces across gaps."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse.csgraph import dijkstra, minimum_spanning_tree
from scipy.spatial import cKDTree

from .model import _unit
from .refinement import _refine_nodes, _refine_on_sides


@dataclass
class _Piece:
    """An ordered run of seam nodes (one cluster of weldable points, or several bridged ones)."""

    X: np.ndarray  # (K, 3) nodes along the run
    A: np.ndarray  # (K, 3) unit approach directions
    closed: bool
    labels: np.ndarray  # (6,) counts of the point classes behind the run
    ok: np.ndarray | None = None  # (K,) nodes where two side planes were fitted (after refinement)
    crease: np.ndarray | None = None  # (K,) angle between the fitted side-plane normals (rad)


def _farthest(
    graph, groups: list[np.ndarray], sources: np.ndarray, directed: bool, predecessors: bool = False
):
    """One batched Dijkstra from one source per group (component): distances (M,) from each node's own
    source, the farthest node of every group and, when asked, the predecessors (M,)."""
    res = dijkstra(graph, directed=directed, indices=sources, min_only=True, return_predecessors=predecessors)
    d = res[0] if predecessors else res
    far = np.array([g[np.argmax(np.where(np.isfinite(d[g]), d[g], -1.0))] for g in groups])
    return (d, far, res[1]) if predecessors else (d, far)


def _trace(pred: np.ndarray, start: int, end: int) -> np.ndarray:
    """Node indices from ``start`` to ``end`` along a Dijkstra predecessor array (rooted at start)."""
    path = [end]
    while path[-1] != start:
        path.append(pred[path[-1]])
    return np.array(path[::-1])


def _tree_diameters(mst, groups: list[np.ndarray]) -> list[np.ndarray]:
    """Ordered node indices of the longest path of the spanning tree of every group (double sweep,
    batched over the groups: two Dijkstra runs in all)."""
    _, a = _farthest(mst, groups, np.array([g[0] for g in groups]), directed=False)
    _, b, pred = _farthest(mst, groups, a, directed=False, predecessors=True)
    return [_trace(pred, start, end) for start, end in zip(a, b, strict=True)]


def _fold(path: np.ndarray, geo: np.ndarray, tol: float) -> int:
    """Index into ``path`` where the path turns back, or -1: the node after which the geodesic distance
    ``geo`` (from ``path[0]`` in the link graph) falls more than ``tol`` below its running maximum."""
    g = geo[path]
    back = np.flatnonzero(g < np.maximum.accumulate(g) - tol)
    return int(np.argmax(g[: back[0]])) if len(back) else -1


def _unfold_path(
    graph, X: np.ndarray, nodes: np.ndarray, path: np.ndarray, geo: np.ndarray, eps: float, rounds: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """The tree path of a cluster without the side branches it folds back along (monotone ordering),
    and the geodesic distances from its start.

    On sparse points the diameter of the minimum spanning tree can end in a side row or spur: it then
    runs back alongside the seam, so the chain folds at that end (its first or last points run
    backwards). Along a path that follows the seam the geodesic distance from its start in the link
    ``graph`` (``geo``) grows monotonically -- a side row within ``eps`` of the seam has about the
    distance of the seam beside it -- so a fall of more than ``eps`` marks the fold (:func:`_fold`).
    The shorter part of the path at the fold is the side branch: its nodes are set aside, the spanning
    tree of the cluster's other nodes is built again and the path re-grown from the kept end to its
    farthest node (e.g. the real seam end, which the old tree may have reached through the branch);
    repeated while a fold remains (at most ``rounds`` times). The set-aside points still belong to
    the cluster (they are binned with the nearest path node). ``nodes``: the cluster's node indices
    into ``graph``, ``path``: its tree diameter, ``geo``: distances from ``path[0]`` in ``graph``.
    """
    local = np.full(graph.shape[0], -1)
    local[nodes] = np.arange(len(nodes))
    sub = graph[nodes][:, nodes]
    aside = np.zeros(len(nodes), dtype=bool)
    for _ in range(rounds):
        f = _fold(path, geo, eps)
        if f < 0:
            break
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(X[path], axis=0), axis=1))])
        if s[f] < s[-1] - s[f]:  # the start is the side branch: keep the end
            path = path[::-1]
            f = len(path) - 1 - f
            geo = dijkstra(graph, directed=True, indices=path[0])
        aside[local[path[f + 1 :]]] = True
        keep = np.flatnonzero(~aside)
        tree = minimum_spanning_tree(sub[keep][:, keep])
        start = int(np.searchsorted(keep, local[path[0]]))
        d, pred = dijkstra(tree, directed=False, indices=start, return_predecessors=True)
        end = int(np.argmax(np.where(np.isfinite(d), d, -1.0)))
        path = nodes[keep[_trace(pred, start, end)]]
    return path, geo


def _bin_means(V: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Means of the rows of ``V`` in the bins ``b`` (occupied bins, in order) and their counts."""
    nbins = int(b.max()) + 1
    cnt = np.bincount(b, minlength=nbins)
    occ = cnt > 0
    sums = np.stack([np.bincount(b, weights=V[:, d], minlength=nbins) for d in range(V.shape[1])], 1)
    return sums[occ] / cnt[occ][:, None], cnt[occ]


def _cluster_pieces(
    X: np.ndarray,
    A: np.ndarray,
    groups: list[np.ndarray],
    graph,
    mst,
    eps: float,
    spacing: float,
    labels: np.ndarray,
) -> list[_Piece | None]:
    """Order each cluster (node indices ``groups`` into ``X``) and average its points in bins of
    ``spacing`` along that order.

    The backbone is the longest path of the cluster's minimum spanning tree, with the side branches it
    folds back along cut off (:func:`_unfold_path`); a backbone whose ends are within ``2 eps`` is a
    closed loop (never unfolded: along a loop the geodesic distance from the start falls after half
    way). Every point takes the arclength of its nearest backbone node. Monotonicity check: along an
    open backbone the bins' mean geodesic distance from the start (in the link ``graph``) must grow;
    a bin more than ``eps`` behind the bins before it would make the chain reverse and is dropped (less
    is the zigzag of a tree path across a band of edge points, which the refinement and smoothing absorb).
    """
    paths = _tree_diameters(mst, groups)
    closed = []
    for path in paths:
        B = X[path]
        L_path = float(np.linalg.norm(np.diff(B, axis=0), axis=1).sum())
        closed.append(float(np.linalg.norm(B[-1] - B[0])) <= 2.0 * eps and L_path > 6.0 * eps)
    open_ids = [i for i, c in enumerate(closed) if not c and len(paths[i]) >= 3]
    geo = None
    if open_ids:  # geodesic distances from every open path's start, one batched Dijkstra
        geo = dijkstra(graph, directed=True, indices=np.array([paths[i][0] for i in open_ids]), min_only=True)
    out: list[_Piece | None] = []
    for nodes, path, is_closed in zip(groups, paths, closed, strict=True):
        if len(path) < 3:
            out.append(None)
            continue
        if not is_closed:
            path, geo_c = _unfold_path(graph, X, nodes, path, geo, eps)
        B = X[path]
        s_path = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(B, axis=0), axis=1))])
        _, near = cKDTree(B).query(X[nodes])  # arclength of every point = that of its nearest backbone node
        b = (s_path[near] / spacing).astype(int)
        Xs, _ = _bin_means(X[nodes], b)
        As, _ = _bin_means(A[nodes], b)
        if not is_closed:  # monotonicity: drop bins that run back along the seam
            g, _ = _bin_means(geo_c[nodes][:, None], b)
            g = g[:, 0]
            keep = g >= np.maximum.accumulate(g) - eps
            Xs, As = Xs[keep], As[keep]
        if len(Xs) < 3:
            out.append(None)
            continue
        lab = np.bincount(labels[nodes].astype(int), minlength=6)
        out.append(_Piece(Xs, _unit(As), bool(is_closed), lab))
    return out


def _end_directions(X: np.ndarray, spacing: float, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit directions at the start and the end of an ordered run: principal axis of the
    nodes within ``length`` of each end, pointing out of the run."""
    k = int(np.clip(round(length / spacing), 1, len(X) - 1))
    out = []
    for Q, chord in ((X[: k + 1], X[0] - X[k]), (X[-1 - k :], X[-1] - X[-1 - k])):
        u = np.linalg.svd(Q - Q.mean(axis=0), full_matrices=False)[2][0]
        out.append(u if float(u @ chord) >= 0 else -u)
    return out[0], out[1]


def _gap_nodes(a: np.ndarray, b: np.ndarray, Aa: np.ndarray, Ab: np.ndarray, spacing: float):
    """Nodes strictly between ``a`` and ``b`` at about ``spacing`` (approach interpolated linearly)."""
    n = int(np.floor(np.linalg.norm(b - a) / spacing)) - 1
    if n <= 0:
        return np.empty((0, 3)), np.empty((0, 3))
    f = np.arange(1, n + 1)[:, None] / (n + 1.0)
    return a + f * (b - a), _unit(Aa + f * (Ab - Aa))


@dataclass(frozen=True)
class Bridging:
    """Settings of :func:`bridge_pieces` (lengths in m, angles in rad)."""

    max_gap: float  # longest gap bridged
    max_angle: float  # end directions anti-parallel, and the gap along them, within this
    spacing: float  # node step across the gap
    side_radius: float  # radius of the side-plane fits that verify the gap
    min_crease_angle: float  # the joint's smallest crease angle in those fits
    max_approach_angle: float = float(np.deg2rad(45.0))  # the two ends' approach directions agree within this
    min_support: float = 0.5  # share of gap nodes that must show two side planes
    approach_radius: float = 0.0  # radius of the approach fits on the gap nodes (0: ``side_radius``)


@dataclass(frozen=True)
class _Bridger:
    """The cloud and the settings of :func:`bridge_pieces`: the tests and the gap filling it applies."""

    P: np.ndarray
    N: np.ndarray
    tree: cKDTree
    cfg: Bridging

    def compatible(self, a, b, da, db, aa, ab) -> bool:
        """Ends ``a``, ``b`` (outward directions ``da``, ``db``, approaches ``aa``, ``ab``) close enough,
        anti-parallel, with approaches that agree and (beyond two nodes) a gap that runs along both."""
        c = self.cfg
        cos_t = np.cos(c.max_angle)
        g = b - a
        dist = float(np.linalg.norm(g))
        if dist > c.max_gap or -float(da @ db) < cos_t or float(aa @ ab) < np.cos(c.max_approach_angle):
            return False
        if dist > 2.0 * c.spacing:
            u = g / dist
            if float(da @ u) < cos_t or -float(db @ u) < cos_t:
                return False
        return True

    def verified(self, a, b, Aa, Ab) -> bool:
        """The joint is there in the gap: at least ``min_support`` of its nodes show two side planes."""
        c = self.cfg
        Xg, _ = _gap_nodes(a, b, Aa, Ab, c.spacing)
        if len(Xg) == 0:
            return True
        fit = _refine_on_sides(self.P, self.N, self.tree, Xg, c.side_radius, c.min_crease_angle)
        return float(fit[2].mean()) >= c.min_support

    def fill(self, a, b, Aa, Ab):
        """The gap's nodes snapped onto their side planes: (X, A, ok, crease), or None for no gap node
        (the approach stays interpolated where no two planes were fitted)."""
        c = self.cfg
        Xg, Ag = _gap_nodes(a, b, Aa, Ab, c.spacing)
        if not len(Xg):
            return None
        Xg, Af, okg, crg = _refine_nodes(
            self.P, self.N, self.tree, Xg, c.side_radius, c.approach_radius, c.min_crease_angle
        )
        return Xg, np.where(okg[:, None], Af, Ag), okg, crg


def bridge_pieces(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    pieces: list[_Piece],
    settings: Bridging | None = None,
    **overrides: float,
) -> list[_Piece]:
    """Join open pieces whose ends are close and whose directions agree (gap bridging).

    ``settings`` is a :class:`Bridging`; keyword ``overrides`` replace its fields (or give them all,
    e.g. ``bridge_pieces(P, N, tree, pieces, max_gap=0.03, max_angle=0.35, spacing=0.0015, ...)``).
    Two piece ends are linked when they are at most ``max_gap`` apart, their outward directions (chords
    over ~10 mm) are anti-parallel within ``max_angle``, the gap runs along both directions (for gaps
    longer than two nodes) within ``max_angle``, their approach directions agree within
    ``max_approach_angle``, and the joint is really there in the gap: at least ``min_support`` of the
    nodes interpolated across it show two side planes (:func:`_refine_on_sides`). Links are accepted
    greedily, shortest gap first, each end at most once and never closing a cycle between different
    pieces (:func:`_link_ends`); a chain whose own two ends then satisfy the same test is closed into a
    loop (:func:`_chain`).
    """
    cfg = replace(settings, **overrides) if settings is not None else Bridging(**overrides)
    br = _Bridger(P, N, tree, cfg)
    open_ids = [i for i, p in enumerate(pieces) if not p.closed]
    out = [p for p in pieces if p.closed]
    if not open_ids:
        return out
    E, D, Ae = _piece_ends([pieces[i] for i in open_ids], cfg.spacing)
    link = _link_ends(br, E, D, Ae)
    seen = np.zeros(len(open_ids), dtype=bool)
    for start in range(len(open_ids)):
        if seen[start] or (link[2 * start] >= 0 and link[2 * start + 1] >= 0):
            continue
        out.append(_chain(br, [pieces[i] for i in open_ids], link, start, seen))
    return out


def _piece_ends(pieces: list[_Piece], spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both ends of every open piece (rows 2i, 2i + 1 for start and end of piece i): positions, outward
    directions (:func:`_end_directions` over ``max(1 cm, 3 spacing)``) and mean approach of 5 nodes."""
    tan_len = max(0.01, 3 * spacing)
    E, D, Ae = [], [], []
    for p in pieces:
        d0, d1 = _end_directions(p.X, spacing, tan_len)
        m = min(len(p.X), 5)
        E += [p.X[0], p.X[-1]]
        D += [d0, d1]
        Ae += [_unit(p.A[:m].mean(0)), _unit(p.A[-m:].mean(0))]
    return np.array(E), np.array(D), np.array(Ae)


def _link_ends(br: _Bridger, E: np.ndarray, D: np.ndarray, Ae: np.ndarray) -> np.ndarray:
    """For every end, the end it is bridged to (-1: none): candidate pairs within ``max_gap`` accepted
    shortest first when both ends are free, the pieces not yet in one chain (union-find) and the pair
    :meth:`_Bridger.compatible` and :meth:`_Bridger.verified`."""
    pairs = cKDTree(E).query_pairs(br.cfg.max_gap, output_type="ndarray")
    pairs = pairs[pairs[:, 0] // 2 != pairs[:, 1] // 2]
    gaps = np.linalg.norm(E[pairs[:, 1]] - E[pairs[:, 0]], axis=1)
    link = np.full(len(E), -1)
    parent = list(range(len(E) // 2))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for k in np.argsort(gaps):
        ea, eb = int(pairs[k, 0]), int(pairs[k, 1])
        if link[ea] >= 0 or link[eb] >= 0 or find(ea // 2) == find(eb // 2):
            continue
        if not br.compatible(E[ea], E[eb], D[ea], D[eb], Ae[ea], Ae[eb]):
            continue
        if not br.verified(E[ea], E[eb], Ae[ea], Ae[eb]):
            continue
        link[ea], link[eb] = eb, ea
        parent[find(ea // 2)] = find(eb // 2)
    return link


def _chain(br: _Bridger, pieces: list[_Piece], link: np.ndarray, start: int, seen: np.ndarray) -> _Piece:
    """The chain of open ``pieces`` that starts at piece ``start`` (a free end), following ``link``
    (marks its pieces ``seen``), with the refined gap nodes between them; closed into a loop when it is
    at least 6 nodes and ``4 max_gap`` long and its own ends pass the bridging tests."""
    cur, entry = start, (0 if link[2 * start] < 0 else 1)
    Xs, As, oks, crs, lab = [], [], [], [], np.zeros(6, dtype=np.int64)
    while True:
        seen[cur] = True
        p = pieces[cur]
        okp = p.ok if p.ok is not None else np.ones(len(p.X), dtype=bool)
        crp = p.crease if p.crease is not None else np.zeros(len(p.X))
        sl = slice(None) if entry == 0 else slice(None, None, -1)
        Xc, Ac = p.X[sl], p.A[sl]
        if Xs:
            gap = br.fill(Xs[-1][-1], Xc[0], As[-1][-1], Ac[0])
            if gap is not None:
                for parts, part in zip((Xs, As, oks, crs), gap, strict=True):
                    parts.append(part)
        Xs.append(Xc)
        As.append(Ac)
        oks.append(okp[sl])
        crs.append(crp[sl])
        lab += p.labels
        nxt = link[2 * cur + 1 - entry]
        if nxt < 0:
            break
        cur, entry = int(nxt) // 2, int(nxt) % 2
    X, A, ok, crease = np.vstack(Xs), np.vstack(As), np.concatenate(oks), np.concatenate(crs)
    closed = False
    L = float(np.linalg.norm(np.diff(X, axis=0), axis=1).sum())
    if len(X) >= 6 and L > 4.0 * br.cfg.max_gap:
        d0, d1 = _end_directions(X, br.cfg.spacing, max(0.01, 3 * br.cfg.spacing))
        a0, a1 = _unit(A[:5].mean(0)), _unit(A[-5:].mean(0))
        if br.compatible(X[-1], X[0], d1, d0, a1, a0) and br.verified(X[-1], X[0], a1, a0):
            closed = True
            gap = br.fill(X[-1], X[0], A[-1], A[0])
            if gap is not None:
                Xg, Ag, okg, crg = gap
                X, A = np.vstack([X, Xg]), np.vstack([A, Ag])
                ok, crease = np.concatenate([ok, okg]), np.concatenate([crease, crg])
    return _Piece(X, A, closed, lab, ok, crease)
