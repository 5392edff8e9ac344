"""Refinement of seam nodes: side planes fitted on both sides of the joint (the node snapped onto
their intersection line, the approach their bisector), quadric wall fits for curved walls, end trims
and orientation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..wall_quadrics import crease_point, tangent_planes
from .model import (
    BEHIND_TOL,
    CONVEX_DROPPED,
    MIN_INCLUDED_ANGLE,
    THIRD_SURFACE,
    TOE_INCLUDED,
    TOE_RADIUS,
    TOE_SHIFT,
    WALL_MAX_POINTS,
    WALL_MIN_CREASE,
    _unit,
)
from .sides import _dot3, _fit_two_planes, _sides_at

#: a groove node's root line is "empty" (an opening) when no point lies within the point spacing / this of
#: the side planes' intersection line (:func:`_empty_line`). A closed crease's surface crosses that
#: cylinder on both walls: within a side radius r of 6 mm it holds ~ 2 (2 r) (h / 3) / h^2 = 8 r / (3 h)
#: >= 4 points at spacings h <= 4 mm (none with a chance below e^-4). Measured on the evaluation set's
#: grooves (seed 0, median over a seam's nodes): closed and backed roots 3-8 points, open ones 0-1
EMPTY_LINE = 3.0

# ----------------------------------------------------------------------------- chaining


def _resample(X: np.ndarray, A: np.ndarray, spacing: float, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    if closed:
        X = np.vstack([X, X[:1]])
        A = np.vstack([A, A[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(X, axis=0), axis=1))])
    L = s[-1]
    if L <= 0:
        return X[:1], A[:1]
    n = max(int(round(L / spacing)), 1)
    t = np.linspace(0.0, L, n + 1)
    if closed:
        t = t[:-1]
    Xr = np.column_stack([np.interp(t, s, X[:, j]) for j in range(3)])
    Ar = _unit(np.column_stack([np.interp(t, s, A[:, j]) for j in range(3)]))
    return Xr, Ar


@dataclass(frozen=True)
class SideLimits:
    """What makes a node's two-side-plane fit usable (:func:`_refine_on_sides`)."""

    k: int = 256  # at most this many nearest cloud points per node
    min_side_fraction: float = 0.2  # share of the points each side holds
    min_included_angle: float = MIN_INCLUDED_ANGLE  # narrower "creases" are folded surfaces (rad)


def _refine_on_sides(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    X: np.ndarray,
    radius: float,
    min_crease_angle: float,
    limits: SideLimits = SideLimits(),  # noqa: B008 (frozen, immutable)
    query: tuple[np.ndarray, np.ndarray] | None = None,
    convex_share: bool = False,
) -> tuple[np.ndarray, ...]:
    """Snap seam nodes onto the intersection line of the two side planes fitted around them.

    ``limits`` (:class:`SideLimits`) holds ``k``, ``min_side_fraction`` and ``min_included_angle``.
    The planes are fitted to the (at most ``k`` nearest) cloud points within ``radius`` of each node.
    Returns the moved nodes, the approach ``-(n_a + n_b)/|.|`` of the fitted planes, a mask of the
    nodes where the fit was usable and the angle between the two plane normals (pi minus the included
    angle of the joint). Usable: the crease angle is at least
    ``min_crease_angle``, the included angle at least ``min_included_angle``, the points of each side lie
    in front of the other side's plane (concave) and both sides hold at least ``min_side_fraction`` of
    the points (a real joint has surface on both sides; the curled, noisy border of a scan has a few
    points only on its "second side"). Also returns the share of each node's points left out of the
    plane fits and, with ``convex_share``, the share that marks a convex edge (:func:`_convex_share`)."""
    k, min_side_fraction, min_included_angle = limits.k, limits.min_side_fraction, limits.min_included_angle
    _, valid0, na, nbv, in_a, Q = _sides_at(P, N, tree, X, radius, k, query)
    # planes n . (x - X) = d; points behind the other side's plane (a third surface) left out
    na, da, nbv, db, ca, cb, valid = _fit_two_planes(Q, valid0, na, nbv, in_a, behind_tol=BEHIND_TOL * radius)
    dropped = 1.0 - valid.sum(1) / np.maximum(valid0.sum(1), 1)
    crease = np.arccos(np.clip(np.einsum("ij,ij->i", na, nbv), -1.0, 1.0))
    ok = (ca >= 3) & (cb >= 3) & (np.minimum(ca, cb) >= min_side_fraction * (ca + cb))
    ok &= (crease >= min_crease_angle) & (np.pi - crease >= min_included_angle)
    ra, rb = _dot3(Q, na) - da[:, None], _dot3(Q, nbv) - db[:, None]
    on_a = valid & (np.abs(ra) <= np.abs(rb))
    on_b = valid & ~on_a
    ok &= _mean_where(rb, on_a) + _mean_where(ra, on_b) > 0  # concave: the air is inside the V
    A = np.stack([na, nbv], axis=1)  # (B, 2, 3)
    r = np.stack([-da, -db], axis=1)  # signed distances of X from the two planes
    AAt = np.einsum("bij,bkj->bik", A, A)
    AAt[~ok] = np.eye(2)
    lam = np.linalg.solve(AAt, r[..., None])[..., 0]
    step = np.einsum("bij,bi->bj", A, lam)
    step[~ok] = 0.0
    too_far = np.linalg.norm(step, axis=1) > radius
    step[too_far] = 0.0
    out = (X - step, -_unit(na + nbv), ok & ~too_far, crease, dropped)
    if convex_share:
        return (*out, _convex_share(valid0, ra, rb, BEHIND_TOL * radius))
    return out


def _convex_share(valid: np.ndarray, ra: np.ndarray, rb: np.ndarray, tol: float) -> np.ndarray:
    """Per row, the share of the points (of ``valid``) that make the crease convex: more than ``tol``
    behind one side's plane and not more than ``tol`` in front of the other (signed distances ``ra``,
    ``rb``). Beyond a convex edge (a pipe end's rim) each side runs on behind the other side's plane
    while staying on its own. A narrow third face parallel to one side -- the top of a thin lap joint's
    upper plate beyond its 2-3 mm edge face -- lies *in front of* that side's plane by the plate's
    thickness: it is left out of the plane fits too, but it is no sign of a convex edge."""
    behind = (ra < -tol) | (rb < -tol)
    front = (ra > tol) | (rb > tol)
    return (valid & behind & ~front).sum(1) / np.maximum(valid.sum(1), 1)


def _mostly_straight(X: np.ndarray, tol: float = 0.01, share: float = 0.95) -> bool:
    """Whether at least ``share`` of the nodes ``X`` lie within ``tol`` x the length of their principal
    line: a straight seam with a few stray nodes (a bridged or grown end, a node whose planes failed),
    which :func:`~.ordering._straight` (every node) reads as curved. Measured on the evaluation set's
    grooves (seed 0): 8 of 33 straight groove pieces have up to 1-9 % of their nodes 1.0-2.3 % off the
    line; 95 % of their nodes lie within 0.1-1.0 %."""
    if len(X) < 3:
        return False
    C = X - X.mean(axis=0)
    u = np.linalg.svd(C, full_matrices=False)[2][0]
    off = np.linalg.norm(C - np.outer(C @ u, u), axis=1)
    return float(np.quantile(off, share)) <= tol * float(np.ptp(C @ u))


def _root_opening(
    P: np.ndarray, N: np.ndarray, tree: cKDTree, X: np.ndarray, radius: float, min_share: float = 0.5
) -> np.ndarray:
    """Seam nodes ``X`` (on their side planes' intersection line, :func:`_refine_on_sides`) moved to the
    root opening when the joint demonstrably has one; ``X`` unchanged otherwise.

    With a root gap the bevel walls end before their planes meet: the root pass is aimed at the centre
    of the opening between the walls' lower ends, ``g/2 / tan(bevel)`` above the planes' intersection
    (1-2 mm on the evaluation set's grooves). Per node, from the side planes within ``radius``: each
    wall's points are its side's points within 3 x its residual RMS of its plane (the noise) and not
    across the line, its end the third lowest of them along the plane, away from the line (a measured
    point, not an extrapolation). A node *sees an opening* when the scan shows surface behind a wall
    plane (by more than that band) within 2 point spacings of the intersection: the slot's root faces
    or what lies below, seen through the gap; behind a fillet's or a closed root's crease is solid
    material. It also sees one when its root line is empty (:func:`_empty_line`: nothing shows within
    reach below the opening, an X-groove seen from one face). A seam moves only when at least
    ``min_share`` of its nodes see an opening (seams doc, "Issue 16, fourth session": 77-80 % of the
    nodes of a 1 mm gap, 7-14 % of a fillet and a gapless groove; seventh session: the empty line), each
    node to the midpoint of its two wall ends: each end the larger of its estimates along the plane and
    across the joint, as a running median along the seam; then the nodes' offsets across the seam as a
    running median too (:func:`_median_across`). Point spacing ``h``: ``d_k sqrt(pi / k)`` of the
    256-nearest neighbourhoods."""
    if len(X) < 3:
        return X
    query = tree.query(X, k=int(min(256, len(P))), workers=-1)
    _, valid0, na, nb, in_a, Q = _sides_at(P, N, tree, X, radius, 256, query)
    na, da, nb, db, ca, cb, valid = _fit_two_planes(Q, valid0, na, nb, in_a, behind_tol=BEHIND_TOL * radius)
    ok = (ca >= 3) & (cb >= 3)
    line = np.cross(na, nb)
    ok &= np.linalg.norm(line, axis=1) > 1e-3
    A = np.stack([na, nb], axis=1)
    AAt = np.einsum("bij,bkj->bik", A, A)
    AAt[~ok] = np.eye(2)
    xs = np.einsum("bij,bi->bj", A, np.linalg.solve(AAt, np.stack([da, db], axis=1)[..., None])[..., 0])
    line = _unit(line)
    bis = -_unit(na + nb)  # the approach: along the bisector, into the joint
    D = tuple(Q[j] - xs[:, j : j + 1] for j in range(3))  # the points relative to the intersection point
    r2 = D[0] ** 2 + D[1] ** 2 + D[2] ** 2
    # point spacing from the neighbourhood's density: k points on a disc of the k-th distance
    dist = query[0]
    h = np.median(dist[:, -1]) * np.sqrt(np.pi / dist.shape[1])
    ra, rb = _dot3(Q, na) - da[:, None], _dot3(Q, nb) - db[:, None]
    on_a = valid & (np.abs(ra) <= np.abs(rb))
    ends, bands = [], []
    for n, r, side in ((na, ra, on_a), (nb, rb, valid & ~on_a)):
        u = _unit(np.cross(line, n))
        u = u * np.where(_mean_where(_dot3(D, u), side) < 0, -1.0, 1.0)[:, None]
        band = 3.0 * np.sqrt(_mean_where(r**2, side))
        # the wall's end twice: along the plane (root faces or an X-groove's land below the end stay within
        # the band for a while and pull it towards the line) and across the joint (a floor seen through
        # the gap -- a backing bar, the table -- lies near the line and pulls that one in): a contaminant
        # only shortens its own estimate, so the wall ends at the larger
        lat = u - np.einsum("ij,ij->i", u, bis)[:, None] * bis
        sin_b = np.maximum(np.linalg.norm(lat, axis=1), 1e-3)
        low = np.zeros(len(X))
        for s, scale in ((_dot3(D, u), 1.0), (_dot3(D, lat / sin_b[:, None]), sin_b)):
            wall = side & (np.abs(r) <= band[:, None]) & (s > -band[:, None])  # not across the line
            low = np.maximum(low, np.sort(np.where(wall, s, np.inf), axis=1)[:, 2] / scale)
        ends.append((u, low))
        bands.append(band)
    (ua, la), (ub, lb) = ends
    behind = (ra < -bands[0][:, None]) | (rb < -bands[1][:, None])
    slot = (valid0 & behind & (r2 <= (2.0 * h) ** 2)).any(1)
    if (ok & (slot | _empty_line(D, r2, line, (ua, ub), valid0, h))).mean() < min_share:
        return X
    # the wall ends of one node are a few samples' extremes: along a straight groove the opening holds its
    # width, so each node takes the running median over the nodes within 2 radii (its neighbourhood and
    # the next ones on either side)
    step = float(np.median(np.linalg.norm(np.diff(X, axis=0), axis=1)))
    half = int(min(np.ceil(2.0 * radius / max(step, 1e-9)), len(X)))
    la, lb = (_running_median(np.where(ok, v, np.nan), half) for v in (la, lb))
    move = ok & np.isfinite(la) & np.isfinite(lb)
    mid = 0.5 * (
        ua * np.where(move, np.maximum(la, 0.0), 0.0)[:, None]
        + ub * np.where(move, np.maximum(lb, 0.0), 0.0)[:, None]
    )
    # a node whose planes' intersection or wall ends lie far off (a fit that failed there) keeps its
    # place, like a curved wall's node (:func:`_curved_wall_nodes`: less than radius / 3)
    move &= np.linalg.norm(xs + mid, axis=1) < radius / 3.0
    out = np.array(X, dtype=float, copy=True)
    out[move] = X[move] + (xs + mid)[move]
    return _median_across(out, move, half)


def _median_across(X: np.ndarray, moved: np.ndarray, half: int) -> np.ndarray:
    """``X`` (nodes of a straight seam) with every node's offset across the seam's principal line replaced
    by the running median (``half`` nodes on either side) of the ``moved`` nodes' offsets: a node's planes
    and wall ends come from its own few samples, and a node that could not be moved (its fit failed)
    would stay at the planes' intersection, a millimetre or more off."""
    if moved.sum() < 3:
        return X
    c = X[moved].mean(axis=0)
    e = np.linalg.svd(X[moved] - c, full_matrices=False)[2][0]
    across = (X - c) - np.outer((X - c) @ e, e)
    med = np.column_stack([_running_median(np.where(moved, a, np.nan), half) for a in across.T])
    fit = np.isfinite(med).all(1)
    out = X.copy()
    out[fit] += med[fit] - across[fit]
    return out


def _running_median(v: np.ndarray, half: int) -> np.ndarray:
    """Median of the finite values of ``v`` within ``half`` places on either side (NaN where none)."""
    w = np.where(np.isfinite(v), v, np.nan)
    pad = np.concatenate([np.full(half, np.nan), w, np.full(half, np.nan)])
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1)
    out = np.full(len(v), np.nan)
    some = np.isfinite(win).any(1)
    out[some] = np.nanmedian(win[some], axis=1)
    return out


def _empty_line(
    D: tuple[np.ndarray, ...],
    r2: np.ndarray,
    line: np.ndarray,
    walls: tuple[np.ndarray, np.ndarray],
    valid: np.ndarray,
    h: float,
) -> np.ndarray:
    """Per node, whether its root line is empty: no point (of ``valid``; offsets ``D`` from the planes'
    intersection point, squared distances ``r2``) within ``h / EMPTY_LINE`` of the intersection line,
    while the same cylinder laid on each wall (parallel, ``2 h`` out along ``walls``, the in-plane
    directions away from the line) holds at least 3 -- where a scan samples its surfaces that finely, a
    closed crease's surface would show on the line too. The walls end before they meet and nothing is
    seen within reach below the opening (an X-groove's far root lies a land's depth further down)."""
    tol2 = (h / EMPTY_LINE) ** 2
    along = _dot3(D, line)
    on_line = (valid & (r2 - along**2 <= tol2)).sum(1)
    sampled = np.ones(len(on_line), dtype=bool)
    for u in walls:
        c = 2.0 * h * u
        Dc = tuple(D[j] - c[:, j : j + 1] for j in range(3))
        rc2 = Dc[0] ** 2 + Dc[1] ** 2 + Dc[2] ** 2 - along**2
        sampled &= (valid & (rc2 <= tol2)).sum(1) >= 3
    return sampled & (on_line == 0)


def _curved_wall_nodes(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    X: np.ndarray,
    plane_radius: float,
    wall_radius: float,
    side_radius: float,
    iterations: int = 2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seam nodes and approach directions of a curved joint from quadric wall patches
    (:mod:`~weldcell.plugins.scan_plan.wall_quadrics`): the sides are split by the two planes fitted
    within ``plane_radius``, each wall is fitted within ``wall_radius`` and the node moves onto the
    intersection of the walls' tangent planes (twice: the second pass is centred on the moved node).
    Returns the nodes, the approach ``-(n_a + n_b)`` of the tangent planes and a mask of the nodes
    where both walls were fitted and the node moved by less than ``side_radius / 3``; elsewhere the
    input node is kept."""
    X = np.array(X, dtype=float, copy=True)
    ok_all = np.ones(len(X), dtype=bool)
    A = np.zeros_like(X)
    Pt = np.ascontiguousarray(P.T)
    for _ in range(iterations):
        dist0, idx0 = tree.query(X, k=int(min(256, len(P))), workers=-1)
        _, valid0, na, nb, in_a, Q = _sides_at(P, N, tree, X, plane_radius, 256, query=(dist0, idx0))
        na, da, nb, db, ca, cb, _ = _fit_two_planes(
            Q, valid0, na, nb, in_a, behind_tol=BEHIND_TOL * plane_radius
        )
        crease = np.arccos(np.clip(np.einsum("ij,ij->i", na, nb), -1.0, 1.0))
        ok = (ca >= 3) & (cb >= 3) & (crease >= WALL_MIN_CREASE)
        # as many neighbours as the wall patches hold: the density seen by the 256-nearest query
        reach = float(np.median(dist0[:, -1]))
        k = int(min(len(P), WALL_MAX_POINTS, max(256, 256 * (wall_radius / max(reach, 1e-9)) ** 2)))
        dist, idx = tree.query(X, k=k, workers=-1)
        Qw = tuple(Pt[j][idx] - X[:, j : j + 1] for j in range(3))
        tp = tangent_planes(
            Qw,
            dist <= wall_radius,
            na,
            da,
            nb,
            db,
            radius=wall_radius,
            u_min=side_radius / 4.0,
            band=2.0 * side_radius,
            tol=side_radius / 12.0,
        )
        q = crease_point(tp)
        ok &= tp.ok & (np.linalg.norm(q, axis=1) < side_radius / 3.0)
        X[ok] += q[ok]
        A = -_unit(tp.n_a + tp.n_b)
        ok_all &= ok
    return X, A, ok_all


def _mean_where(v: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Row means (B,) of ``v`` (B, K) over ``mask`` (0 where a row has no member)."""
    return np.where(mask, v, 0.0).sum(1) / np.maximum(mask.sum(1), 1)


def _trim_turning_ends(X: np.ndarray, max_turn: float = np.deg2rad(30.0), max_nodes: int = 8) -> slice:
    """Slice without the end nodes whose step turns by more than ``max_turn`` from the direction of the
    seam a few nodes further in (an end that folds back or runs onto another edge)."""
    a, b = 0, len(X)
    cos = np.cos(max_turn)

    def turned(u: np.ndarray, v: np.ndarray) -> bool:
        return float(np.dot(u, v)) < cos * float(np.linalg.norm(u) * np.linalg.norm(v))

    for _ in range(max_nodes):
        if b - a < 8 or not turned(X[a + 1] - X[a], X[a + 6] - X[a + 3]):
            break
        a += 1
    for _ in range(max_nodes):
        if b - a < 8 or not turned(X[b - 1] - X[b - 2], X[b - 4] - X[b - 7]):
            break
        b -= 1
    return slice(a, b)


def _cut_end_corners(X: np.ndarray, max_turn: float = np.deg2rad(45.0), max_nodes: int = 10) -> slice:
    """Slice without a short run at either end that meets the seam at a corner: where, within
    ``max_nodes`` of the end, the direction turns by more than ``max_turn`` between the two-step chords
    before and after a node (a trace that ran along the part's end before it found the joint: an L, not
    a fold, which :func:`_trim_turning_ends` misses when the run is longer than its reference window).
    Arcs turn by 2 x spacing / radius there: < 45 deg down to a radius of ~2.5 x spacing."""
    n = len(X)
    if n < 2 * max_nodes:
        return slice(0, n)
    cos = np.cos(max_turn)

    def corner(idx: range) -> int | None:
        for i in idx:
            u, v = X[i] - X[i - 2], X[i + 2] - X[i]
            if float(np.dot(u, v)) < cos * float(np.linalg.norm(u) * np.linalg.norm(v)):
                return i
        return None

    a = corner(range(2, max_nodes))
    b = corner(range(n - 3, n - max_nodes - 1, -1))
    return slice(0 if a is None else a + 1, n if b is None else b)


def _orient(
    X: np.ndarray, A: np.ndarray, closed: bool, min_curl: float = 0.02
) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic travel direction, one convention for every piece of a curved seam.

    Closed seams, and open ones that curve (the area swept about their centroid is at least
    ``min_curl`` x length^2, e.g. an arc of more than ~15 deg of a pipe junction), run counter-clockwise
    seen from the torch (looking along the mean approach), so the open pieces of a closed curve travel
    the same way round as the whole loop would. Straight open seams run along their principal axis
    (sign: largest component positive).
    """
    length = float(np.linalg.norm(np.diff(X, axis=0), axis=1).sum())
    c = X - X.mean(axis=0)
    area = 0.5 * np.cross(c, np.roll(c, -1, axis=0)).sum(axis=0)  # closed by the chord when open
    axis = -_unit(A.mean(axis=0))
    about = float(area @ axis)
    if closed or abs(about) >= min_curl * length**2:
        flip = about < 0
    else:
        u = np.linalg.svd(c, full_matrices=False)[2][0]
        u = u * np.sign(u[np.argmax(np.abs(u))])
        flip = float((X[-1] - X[0]) @ u) < 0
    return (X[::-1].copy(), A[::-1].copy()) if flip else (X, A)


def _refine_nodes(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    X: np.ndarray,
    side_radius: float,
    approach_radius: float,
    min_crease_angle: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_refine_on_sides` at two scales: the approach, crease angle and the usable-node mask from
    the side planes within ``approach_radius`` (large: many points, sub-degree normals; by symmetry the
    bisector of two planes fitted to a curved wall is still the local one), the position from those
    within ``side_radius`` where that fit is usable too (small: planes fitted to a strongly curved wall
    over a large radius sit inside it and pull the intersection line inwards). Two exceptions: an acute
    node whose two positions disagree (curved walls, the Y-pipe's toe) takes its position from planes
    within ``TOE_RADIUS * side_radius``; a node whose approach-radius fit saw a third surface (a narrow
    face) takes the approach of the ``side_radius`` planes."""
    workers = -1 if len(X) >= 64 else 1  # threads cost more than they save on a few nodes (a trace step)
    query = tree.query(X, k=int(min(256, len(P))), workers=workers)  # one search for both scales
    X2, A, ok, crease, dropped = _refine_on_sides(
        P, N, tree, X, approach_radius, min_crease_angle, query=query
    )
    if approach_radius > side_radius:
        Xs, As, ok_s, _, _, convex_s = _refine_on_sides(
            P, N, tree, X, side_radius, min_crease_angle, query=query, convex_share=True
        )
        # a convex edge whose noise leaves a small concave lip (a pipe's end rim): most of the points
        # lie behind the other side's plane even at the side radius; a narrow face's third surface (a
        # lap plate's top, in reach of the side radius when the plate is 2-3 mm thin) lies in front of
        # the lower plate's plane and does not count (seams doc, "Issue 16, sixth session")
        ok &= convex_s <= CONVEX_DROPPED
        both = ok & ok_s
        # an acute crease whose two position estimates disagree has curved walls (the Y-pipe's toe): its
        # plane intersection at side_radius still lies inside the curve: position from smaller planes
        toe = both & (np.linalg.norm(Xs - X2, axis=1) > TOE_SHIFT) & (np.pi - crease < TOE_INCLUDED)
        X2 = np.where(both[:, None], Xs, X2)
        if toe.any():
            i = np.flatnonzero(toe)
            Xt, _, ok_t, _, _ = _refine_on_sides(P, N, tree, X[i], TOE_RADIUS * side_radius, min_crease_angle)
            X2[i[ok_t]] = Xt[ok_t]
        # a third surface within the approach radius (a narrow face, e.g. a thin lap plate's edge): the
        # planes of the smaller radius see less of what lies beyond it
        A = np.where((both & (dropped > THIRD_SURFACE))[:, None], As, A)
    return X2, A, ok, crease
