"""The seam stage end to end: :func:`extract_seams` (eqs. 11-17 -> classes -> chained polylines) and
:func:`chain_seams` (weldable points -> ordered, refined, resampled seams)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree
from weldcell.sdk.cloud import ScanStructure
from weldcell.sdk.errors import DataError

from ..cloud_numerics import NeighbourTable, noise_level, sampling_spacings
from . import scales
from .candidates import classify_edges, point_normals
from .chaining import Bridging, _cluster_pieces, _end_directions, _Piece, bridge_pieces
from .edges import _usable_table, edge_scores
from .model import CONCAVE, GROOVE, WELDABLE, SeamExtraction, SeamPolyline, _as_points
from .ordering import _orthogonal_to_travel, _smooth_approach, _smooth_positions, _straight
from .orientation import scan_side_normals
from .refinement import (
    _curved_wall_nodes,
    _cut_end_corners,
    _mostly_straight,
    _orient,
    _refine_nodes,
    _resample,
    _root_opening,
    _trim_turning_ends,
)
from .settings import ChainSettings, SeamSettings
from .support import SupportPlane, drop_contact, on_support, support_plane
from .tracing import Growing, grow_pieces

# A cloud is read as an anisotropic (line-by-line) scan when its coarse spacing exceeds this x its fine
# spacing (:func:`~weldcell.plugins.scan_plan.cloud_numerics.sampling_spacings`, measured after the
# denoiser's voxel grid): then the PCA normals take as many neighbours as reach across the coarse spacing.
# Measured on the evaluation set (cases 0-230, seed 0): area RGB-D 1.36-1.71 (Table II's D415 frames up
# to 1.69, tilted), structured light 1.14-1.36, swept laser line 2.05-6.13. At 1.5 (until 2026-11-24,
# fifth session) half the RGB-D clouds and Table II's tilted frame took 13-point normals: tilted rotation
# RMSE 0.67 -> 0.95 deg. 1.85 lies between the two groups (their geometric mean).
ANISOTROPIC = 1.85


def chain_seams(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    weld_idx: np.ndarray,
    weld_labels: np.ndarray,
    approach: np.ndarray,
    cfg: ChainSettings,
) -> list[SeamPolyline]:
    """Cluster the weldable points and turn the clusters into ordered, resampled polylines.

    Points are linked within ``cfg.eps`` when their approach directions differ by less than
    ``max_approach_angle``; each connected component is ordered along the longest path of its
    minimum spanning tree (closed when the path's ends are within ``2 eps``; open paths without the side
    branches they fold back along) and binned at ``spacing`` (:func:`_cluster_pieces`).
    Pieces whose ends are close (``max_gap``) and collinear (``max_gap_angle``) are chained across the
    gap (:func:`bridge_pieces`). Each chain is snapped onto the side planes fitted within
    ``side_radius`` (``refine``), resampled at ``spacing``, smoothed (quadratic Savitzky-Golay over
    ``smooth_length`` or ``smooth_window`` nodes, whichever is longer; robust for the approach).
    Chains where fewer than ``min_fit_fraction`` of the nodes show two distinct side planes are dropped
    (noise on a flat surface), and open seams are trimmed to the fitted nodes. Curved and closed chains
    (not within 1 % of a straight line) take their nodes and approach from quadric wall patches within
    ``wall_radius`` (:func:`_curved_wall_nodes`; 0 disables): planes fit straight joints exactly, but
    sit inside curved walls.
    """
    if len(weld_idx) < 3:
        return []
    pieces = _fitted_pieces(P, N, tree, _clusters(P, weld_idx, weld_labels, approach, cfg), cfg)
    s = cfg
    if s.max_grow > 0 and s.refine:
        growing = Growing(
            spacing=s.spacing,
            eps=s.eps,
            side_radius=s.side_radius,
            approach_radius=s.approach_radius,
            min_crease_angle=min(s.min_crease_angle, s.grow_min_crease_angle),
            max_length=s.max_grow,
        )
        pieces = grow_pieces(P, N, tree, pieces, growing)
    if s.max_gap > 0 and s.refine:
        bridging = Bridging(
            max_gap=s.max_gap,
            max_angle=s.max_gap_angle,
            spacing=s.spacing,
            side_radius=s.side_radius,
            min_crease_angle=min(s.min_crease_angle, s.grow_min_crease_angle),
            approach_radius=s.approach_radius,
        )
        pieces = bridge_pieces(P, N, tree, pieces, bridging)
    seams: list[SeamPolyline] = []
    for piece in sorted(pieces, key=lambda p: -len(p.X)):
        seam = _polyline(P, N, tree, piece, cfg, len(seams))
        if seam is not None:
            seams.append(seam)
    return seams


def _clusters(
    P: np.ndarray, weld_idx: np.ndarray, weld_labels: np.ndarray, approach: np.ndarray, cfg: ChainSettings
) -> list[_Piece]:
    """The weldable points linked within ``cfg.eps`` (approach directions agreeing), each component of
    at least 5 points ordered into a piece (:func:`_cluster_pieces`), largest first."""
    M = len(weld_idx)
    X = P[weld_idx]
    pairs = cKDTree(X).query_pairs(cfg.eps, output_type="ndarray")
    if len(pairs):
        agree = np.einsum("ij,ij->i", approach[pairs[:, 0]], approach[pairs[:, 1]])
        pairs = pairs[agree > np.cos(cfg.max_approach_angle)]
    i, j = pairs[:, 0], pairs[:, 1]
    w = np.linalg.norm(X[i] - X[j], axis=1) + 1e-12
    G = coo_matrix((w, (i, j)), shape=(M, M)).tocsr()
    n_comp, comp = connected_components(G, directed=False)
    G = G + G.T
    mst = minimum_spanning_tree(G)
    sizes = np.bincount(comp, minlength=n_comp)
    big = np.flatnonzero(sizes >= 5)
    order = np.argsort(comp, kind="stable")
    members = np.split(order, np.cumsum(sizes)[:-1])
    groups = [members[c] for c in big[np.argsort(-sizes[big], kind="stable")]]
    raw = _cluster_pieces(X, approach, groups, G, mst, cfg.eps, cfg.spacing, weld_labels)
    return [p for p in raw if p is not None]


def _fitted_pieces(
    P: np.ndarray, N: np.ndarray, tree: cKDTree, raw: list[_Piece], cfg: ChainSettings
) -> list[_Piece]:
    """The pieces snapped onto their side planes (``cfg.refine``; all nodes in one batch: one search, one
    set of plane fits); pieces without two side planes along most of them are dropped, open ones
    trimmed to their fitted nodes."""
    if not (cfg.refine and raw):
        return list(raw)
    cuts = np.cumsum([len(p.X) for p in raw])[:-1]
    fits = _refine_nodes(
        P, N, tree, np.vstack([p.X for p in raw]), cfg.side_radius, cfg.approach_radius, cfg.min_crease_angle
    )
    pieces = []
    for piece, fit in zip(raw, zip(*(np.split(a, cuts) for a in fits), strict=True), strict=True):
        Xs, A_fit, ok, crease = fit
        if ok.mean() < cfg.min_fit_fraction:  # no two distinct side planes along most of it: not a joint
            continue
        As = np.where(ok[:, None], A_fit, piece.A)
        if not piece.closed:  # trim ends where the two side planes could not be fitted
            good = np.flatnonzero(ok)
            sl = slice(good[0], good[-1] + 1)
            Xs, As, ok, crease = Xs[sl], As[sl], ok[sl], crease[sl]
            sl = _trim_turning_ends(Xs)
            Xs, As, ok, crease = Xs[sl], As[sl], ok[sl], crease[sl]
            if len(Xs) < 3:
                continue
        pieces.append(_Piece(Xs, As, piece.closed, piece.labels, ok, crease))
    return pieces


def _polyline(
    P: np.ndarray, N: np.ndarray, tree: cKDTree, piece: _Piece, cfg: ChainSettings, seam_id: int
) -> SeamPolyline | None:
    """One chained piece as a seam: curved walls fitted, smoothed, resampled at ``cfg.spacing``, ends
    cut where smoothing overshot or the trace turned, approach orthogonal to travel and oriented; None
    when it is shorter than ``cfg.min_length`` or of a class not in ``cfg.joints``."""
    spacing = cfg.spacing
    Xs, As, closed = piece.X, piece.A, piece.closed
    ok = piece.ok if piece.ok is not None else np.ones(len(Xs), dtype=bool)
    crease = piece.crease if piece.crease is not None else np.zeros(len(Xs))
    curved = closed or len(Xs) < 3 or not _straight(Xs)
    groove = cfg.refine and len(Xs) >= 3 and _joint_class(piece, ok, crease, cfg) == "groove"
    if groove and not closed and (not curved or _mostly_straight(Xs)):
        # at the root opening, where the walls end; also a straight groove with a few stray nodes when
        # it has an opening (else it keeps the curved-wall fit it had)
        Xo = _root_opening(P, N, tree, Xs, cfg.side_radius)
        if not curved or not np.array_equal(Xo, Xs):
            Xs, curved = Xo, False
    if cfg.refine and cfg.wall_radius > 0 and len(Xs) >= 3 and ok.any() and curved:
        Xw, Aw, ok_w = _curved_wall_nodes(
            P, N, tree, Xs, cfg.approach_radius, cfg.wall_radius, cfg.side_radius
        )
        use = ok & ok_w & (np.linalg.norm(Xw - Xs, axis=1) < cfg.side_radius / 6.0)
        Xs = np.where(use[:, None], Xw, Xs)
        As = np.where(use[:, None], Aw, As)
    # smoothing window: smooth_length, but at most 1/8 of the seam (a quadratic fit over more of a
    # small ring would shrink it)
    window = max(int(cfg.smooth_window), int(round(cfg.smooth_length / spacing)) | 1)
    L = float(np.linalg.norm(np.diff(Xs, axis=0), axis=1).sum())
    w = max(int(cfg.smooth_window), min(window, int(L / (8.0 * spacing)) | 1))
    As = _smooth_approach(As, ok, w, closed, curved)
    Xr, Ar = _resample(Xs, As, spacing, closed)
    Xr = _smooth_positions(Xr, w, closed)
    Ar = _smooth_approach(Ar, np.ones(len(Ar), dtype=bool), w, closed, curved)
    if not closed:
        cut = _cut_overshoot(Xs, Xr, Ar, spacing)
        if cut is None:
            return None
        Xr, Ar = cut
    Xr, Ar = _resample(Xr, Ar, spacing, closed)  # smoothing moved the nodes: equal steps again
    # open ends again: a hook the resampling straightened into a fold, or an L (a trace that turned)
    for trim in () if closed else (_trim_turning_ends, _cut_end_corners):
        sl = trim(Xr)
        if sl != slice(0, len(Xr)):
            Xr, Ar = _resample(Xr[sl], Ar[sl], spacing, closed)
    ring = np.vstack([Xr, Xr[:1]]) if closed else Xr
    length = float(np.linalg.norm(np.diff(ring, axis=0), axis=1).sum())
    if length < cfg.min_length or len(Xr) < 2:
        return None
    Ar = _orthogonal_to_travel(Xr, Ar, closed)
    Xr, Ar = _orient(Xr, Ar, closed)
    joint = _joint_class(piece, ok, crease, cfg)
    if joint not in cfg.joints:
        return None
    return SeamPolyline(seam_id, joint, Xr, Ar, bool(closed), length)


def _joint_class(piece: _Piece, ok: np.ndarray, crease: np.ndarray, cfg: ChainSettings) -> str:
    """The joint class, "groove" or "concave": the included angle of the fitted side planes decides
    (``cfg.refine``), else the piece's majority label."""
    if cfg.refine and ok.sum() >= 3:
        return "groove" if np.pi - np.median(crease[ok]) < cfg.groove_max_angle else "concave"
    return "groove" if piece.labels[GROOVE] > piece.labels[CONCAVE] else "concave"


def _cut_overshoot(
    Xs: np.ndarray, Xr: np.ndarray, Ar: np.ndarray, spacing: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Smoothing must not lengthen an open seam, and its ends can still fold back: cut them (None when
    fewer than 3 nodes are left)."""
    end_len = max(0.01, 3 * spacing)
    d0, d1 = _end_directions(Xs, spacing, end_len)
    # only nodes near each end can overshoot it (a long seam that curves may pass behind the plane
    # through its far end)
    k_end = np.arange(len(Xr))
    near0 = k_end < max(3, int(round(end_len / spacing)))
    near1 = k_end >= len(Xr) - max(3, int(round(end_len / spacing)))
    inside = ~(near0 & (np.einsum("ij,j->i", Xr - Xs[0], d0) > 0)) & ~(
        near1 & (np.einsum("ij,j->i", Xr - Xs[-1], d1) > 0)
    )
    Xr, Ar = Xr[inside], Ar[inside]
    if len(Xr) < 3:
        return None
    sl = _trim_turning_ends(Xr)
    return Xr[sl], Ar[sl]


def extract_seams(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    settings: SeamSettings | None = None,
    *,
    neighbours: NeighbourTable | None = None,
    viewpoints: np.ndarray | None = None,
    structure: ScanStructure | None = None,
    **overrides: object,
) -> SeamExtraction:
    """Edge points (eqs. 11-17) and ordered weld seams of a cloud in metres.

    ``settings`` is a :class:`SeamSettings`; keyword ``overrides`` replace its fields (e.g. ``t=60``),
    so ``extract_seams(P, t=60, min_seam_length=0.02)`` reads as before the settings object.

    Args:
        points: (N, 3) cloud (ideally denoised and voxel down-sampled, spacing ~1-2 mm).
        normals: optional (N, 3) normals; only their orientation (sign) is used, to orient the PCA
            normals: pass them facing the sensor/outward. Without them the normals face the sensor side
            found from the scan itself (:mod:`~.orientation`: the side of the supporting table or
            fixture the part is on, propagated along the smoothest paths), or ``up`` when it is set.
        contact_seams: keep the part's contact lines with the plane it rests on or is held against
            (:mod:`~.support`, found from the cloud); by default they are not seams and are dropped.
        coarse_reach: on an anisotropic scan (a laser line profiler: ~1 mm along a line, 5-7 mm between
            lines) r of eq. 11 and the side fits reach at least this x the coarse spacing
            (:func:`~weldcell.plugins.scan_plan.cloud_numerics.sampling_spacings`), the PCA normals hold as
            many neighbours as that disc; isotropic clouds are unchanged (3 x spacing is larger).
        m: minimum neighbourhood size (eq. 11). t: threshold on ``Tr(H)^3/Det(H)`` (eq. 16, >= 27).
        sigma: Gaussian of eq. 17 in m (default: per-point std of neighbour distances, as the paper).
        radius: r of eq. 11 in m (default ``radius_factor`` x median point spacing).
        floor: noise floor added to H before eq. 16 (x median Tr(H)/3; 0 = as printed).
        min_intensity: edge points also need ``I >= min_intensity`` (eq. 12; 0 disables).
        joints: which classes become seams. min_crease_angle / groove_max_angle: see
            :func:`classify_edges`. class_radius_factor: side-fit radius as a multiple of r.
        cluster_eps: link distance of the clustering (default 2 r). spacing: seam resampling step
            (default r). min_seam_length: shorter seams are dropped (m). smooth_window: nodes.
        fit_radius: radius (m) of the two-side-plane fits that give the seam's approach direction
            (default ``max(class_radius_factor * r, 8 mm)``: enough points for sub-degree planes); the
            seam points are snapped with fits at ``class_radius_factor * r``.
        max_gap: pieces of one seam whose ends are at most this far apart (m) and collinear are
            chained across the gap (0 disables). max_grow: open seams are traced along their joint
            beyond their ends by at most this much (m) per end, joining the pieces they reach
            (:func:`grow_pieces`; 0 disables). smooth_length: smoothing window along the seam (m).
        neighbours: optional :class:`~weldcell.plugins.scan_plan.cloud_numerics.NeighbourTable` of ``points``
            (the denoising stage's shared search); replaces the KD-tree searches of eq. 11 and of the
            normals when it reaches at least r.
        viewpoints: optional (V, 3) camera positions of the scans (the job's ``meta["viewpoints"]``):
            a concave crease counts only when both its sides face a camera at less than
            ``max_incidence`` (rad) -- see :func:`classify_edges`.
        wall_radius: radius (m) of the quadric wall patches that place the nodes and approach of curved
            and closed seams (default 4 x ``fit_radius``, 32 mm; 0 keeps the side planes), see
            :mod:`~weldcell.plugins.scan_plan.wall_quadrics`.
        structure: optional :class:`~weldcell.sdk.cloud.ScanStructure` of the scan, measured on the cloud
            as captured (the job's ``cloud.structure``). On a line scan its spacing between lines and its
            noise (across lines) replace the ones measured here (:func:`_sampling`); on an area scan, or
            without it, the stage measures them on ``points``.
    """
    s = SeamSettings.of(settings, **overrides)
    s.check()
    P = _as_points(points, s.m)
    tree = cKDTree(P)
    fine, coarse, line_noise = _sampling(P, tree, structure)
    es = _edge_step(P, tree, s, neighbours, fine, coarse)
    I, score, r = es.intensity, es.ratio, es.radius
    r_fine = min(r, s.radius_factor * fine) if s.radius is None else r
    table = _usable_table(P, neighbours)
    with np.errstate(invalid="ignore"):
        edge = (score >= s.t) & (I >= s.min_intensity)
    N, plane = _normals(P, tree, normals, s, table, fine, coarse, noise=line_noise)
    labels, seams, support = _seams_on(P, N, tree, edge, plane, s, r, r_fine, viewpoints)
    if not seams and plane is not None and plane.ambiguous and normals is None and s.up is None:
        # The plane hypothesis left no seam: a lone plate's face can pass for a table (its groove then
        # looks like a part behind it, and every normal flips). Without the hypothesis the cloud is read
        # as before support planes existed. Not when the plane surely holds the part (a table or fixture
        # reaching beyond it): its orientation stands, and the re-reading, whose normals all flip, would
        # report the part's convex ridges (a thin corner's roof) as concave seams facing the table.
        N, plane = _normals(P, tree, normals, s, table, fine, coarse, find_support=False, noise=line_noise)
        labels, seams, support = _seams_on(P, N, tree, edge, None, s, r, r_fine, viewpoints)
    if not seams:  # the joint's faces may be narrower than the side fits' radius: a finer reading
        seams = _fine_seams(P, N, tree, edge, labels, support, s, (r, r_fine), (fine, coarse), viewpoints)
    params = dict(m=s.m, t=s.t, radius=r, sigma=s.sigma, floor=s.floor, min_intensity=s.min_intensity)
    params.update(spacing=(fine, coarse), support=None if support is None else support.normal.tolist())
    return SeamExtraction(edge, score, I, labels, seams, r, params)


def _sampling(
    P: np.ndarray, tree: cKDTree, structure: ScanStructure | None
) -> tuple[float, float, float | None]:
    """``(fine, coarse, noise)``: the cloud's spacings along its finest and coarsest sampling directions
    (m) and, on a line scan, its surface noise (m; None: measure it on ``P``, :func:`noise_level`).

    Both spacings are measured on ``P`` (:func:`sampling_spacings`), except on a line scan
    (``structure.line_structured``), whose ``fine`` spacing is the one along its lines and whose noise
    is the one across its lines, both measured on the scan as captured (:class:`ScanStructure`): on the
    stage's cloud the voxel grid has thinned the lines (nearest neighbour 1.2-1.5 mm where the profiler
    samples 0.7-1.3 mm) and k-nearest noise estimates stay within one laser sheet (its flatness, not the
    surface's noise). The coarse spacing stays the measured one: where two sweeps cross (a quarter of
    the set's profiler scans) the structure's line spacing is one sweep's, while the cloud's lines lie
    closer; the choice was measured on the 77 line-laser cases (seams doc, "Scan structure wired")."""
    fine, coarse = sampling_spacings(P, tree)
    if structure is None or not structure.line_structured:
        return fine, coarse, None
    return min(structure.along_spacing, fine), coarse, structure.noise


def _edge_step(
    P: np.ndarray,
    tree: cKDTree,
    s: SeamSettings,
    neighbours: NeighbourTable | None,
    fine: float,
    coarse: float,
):
    """Eqs. 11-17 on the cloud (:func:`edge_scores`) with the settings ``s``: on an anisotropic scan the
    neighbourhood reaches at least ``s.coarse_reach`` x the ``coarse`` spacing (and holds the columns
    such a disc needs)."""
    return edge_scores(
        P,
        m=s.m,
        radius=s.radius,
        radius_factor=s.radius_factor,
        k_max=_wide_enough(s.k_max, s.coarse_reach * coarse, fine, coarse),
        sigma=s.sigma,
        floor=s.floor,
        min_intensity=s.min_intensity,
        neighbours=neighbours,
        min_radius=s.coarse_reach * coarse,
        tree=tree,
    )


def _seams_on(P, N, tree, edge, plane, s, r, r_fine, viewpoints):
    """Labels, seams and the support plane in use, given oriented normals ``N`` and the found ``plane``
    (its contact lines are dropped unless ``s.contact_seams``)."""
    support = None if s.contact_seams or plane is None or not plane.holds_part else plane
    labels = np.zeros(len(P), dtype=np.int8)
    cand = np.flatnonzero(edge)
    seams: list[SeamPolyline] = []
    if len(cand):
        R = s.class_radius(r, r_fine)
        lab, appr = classify_edges(P, N, tree, cand, R, s.classifying(), viewpoints=viewpoints)
        labels[cand] = lab
        keep = np.isin(lab, [WELDABLE[j] for j in s.joints]) & ~on_support(P, tree, support, P[cand], R)
        cfg = s.chain(r, r_fine)
        seams = chain_seams(P, N, tree, cand[keep], lab[keep], appr[keep], cfg)
        if support is not None:
            seams = drop_contact(P, tree, seams, support, cfg.side_radius, cfg.min_length)
    return labels, seams, support


def _fine_seams(P, N, tree, edge, labels, support, s, radii, spacing, viewpoints):
    """Seams at the fine radius (:mod:`~.scales`: a joint whose faces are narrower than the side fits'
    class radius, e.g. a thin corner's notch), read when the stage's scale found none; ``labels`` take the
    fine classes of the points used. ``radii``: eq. 11's r and r_fine, ``spacing``: (fine, coarse). No
    seam when the sampling or the noise do not allow a finer reading (:func:`~.scales.fine_radius`,
    :func:`~.scales.resolvable`)."""
    cand = np.flatnonzero(edge)
    (r, r_fine), (fine, coarse) = radii, spacing
    Rf = scales.fine_radius(fine, coarse, s.coarse_reach)
    if not len(cand) or Rf > scales.FINE_GAIN * s.class_radius(r, r_fine):  # the same structure
        return []
    if coarse > ANISOTROPIC * fine:  # a line scan: no disc finer than its line gap (see scales)
        return []
    if not scales.resolvable(Rf, scales.cloud_noise(P, fine, coarse, s.coarse_reach)):
        return []
    i, lab, appr = scales.fine_candidates(P, N, tree, cand, labels[cand], Rf, s, viewpoints)
    keep = ~on_support(P, tree, support, P[cand[i]], Rf)
    i, lab, appr = i[keep], lab[keep], appr[keep]
    cfg_f = scales.fine_chain(s.chain(r, r_fine), Rf, s)
    seams = chain_seams(P, N, tree, cand[i], lab, appr, cfg_f)
    if support is not None:
        seams = drop_contact(P, tree, seams, support, cfg_f.side_radius, cfg_f.min_length)
    if seams:
        labels[cand[i]] = lab
    return seams


def _wide_enough(k_max: int, reach: float, fine: float, coarse: float) -> int:
    """``k_max`` neighbour columns, or as many as a disc of radius ``reach`` holds on a scan sampled at
    ``fine`` x ``coarse`` (plus half again: the density varies), whichever is more."""
    return int(max(k_max, np.ceil(1.5 * np.pi * reach**2 / max(fine * coarse, 1e-18))))


def _normals(
    P: np.ndarray,
    tree: cKDTree,
    normals: np.ndarray | None,
    s: SeamSettings,
    table: NeighbourTable | None,
    fine: float,
    coarse: float,
    find_support: bool = True,
    noise: float | None = None,
) -> tuple[np.ndarray, SupportPlane | None]:
    """Oriented PCA normals and the plane the part rests on (:func:`~.support.support_plane`, None when
    the scan holds none or ``find_support`` is False). Normals are oriented along ``normals`` when
    given, towards ``s.up`` when set, else towards the sensor side found from the scan itself
    (:func:`~.orientation.scan_side_normals`).
    The PCA neighbourhood holds 10 points, or as many as reach ``s.coarse_reach`` x the coarse spacing
    (an anisotropic scan: coarse spacing above ``ANISOTROPIC`` x the fine one); the RANSAC band of the
    support comes from the cloud's noise
    (:func:`~weldcell.plugins.scan_plan.cloud_numerics.noise_level` within that reach, or ``noise``
    when given: a line scan's, measured across its lines)."""
    oriented = None
    if normals is not None:
        oriented = np.asarray(normals, dtype=float)
        if oriented.shape != P.shape or not np.all(np.isfinite(oriented)):
            raise DataError(
                f"normals must be a finite {P.shape} array, got {oriented.shape}",
                "pass one normal per point or normals=None",
            )
    anisotropic = coarse > ANISOTROPIC * fine or noise is not None  # noise given: a line scan
    k = min(_wide_enough(10, s.coarse_reach * coarse, fine, coarse) if anisotropic else 10, len(P))
    up = np.asarray(s.up, dtype=float) if s.up is not None else None
    if oriented is not None or up is not None:
        N = point_normals(P, tree, k, oriented, up, table)
        idx = None
    else:
        _, idx = tree.query(P, k=k, workers=-1)
        N = point_normals(P, tree, k, None, None, None, idx=idx)
    plane = None
    if find_support:
        measured = noise_level(P, max(3.0 * fine, s.coarse_reach * coarse), sample=4000)
        # a line scan's noise across its lines; never below what the neighbourhoods here read
        noise = measured if noise is None else max(noise, measured)
        plane = support_plane(P, N, noise, fine, margin=max(s.fit_radius or 0.0, 0.008))
    if idx is not None:
        N = scan_side_normals(P, N, idx, plane, contact=not anisotropic)
    return N, plane
