"""Weld-seam extraction from a workpiece point cloud (paper 000, section II-E, eqs. 11-17), plus the
joint classification and polyline chaining a weld path needs.

Paper part (per point, fully vectorised over fixed-width neighbour arrays from one KD-tree query):

* eq. 11 -- adaptive neighbourhood ``N_r(p)``: the points within radius ``r``, grown to the ``m``
  nearest where fewer than ``m`` lie inside ``r`` (the effective radius ``r_p`` is recorded);
* eq. 12 -- edge intensity ``I_p = |p - centroid(N_r(p))| / r_p``: the normalised displacement of a
  point from the centroid of its neighbours (low on smooth surface, a ridge along edges);
* eq. 13 -- 3-D gradient of the intensity, ``I_k = max_i (I_i - I_p) * delta_k / d^2`` (the steepest
  neighbour slope projected on axis k, see :func:`intensity_gradient` for why not ``d / delta_k``);
* eqs. 14-15, 17 -- structure tensor ``H = sum_i G(p, q_i) g_i g_i^T`` over ``N_r(p)`` with the
  Gaussian of eq. 17 (sigma = standard deviation of the neighbour distances);
* eq. 16 -- the eigenvalue-free edge test ``Tr(H)^3 / Det(H) >= t``.

Beyond the paper (the paper stops at a set of edge points):

* each edge point is classified from the oriented normals of its two sides (a 2-means split of the
  neighbour normals): ``concave`` (fillet / lap / corner roots), ``groove`` (V-groove bottoms: concave
  with a narrow included angle), ``convex`` (plate outlines, web tops), ``boundary`` (one-sided
  neighbourhood: scan borders, free plate edges) and ``weak`` (sides nearly parallel: noise);
* weldable points are clustered (KD-tree radius graph, approach directions must agree), each cluster
  is ordered along a minimum-spanning-tree diameter (works for curved and closed seams) from which the
  side rows and spurs it folds back along are cut (a monotonicity check of the geodesic distance from
  its start, :func:`_unfold_path`), binned along that arclength (bins that run back are dropped),
  snapped onto the intersection line of the two fitted side planes, smoothed and resampled at a fixed
  spacing into a :class:`SeamPolyline`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import savgol_filter
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra, minimum_spanning_tree
from scipy.spatial import cKDTree
from weldcell.sdk.arrays import row_sums
from weldcell.sdk.errors import DataError

from .denoise import NeighbourTable, knn_table, largest_eigvec, masked_covariance, offsets, smallest_eigvec
from .wall_quadrics import crease_point, tangent_planes

#: per-point class labels of :attr:`SeamExtraction.labels`
NONE, CONCAVE, GROOVE, CONVEX, BOUNDARY, WEAK = 0, 1, 2, 3, 4, 5
LABEL_NAMES = {
    NONE: "none",
    CONCAVE: "concave",
    GROOVE: "groove",
    CONVEX: "convex",
    BOUNDARY: "boundary",
    WEAK: "weak",
}
WELDABLE = {"concave": CONCAVE, "groove": GROOVE}
#: smallest included angle of a weldable crease: sides that face each other more closely are the two faces
#: of a thin sheet or a scan border whose normals flipped, not a groove a torch (or a camera) can see into
MIN_INCLUDED_ANGLE = np.deg2rad(25.0)
#: side-plane fits of the refinement ignore points more than this x the fit radius behind the other
#: side's plane or off their own (a third surface, e.g. the top of a lap joint's upper plate beyond its
#: 6 mm edge face)
BEHIND_TOL = 0.15
#: a fit that left out more than this fraction of its points saw a third surface: it is fitted again
#: from the points within CORE_FRACTION x its radius, and the node takes the approach of the smaller
#: (position) radius
THIRD_SURFACE = 0.1
CORE_FRACTION = 0.5
#: acute creases (included angle below TOE_INCLUDED) whose position at the approach and the side radius
#: differ by more than TOE_SHIFT (m) take their position from planes within TOE_RADIUS x the side radius
#: (55 deg: the Y-pipe's 45 deg toe, not a 60 deg V-groove, whose root faces also make the two positions
#: differ; there the 4 mm planes only add ripple to the seam line, 0.67 -> 1.25 deg in the demo job)
TOE_INCLUDED = np.deg2rad(55.0)
TOE_SHIFT = 3e-4
TOE_RADIUS = 2.0 / 3.0
#: a node whose side-radius planes leave out more than this fraction of its points as lying behind
#: the other side's plane is a convex edge, not a joint (the Y-pipe's branch rim: 0.43; a lap joint: 0)
CONVEX_DROPPED = 0.3
#: below this many rows (a trace step) LAPACK's eigh is faster than the vectorised closed form
SMALL_BATCH = 16
#: at most this many points per node in the curved-wall fits (memory: nodes x points x 6 floats)
WALL_MAX_POINTS = 8000
#: the side planes must differ by this much for the crease line to be defined (obtuse flanks: 145 deg)
WALL_MIN_CREASE = np.deg2rad(10.0)


@dataclass
class SeamPolyline:
    """One ordered weld seam: ``points`` (K, 3) along travel, ``normals`` (K, 3) unit approach
    directions (pointing into the joint, i.e. from the torch towards the work)."""

    id: int
    joint_class: str
    points: np.ndarray
    normals: np.ndarray
    closed: bool
    length: float

    @property
    def approach(self) -> np.ndarray:
        """Alias of :attr:`normals`: unit approach directions (K, 3)."""
        return self.normals


@dataclass
class SeamExtraction:
    """Result of :func:`extract_seams`. Per-point arrays have one row per input point."""

    edge_mask: np.ndarray  # (N,) bool, eq. 16 edge points
    score: np.ndarray  # (N,) Tr(H)^3 / Det(H), eq. 16
    intensity: np.ndarray  # (N,) edge intensity, eq. 12
    labels: np.ndarray  # (N,) int8, see LABEL_NAMES (NONE for non-edge points)
    seams: list[SeamPolyline]
    radius: float  # the radius r used (m)
    params: dict = field(default_factory=dict)

    def label_names(self) -> np.ndarray:
        """Per-point class names (N,)."""
        return np.array([LABEL_NAMES[int(v)] for v in range(6)])[self.labels]


# ----------------------------------------------------------------------------- input checks


def _as_points(points: np.ndarray, m: int) -> np.ndarray:
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3:
        raise DataError(
            f"points must be an (N, 3) array, got shape {P.shape}", "pass x, y, z columns in metres"
        )
    if len(P) == 0:
        raise DataError(
            "the point cloud is empty", "check that the scan saw the workpiece and that cropping kept it"
        )
    if not np.all(np.isfinite(P)):
        bad = int((~np.all(np.isfinite(P), axis=1)).sum())
        raise DataError(
            f"points has {bad} rows with NaN or infinite coordinates",
            "drop invalid points first (weldcell.sdk.cloud.drop_invalid)",
        )
    if len(P) < m + 1:
        raise DataError(
            f"the cloud has {len(P)} points but the neighbourhood needs m={m} neighbours (eq. 11)",
            "pass a denser cloud or a smaller m",
        )
    return P


def _positive(value: float | None, name: str) -> float | None:
    if value is None:
        return None
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise DataError(f"{name} must be a positive number, got {value}", f"pass {name} > 0")
    return v


def _unit(v: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), eps)


# ----------------------------------------------------------------------------- eqs. 11-17


@dataclass
class Neighbourhood:
    """Fixed-width neighbour arrays (self excluded): ``idx``/``dist`` (N, K), ``valid`` (N, K) marks
    the members of ``N_r(p)`` (eq. 11), ``r_eff`` (N,) the grown radius."""

    idx: np.ndarray
    dist: np.ndarray
    valid: np.ndarray
    r_eff: np.ndarray


def adaptive_neighbourhood(
    P: np.ndarray,
    tree: cKDTree,
    r: float,
    m: int,
    k_max: int,
    table: NeighbourTable | None = None,
) -> Neighbourhood:
    """Eq. 11: ``N_r(p) = {q : |q - p| < r}``, grown to the ``m`` nearest where fewer lie within ``r``.

    At most ``k_max`` neighbours are kept (the nearest ones) so every array has a fixed width. The
    neighbours come from ``table`` (a :class:`NeighbourTable` of these points with at least ``k_max``
    neighbours within at least ``r``) or from one search bounded at ``2 r``; rows that hold fewer than
    ``m`` neighbours are searched again without a bound. Columns are not sorted by distance; the
    members are marked by ``valid``.
    """
    k = int(min(max(k_max, m), len(P) - 1))
    if table is None or table.radius < r or table.k < k:
        table = knn_table(P, k, radius=2.0 * r, tree=tree)
    idx, dist = table.idx[:, 1 : k + 1], table.dist[:, 1 : k + 1]
    finite = np.isfinite(dist)
    few = np.flatnonzero(row_sums(finite) < m)
    if len(few):  # not m neighbours within the table's reach: search those rows without a bound
        d_f, i_f = tree.query(P[few], k=k + 1, workers=-1)
        idx, dist = idx.copy(), dist.copy()
        idx[few], dist[few] = i_f[:, 1:], d_f[:, 1:]
    # the m nearest of each row (the row holds every point within the table's reach, nearest first)
    d_m = np.partition(dist, m - 1, axis=1)[:, m - 1]
    valid = (dist < r) | (dist <= d_m[:, None])
    r_eff = np.maximum(r, d_m)
    width = int(row_sums(valid).max())
    if width < k:  # drop the columns no row needs (the members first): narrower arrays below
        keep = np.argpartition(np.where(valid, dist, np.inf), width - 1, axis=1)[:, :width]
        idx, dist, valid = (np.take_along_axis(a, keep, 1) for a in (idx, dist, valid))
    fin = np.isfinite(dist)
    if not fin.all():  # entries beyond the search bound (never members): finite, for the masked sums
        dist = np.where(fin, dist, 2.0 * float(np.max(np.where(fin, dist, 0.0))) + r)
    return Neighbourhood(idx, dist, valid, r_eff)


def edge_intensity(P: np.ndarray, nb: Neighbourhood) -> np.ndarray:
    """Eq. 12: ``I_p = |p - (1/n) sum q_i| / r`` with the neighbourhood's (grown) radius as ``r``."""
    w = nb.valid.astype(float)
    inv = 1.0 / row_sums(w)
    s = [np.einsum("nk,nk->n", w, d) * inv for d in offsets(P, nb.idx)]  # centroid - p
    return np.sqrt(s[0] ** 2 + s[1] ** 2 + s[2] ** 2) / nb.r_eff


def intensity_gradient(P: np.ndarray, intensity: np.ndarray, nb: Neighbourhood) -> np.ndarray:
    """Eq. 13: per axis k, the steepest neighbour slope of the intensity, ``(I_i - I_p) delta_k / d^2``.

    The printed eq. 13 reads ``(I_i - I_p) d / delta_k``, which is unbounded when a neighbour has
    ``delta_k -> 0``; Fig. 5's caption ("the difference ... divided by the coordinate difference")
    and the Taylor model of eq. 14 both describe a slope. We use the slope towards neighbour i,
    ``(I_i - I_p) / d``, projected on axis k (``delta_k / d``), and take the neighbour of largest
    magnitude (sign kept), which equals the caption's quotient for a neighbour on the axis.
    """
    dI = np.where(nb.valid, intensity[nb.idx] - intensity[:, None], 0.0)
    f = dI / np.maximum(nb.dist, 1e-12) ** 2
    g = np.empty((len(P), 3))
    for k, delta in enumerate(offsets(P, nb.idx)):
        slope = f * delta
        j = np.abs(slope).argmax(axis=1)
        g[:, k] = np.take_along_axis(slope, j[:, None], axis=1)[:, 0]
    return g


def structure_tensor(
    grad: np.ndarray,
    nb: Neighbourhood,
    sigma: float | None = None,
    rows: np.ndarray | None = None,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Eqs. 14-15 smoothed with eq. 17: ``H_p = sum_{q in N_r(p) + p} G(p, q) g_q g_q^T / sum G``.

    ``G`` is the Gaussian of eq. 17 with, unless ``sigma`` (m) is given, the paper's choice: the
    standard deviation of the distances from p to its neighbours. Returns (N, 3, 3), or (len(rows), 3, 3)
    for the points ``rows`` only (each row computed exactly as in the full call). ``weights``: the
    :func:`tensor_weights` when already computed.
    """
    w = tensor_weights(nb, sigma) if weights is None else weights
    idx = nb.idx
    if rows is not None:
        w, idx, grad_p = w[rows], idx[rows], grad[rows]
    else:
        grad_p = grad
    gg = grad[:, :, None] * grad[:, None, :]
    H = grad_p[:, :, None] * grad_p[:, None, :]
    H = H + (w[:, None, :] @ gg.reshape(-1, 9)[idx]).reshape(-1, 3, 3)
    return H / (1.0 + row_sums(w))[:, None, None]


def tensor_weights(nb: Neighbourhood, sigma: float | None = None) -> np.ndarray:
    """Eq. 17 weights ``G(p, q)`` (N, K) of the neighbours (0 outside N_r(p)), up to the constant
    ``1/(sigma sqrt(2 pi))`` (it cancels in eq. 15's normalisation)."""
    if sigma is None:
        cnt = row_sums(nb.valid)
        dv = nb.dist * nb.valid
        mu = row_sums(dv) / cnt
        s = np.sqrt(np.maximum(np.einsum("nk,nk->n", dv, nb.dist) / cnt - mu**2, 0.0))
        s = np.maximum(s, 1e-3 * nb.r_eff)
    else:
        s = np.full(len(nb.idx), float(sigma))
    return np.exp(-(nb.dist**2) / (2.0 * s[:, None] ** 2)) * nb.valid


def tensor_trace(
    grad: np.ndarray, nb: Neighbourhood, sigma: float | None = None, weights: np.ndarray | None = None
) -> np.ndarray:
    """``Tr(H_p)`` (N,) of eq. 15 without forming H: ``(|g_p|^2 + sum G |g_q|^2) / (1 + sum G)``."""
    w = tensor_weights(nb, sigma) if weights is None else weights
    g2 = np.einsum("ij,ij->i", grad, grad)
    return (g2 + np.einsum("nk,nk->n", w, g2[nb.idx])) / (1.0 + row_sums(w))


def edge_ratio(H: np.ndarray, floor: float = 1.0) -> np.ndarray:
    """Eq. 16: ``Tr(H)^3 / Det(H)`` (27 for an isotropic H, growing with the eigenvalue spread).

    ``floor`` adds ``floor * median_p(Tr(H_p)) / 3`` to the diagonal first: the gradient energy of the
    surface noise, so that the ratio measures structure *above the noise* (with ``floor=0`` a flat,
    noisy patch whose gradients all lie in its plane has ``Det -> 0`` and passes any threshold).
    """
    tr = np.trace(H, axis1=1, axis2=2)
    return _floored_ratio(H, noise_floor(tr, floor))


def noise_floor(trace: np.ndarray, floor: float) -> float:
    """The diagonal term ``floor * median(Tr H) / 3`` added to every H before eq. 16 (see
    :func:`edge_ratio`); ``trace`` holds Tr(H) of *all* points."""
    eps = floor * float(np.median(trace)) / 3.0 if floor > 0 else 0.0
    return max(eps, 1e-12 * float(np.max(trace, initial=0.0)), 1e-300)


def _floored_ratio(H: np.ndarray, eps: float) -> np.ndarray:
    """Eq. 16 on ``H + eps I``: ``Tr^3 / Det`` with Det in closed form (inf where Det <= 0)."""
    a, b, c = H[:, 0, 0] + eps, H[:, 1, 1] + eps, H[:, 2, 2] + eps
    d, e, f = H[:, 0, 1], H[:, 0, 2], H[:, 1, 2]
    det = a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)
    tr = a + b + c
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        return np.where(det > 0, tr**3 / det, np.inf)


# ----------------------------------------------------------------------------- normals and classes


def point_normals(
    P: np.ndarray,
    tree: cKDTree,
    k: int = 10,
    oriented: np.ndarray | None = None,
    up: np.ndarray | None = None,
    table: NeighbourTable | None = None,
) -> np.ndarray:
    """Unit PCA normals from the ``k`` nearest neighbours (the point itself included), oriented.

    ``table`` (a :class:`NeighbourTable` of ``P``) replaces the KD-tree query where its rows hold at
    least ``k - 1`` neighbours (the nearest ones are picked from the row).

    Orientation: along ``oriented`` (given normals, e.g. facing the sensor) when given; otherwise the
    weld-cell heuristic: towards ``up`` where the surface is not steep, and for steep (wall) normals
    away from the vertical axis through the cloud centroid (outward for a part standing on a table).
    """
    k = int(min(k, len(P)))
    if table is not None and table.k >= k - 1:
        part = np.argpartition(table.dist[:, 1:], k - 2, axis=1)[:, : k - 1] + 1
        idx = np.concatenate([table.idx[:, :1], np.take_along_axis(table.idx, part, 1)], axis=1)
        short = np.flatnonzero(~np.isfinite(np.take_along_axis(table.dist, part, 1)).all(axis=1))
        if len(short):
            idx[short] = tree.query(P[short], k=k, workers=-1)[1]
    else:
        _, idx = tree.query(P, k=k, workers=-1)
    n = smallest_eigvec(masked_covariance(offsets(P, idx), np.ones(idx.shape))[0])
    if oriented is not None:
        ref = oriented
    else:
        u = _unit(np.asarray(up if up is not None else (0.0, 0.0, 1.0), dtype=float))
        out = P - P.mean(axis=0)
        out = out - np.outer(out @ u, u)
        steep = np.abs(n @ u) < 0.3
        ref = np.where(steep[:, None], out, u[None, :])
    flip = np.einsum("ij,ij->i", n, ref) < 0
    n[flip] *= -1.0
    return n


def _dot3(U: tuple[np.ndarray, ...], v: np.ndarray) -> np.ndarray:
    """Row-wise dot products (B, K) of component arrays ``U`` = (x, y, z), each (B, K), with ``v`` (B, 3)."""
    return U[0] * v[:, :1] + U[1] * v[:, 1:2] + U[2] * v[:, 2:]


def _wsum3(w: np.ndarray, U: tuple[np.ndarray, ...]) -> np.ndarray:
    """Weighted row sums (B, 3) of component arrays ``U`` with weights ``w`` (B, K)."""
    return np.stack([np.einsum("bk,bk->b", w, u) for u in U], axis=1)


def two_sides(nbr_normals: np.ndarray, valid: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, ...]:
    """Split each row of neighbour normals (B, K, 3) into two sides (2-means on the unit sphere).

    Starts from the principal axis of the normal scatter; returns ``(n_a, n_b, in_a)`` with side
    normals (B, 3) and the membership (B, K) of side a.
    """
    U = tuple(np.ascontiguousarray(nbr_normals[..., j]) for j in range(3))
    return _two_sides(U, valid, iterations)


def _two_sides(U: tuple[np.ndarray, ...], valid: np.ndarray, iterations: int = 3) -> tuple[np.ndarray, ...]:
    """:func:`two_sides` on the normals' components ``U`` = (x, y, z), each (B, K)."""
    w = valid.astype(float)
    C, cnt = masked_covariance(U, w)
    mean = _wsum3(w, U) / np.maximum(cnt, 1)[:, None]
    e = np.linalg.eigh(C)[1][..., 2] if len(C) <= SMALL_BATCH else largest_eigvec(C)
    in_a = _dot3(U, e) > (mean * e).sum(1)[:, None]
    for _ in range(iterations):
        na = _unit(_wsum3(w * in_a, U))
        nbv = _unit(_wsum3(w * ~in_a, U))
        in_a = _dot3(U, na) >= _dot3(U, nbv)
    return na, nbv, in_a


def _sides_at(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    X: np.ndarray,
    radius: float,
    k: int,
    query: tuple[np.ndarray, np.ndarray] | None = None,
):
    """Neighbours (at most ``k`` nearest, at least 4, within ``radius``) of the points ``X`` and their
    2-means split by normal. Returns ``idx, valid, n_a, n_b, in_a, Q`` with ``Q`` the neighbour offsets
    from X as components (x, y, z). ``query``: a (dist, idx) k-nearest result to reuse."""
    k = int(min(k, len(P)))
    dist, idx = tree.query(X, k=k, workers=-1) if query is None else query
    valid = dist <= radius
    valid[:, :4] = True
    if idx.size < len(P):  # a few nodes (e.g. one step of a trace): gather rows, don't transpose the cloud
        Ng, Pg = N[idx], P[idx]
        Nc = tuple(np.ascontiguousarray(Ng[..., j]) for j in range(3))
        Q = tuple(Pg[..., j] - X[:, j : j + 1] for j in range(3))
    else:  # per-coordinate gathers from transposed copies (4x faster than (B, K, 3) gathers)
        Nt, Pt = np.ascontiguousarray(N.T), np.ascontiguousarray(P.T)
        Nc = tuple(Nt[j][idx] for j in range(3))
        Q = tuple(Pt[j][idx] - X[:, j : j + 1] for j in range(3))
    na, nb_, in_a = _two_sides(Nc, valid)
    return idx, valid, na, nb_, in_a, Q


def classify_edges(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    cand: np.ndarray,
    radius: float,
    *,
    k: int = 32,
    min_crease_angle: float = np.deg2rad(35.0),
    groove_max_angle: float = np.deg2rad(75.0),
    boundary_shift: float = 0.25,
    min_side_fraction: float = 0.2,
    viewpoints: np.ndarray | None = None,
    max_incidence: float = np.deg2rad(75.0),
    min_included_angle: float = MIN_INCLUDED_ANGLE,
):
    """Class of each candidate edge point (indices ``cand``) from its neighbourhood within ``radius``.

    * sides: 2-means split of the oriented neighbour normals, refined by a two-plane fit -> ``n_a``, ``n_b``;
    * ``weak``: the sides differ by less than ``min_crease_angle`` and the centroid is not shifted
      sideways (noise on a smooth surface); ``boundary``: same, but the centroid is shifted by more
      than ``boundary_shift * radius`` within the tangent plane (one-sided neighbourhood);
    * two planes are fitted to the neighbourhood (:func:`fit_two_planes`); at a concave crease the
      points of each side lie in front of (on the normal side of) the other side's plane -- the air is
      inside the V -- and behind it at a convex one;
    * a concave crease must have real surface on both sides, else it is a ``boundary`` (the curled,
      noisy border of a scan seen at grazing incidence looks like a narrow V): each side holds at least
      ``min_side_fraction`` of the neighbours, and, when the camera positions ``viewpoints`` (V, 3) are
      given, each side's normal faces some camera at an incidence below ``max_incidence``;
    * a "crease" whose sides face each other within ``min_included_angle`` (included angle below it) is a
      ``boundary`` too: a surface folded onto itself, i.e. the two faces of a thin sheet or a scan border
      whose normals flipped (a rim seen at grazing incidence), not a gap a torch can reach;
    * concave creases whose included angle (pi - angle(n_a, n_b)) is below ``groove_max_angle`` are
      ``groove`` (butt V-grooves), the others ``concave`` (fillet, lap, corner roots).

    Returns ``labels`` (M,) and the approach directions ``-(n_a + n_b)/|.|`` (M, 3).
    """
    X = P[cand]
    idx, valid, na, nbv, in_a, Q = _sides_at(P, N, tree, X, radius, k)
    na, da, nbv, db, _, _, _ = _fit_two_planes(Q, valid, na, nbv, in_a)
    # re-split by plane distance, then: is each side in front of (concave) or behind (convex) the other?
    ra = _dot3(Q, na) - da[:, None]
    rb = _dot3(Q, nbv) - db[:, None]
    on_a = valid & (np.abs(ra) <= np.abs(rb))
    on_b = valid & ~on_a
    front = np.where(on_a, rb, 0).sum(1) / np.maximum(on_a.sum(1), 1) + np.where(on_b, ra, 0).sum(
        1
    ) / np.maximum(on_b.sum(1), 1)
    w = valid.astype(float)
    v = _wsum3(w, Q) / w.sum(1)[:, None]  # centroid - X
    crease = np.arccos(np.clip(np.einsum("ij,ij->i", na, nbv), -1.0, 1.0))
    bis = _unit(na + nbv)
    shift = np.linalg.norm(v - np.einsum("ij,ij->i", v, bis)[:, None] * bis, axis=1) / radius
    labels = np.full(len(cand), WEAK, dtype=np.int8)
    flat = crease < min_crease_angle
    labels[flat & (shift > boundary_shift)] = BOUNDARY
    labels[~flat & (front <= 0)] = CONVEX
    concave = ~flat & (front > 0)
    # a concave crease needs real surface on both sides: a scan border that curls (grazing views, noise)
    # has a narrow, sparse "second side" -> boundary
    na_cnt, nb_cnt = on_a.sum(1), on_b.sum(1)
    one_sided = np.minimum(na_cnt, nb_cnt) < min_side_fraction * np.maximum(na_cnt + nb_cnt, 1)
    if viewpoints is not None and len(viewpoints):
        # ... and both sides must have been seen by some camera at less than max_incidence (a side that
        # faces away from every camera, or is seen only at grazing incidence, is not measured surface)
        V = np.asarray(viewpoints, dtype=float).reshape(-1, 3)
        view = V[None, :, :] - X[:, None, :]
        view /= np.maximum(np.linalg.norm(view, axis=2, keepdims=True), 1e-12)
        cos_min = np.cos(max_incidence)
        seen_a = (np.einsum("bvj,bj->bv", view, na) >= cos_min).any(axis=1)
        seen_b = (np.einsum("bvj,bj->bv", view, nbv) >= cos_min).any(axis=1)
        one_sided |= ~(seen_a & seen_b)
    one_sided |= np.pi - crease < min_included_angle  # folded onto itself: no torch fits in
    labels[concave & one_sided] = BOUNDARY
    concave &= ~one_sided
    labels[concave] = np.where(np.pi - crease[concave] < groove_max_angle, GROOVE, CONCAVE)
    return labels, -bis


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


def fit_two_planes(
    Q: np.ndarray, valid: np.ndarray, n_a: np.ndarray, n_b: np.ndarray, in_a: np.ndarray, iterations: int = 3
) -> tuple[np.ndarray, ...]:
    """Fit two planes to each row of points (B, K, 3) by alternating PCA fits and re-assignment of
    every point to the closer plane (2-plane k-means). Starts from the normal split ``in_a``; plane
    normals keep the orientation of ``n_a`` / ``n_b``. Returns ``(n_a, d_a, n_b, d_b, count_a, count_b)``
    with planes ``n . x = d``."""
    U = tuple(np.ascontiguousarray(Q[..., j]) for j in range(3))
    return _fit_two_planes(U, valid, n_a, n_b, in_a, iterations)[:6]


def _fit_two_planes(
    U: tuple[np.ndarray, ...],
    valid: np.ndarray,
    n_a: np.ndarray,
    n_b: np.ndarray,
    in_a: np.ndarray,
    iterations: int = 3,
    behind_tol: float | None = None,
) -> tuple[np.ndarray, ...]:
    """:func:`fit_two_planes` on the points' components ``U`` = (x, y, z), each (B, K); also returns the
    mask of the points the final planes were fitted to.

    ``behind_tol`` (m): fit a *concave* crease. A point assigned to one side that lies more than this
    behind the other side's plane, or further than this from its own side's plane, is left out of the
    next fit: it belongs to a third surface beyond a convex edge (e.g. the upper plate's top behind the
    6 mm edge face of a lap joint), which would tilt the side plane it was assigned to. Rows where more
    than ``THIRD_SURFACE`` of the points were left out are fitted again, starting from the points within
    ``CORE_FRACTION`` of the radius (``behind_tol / BEHIND_TOL``): the normal split alone puts both
    plates' tops on one side, and a plane through both sits between them."""
    fit = _fit_planes_from(U, valid, valid, n_a, n_b, in_a, iterations, behind_tol, trim=False)
    if behind_tol is None:
        return fit
    i = np.flatnonzero(fit[6].sum(1) < (1.0 - THIRD_SURFACE) * valid.sum(1))
    fit = (*fit[:6], valid)
    if not len(i):
        return fit
    core = (CORE_FRACTION * behind_tol / BEHIND_TOL) ** 2
    near = valid[i] & (U[0][i] ** 2 + U[1][i] ** 2 + U[2][i] ** 2 <= core)
    enough = near.sum(1) >= 8
    i, near = i[enough], near[enough]
    if not len(i):
        return fit
    Ui = tuple(u[i] for u in U)
    again = _fit_planes_from(Ui, valid[i], near, n_a[i], n_b[i], in_a[i], iterations + 1, behind_tol)
    fit = tuple(f.copy() for f in fit)
    for whole, part in zip(fit, again, strict=True):
        whole[i] = part
    return fit


def _kept(valid: np.ndarray, ra: np.ndarray, rb: np.ndarray, tol: float) -> np.ndarray:
    """The points (of ``valid``) within ``tol`` of the nearer of two planes (signed distances ``ra``,
    ``rb``) and not more than ``tol`` behind the other one."""
    in_a = np.abs(ra) <= np.abs(rb)
    own, other = np.where(in_a, ra, rb), np.where(in_a, rb, ra)
    return valid & (np.abs(own) <= tol) & (other >= -tol)


def _fit_planes_from(
    U: tuple[np.ndarray, ...],
    valid: np.ndarray,
    use: np.ndarray,
    n_a: np.ndarray,
    n_b: np.ndarray,
    in_a: np.ndarray,
    iterations: int,
    behind_tol: float | None,
    trim: bool = True,
) -> tuple[np.ndarray, ...]:
    """:func:`_fit_two_planes` whose first fit uses only the points ``use`` (a subset of ``valid``); with
    ``trim``, later fits only the points :func:`_kept` by ``behind_tol``. The last item returned is the
    mask of the points kept by the final planes (``valid`` when ``behind_tol`` is None)."""
    out, kept = [], valid
    for _ in range(iterations):
        out = []
        for mask, ref in ((use & in_a, n_a), (use & ~in_a, n_b)):
            w = mask.astype(float)
            C, cnt = masked_covariance(U, w)
            c = _wsum3(w, U) / np.maximum(cnt, 1)[:, None]
            n = np.linalg.eigh(C)[1][..., 0] if len(C) <= SMALL_BATCH else smallest_eigvec(C)
            n[np.einsum("ij,ij->i", n, ref) < 0] *= -1.0
            n[cnt < 3] = ref[cnt < 3]
            out.append((n, np.einsum("ij,ij->i", n, c), cnt))
        (na, da, _), (nb, db, _) = out
        ra = _dot3(U, na) - da[:, None]
        rb = _dot3(U, nb) - db[:, None]
        in_a = np.abs(ra) <= np.abs(rb)
        if behind_tol is not None:
            kept = _kept(valid, ra, rb, behind_tol)
            use = kept if trim else valid
    (na, da, ca), (nb, db, cb) = out
    return na, da, nb, db, ca, cb, kept


def _refine_on_sides(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    X: np.ndarray,
    radius: float,
    min_crease_angle: float,
    k: int = 256,
    min_side_fraction: float = 0.2,
    query: tuple[np.ndarray, np.ndarray] | None = None,
    min_included_angle: float = MIN_INCLUDED_ANGLE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Snap seam nodes onto the intersection line of the two side planes fitted around them.

    The planes are fitted to the (at most ``k`` nearest) cloud points within ``radius`` of each node.
    Returns the moved nodes, the approach ``-(n_a + n_b)/|.|`` of the fitted planes, a mask of the
    nodes where the fit was usable and the angle between the two plane normals (pi minus the included
    angle of the joint). Usable: the crease angle is at least
    ``min_crease_angle``, the included angle at least ``min_included_angle``, the points of each side lie
    in front of the other side's plane (concave) and both sides hold at least ``min_side_fraction`` of
    the points (a real joint has surface on both sides; the curled, noisy border of a scan has a few
    points only on its "second side")."""
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
    return X - step, -_unit(na + nbv), ok & ~too_far, crease, dropped


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
        Xs, As, ok_s, _, dropped_s = _refine_on_sides(
            P, N, tree, X, side_radius, min_crease_angle, query=query
        )
        # a convex edge whose noise leaves a small concave lip (a pipe's end rim): most of the points
        # lie behind the other side's plane even at the side radius, where a narrow face's third
        # surface (the lap joint's upper plate, 12-15 % at the approach radius) is out of reach
        ok &= dropped_s <= CONVEX_DROPPED
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


def bridge_pieces(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    pieces: list[_Piece],
    *,
    max_gap: float,
    max_angle: float,
    spacing: float,
    side_radius: float,
    min_crease_angle: float,
    max_approach_angle: float = np.deg2rad(45.0),
    min_support: float = 0.5,
    approach_radius: float = 0.0,
) -> list[_Piece]:
    """Join open pieces whose ends are close and whose directions agree (gap bridging).

    Two piece ends are linked when they are at most ``max_gap`` apart, their outward directions (chords
    over ~10 mm) are anti-parallel within ``max_angle``, the gap runs along both directions (for gaps
    longer than two nodes) within ``max_angle``, their approach directions agree within
    ``max_approach_angle``, and the joint is really there in the gap: at least ``min_support`` of the
    nodes interpolated across it show two side planes (:func:`_refine_on_sides`). Links are accepted
    greedily, shortest gap first, each end at most once and never closing a cycle between different
    pieces; a chain whose own two ends then satisfy the same test is closed into a loop.
    """
    open_ids = [i for i, p in enumerate(pieces) if not p.closed]
    out = [p for p in pieces if p.closed]
    if not open_ids:
        return out
    tan_len = max(0.01, 3 * spacing)
    E, D, Ae = [], [], []
    for i in open_ids:
        p = pieces[i]
        d0, d1 = _end_directions(p.X, spacing, tan_len)
        m = min(len(p.X), 5)
        E += [p.X[0], p.X[-1]]
        D += [d0, d1]
        Ae += [_unit(p.A[:m].mean(0)), _unit(p.A[-m:].mean(0))]
    E, D, Ae = np.array(E), np.array(D), np.array(Ae)
    cos_t, cos_a = np.cos(max_angle), np.cos(max_approach_angle)

    def verified(a: np.ndarray, b: np.ndarray, Aa: np.ndarray, Ab: np.ndarray) -> bool:
        Xg, _ = _gap_nodes(a, b, Aa, Ab, spacing)
        if len(Xg) == 0:
            return True
        return float(_refine_on_sides(P, N, tree, Xg, side_radius, min_crease_angle)[2].mean()) >= min_support

    def compatible(ea: int, eb: int, a: np.ndarray, b: np.ndarray, da: np.ndarray, db: np.ndarray) -> bool:
        g = b - a
        dist = float(np.linalg.norm(g))
        if dist > max_gap or -float(da @ db) < cos_t or float(Ae[ea] @ Ae[eb]) < cos_a:
            return False
        if dist > 2.0 * spacing:
            u = g / dist
            if float(da @ u) < cos_t or -float(db @ u) < cos_t:
                return False
        return True

    pairs = cKDTree(E).query_pairs(max_gap, output_type="ndarray")
    pairs = pairs[pairs[:, 0] // 2 != pairs[:, 1] // 2]
    gaps = np.linalg.norm(E[pairs[:, 1]] - E[pairs[:, 0]], axis=1)
    link = np.full(len(E), -1)
    parent = list(range(len(open_ids)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for k in np.argsort(gaps):
        ea, eb = int(pairs[k, 0]), int(pairs[k, 1])
        if link[ea] >= 0 or link[eb] >= 0 or find(ea // 2) == find(eb // 2):
            continue
        if not compatible(ea, eb, E[ea], E[eb], D[ea], D[eb]):
            continue
        if not verified(E[ea], E[eb], Ae[ea], Ae[eb]):
            continue
        link[ea], link[eb] = eb, ea
        parent[find(ea // 2)] = find(eb // 2)

    seen = np.zeros(len(open_ids), dtype=bool)
    for start in range(len(open_ids)):
        if seen[start] or (link[2 * start] >= 0 and link[2 * start + 1] >= 0):
            continue
        cur, entry = start, (0 if link[2 * start] < 0 else 1)
        Xs, As, oks, crs, lab = [], [], [], [], np.zeros(6, dtype=np.int64)
        while True:
            seen[cur] = True
            p = pieces[open_ids[cur]]
            okp = p.ok if p.ok is not None else np.ones(len(p.X), dtype=bool)
            crp = p.crease if p.crease is not None else np.zeros(len(p.X))
            sl = slice(None) if entry == 0 else slice(None, None, -1)
            Xc, Ac = p.X[sl], p.A[sl]
            if Xs:
                Xg, Ag = _gap_nodes(Xs[-1][-1], Xc[0], As[-1][-1], Ac[0], spacing)
                if len(Xg):
                    Xg, Af, okg, crg = _refine_nodes(
                        P, N, tree, Xg, side_radius, approach_radius, min_crease_angle
                    )
                    Xs.append(Xg)
                    As.append(np.where(okg[:, None], Af, Ag))
                    oks.append(okg)
                    crs.append(crg)
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
        if len(X) >= 6 and L > 4.0 * max_gap:
            d0, d1 = _end_directions(X, spacing, tan_len)
            a0, a1 = _unit(A[:5].mean(0)), _unit(A[-5:].mean(0))
            Ae_save = Ae
            Ae = np.vstack([Ae_save, a1, a0])  # compatible() looks approach up by end index
            n = len(Ae)
            if compatible(n - 2, n - 1, X[-1], X[0], d1, d0) and verified(X[-1], X[0], a1, a0):
                closed = True
                Xg, Ag = _gap_nodes(X[-1], X[0], A[-1], A[0], spacing)
                if len(Xg):
                    Xg, Af, okg, crg = _refine_nodes(
                        P, N, tree, Xg, side_radius, approach_radius, min_crease_angle
                    )
                    X, A = np.vstack([X, Xg]), np.vstack([A, np.where(okg[:, None], Af, Ag)])
                    ok, crease = np.concatenate([ok, okg]), np.concatenate([crease, crg])
            Ae = Ae_save
        out.append(_Piece(X, A, closed, lab, ok, crease))
    return out


@dataclass(frozen=True)
class _Tracer:
    """The cloud and the settings of :func:`grow_pieces` (one object instead of a dozen arguments)."""

    P: np.ndarray
    N: np.ndarray
    tree: cKDTree
    spacing: float
    eps: float
    side_radius: float
    approach_radius: float
    min_crease_angle: float
    max_steps: int
    max_turn: float
    max_approach_turn: float
    max_join_angle: float


def grow_pieces(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    pieces: list[_Piece],
    *,
    spacing: float,
    eps: float,
    side_radius: float,
    approach_radius: float,
    min_crease_angle: float,
    max_length: float,
    max_turn: float = np.deg2rad(30.0),
    max_approach_turn: float = np.deg2rad(20.0),
    max_join_angle: float = np.deg2rad(45.0),
) -> list[_Piece]:
    """Extend every open piece at both ends by tracing its joint (seam tracking on the cloud), and join
    the pieces the traces run into.

    Where a shallow crease (e.g. the flanks of a pipe junction, ~145 deg included angle) gives too few
    eq. 16 edge points, a seam is found in pieces. From each open end, nodes are placed ``spacing``
    further along the end direction and snapped onto the two side planes (:func:`_refine_nodes`); a node
    is accepted while the fit is a concave crease of at least ``min_crease_angle`` with surface on both
    sides (:func:`_refine_on_sides`), the cloud continues around it (its neighbours within
    ``side_radius`` are not all behind it: the part or the scan ends there), the step turns by less
    than ``max_turn`` and the approach by less than ``max_approach_turn``, at most ``max_length`` (m)
    per end. A trace that comes within ``eps`` of another piece's end (approaches within
    ``max_join_angle``) joins that piece; one that reaches its own piece's other end closes it into a
    loop; one that meets any other node stops. Closed pieces are returned unchanged.
    """
    max_steps = int(max_length / spacing)
    if max_steps < 1:
        return pieces
    tr = _Tracer(
        P,
        N,
        tree,
        spacing,
        eps,
        side_radius,
        approach_radius,
        min_crease_angle,
        max_steps,
        max_turn,
        max_approach_turn,
        max_join_angle,
    )
    out = [_with_fit(p) for p in pieces]
    todo = [(i, e) for i, p in enumerate(out) if not p.closed for e in (0, 1)]
    while todo:
        i, e = todo.pop(0)
        j = _grow_end(tr, out, i, e)
        if j is not None:  # out[-1] is piece i (traced end last) + piece j: both new ends are traced again
            keep = [k for k in range(len(out) - 1) if k not in (i, j)]
            renumber = {k: n for n, k in enumerate(keep)}
            out = [out[k] for k in keep] + [out[-1]]
            todo = [(renumber[k], f) for k, f in todo if k in renumber] + [
                (len(out) - 1, 0),
                (len(out) - 1, 1),
            ]
    return out


def _with_fit(p: _Piece) -> _Piece:
    """``p`` with its ``ok`` / ``crease`` arrays filled in (all usable / 0 where not refined)."""
    ok = p.ok if p.ok is not None else np.ones(len(p.X), dtype=bool)
    crease = p.crease if p.crease is not None else np.zeros(len(p.X))
    return _Piece(p.X, p.A, p.closed, p.labels, ok, crease)


def _sub(p: _Piece, sl: slice, closed: bool | None = None) -> _Piece:
    """The nodes ``sl`` of ``p`` (reversed order with a negative step), optionally re-flagged closed."""
    return _Piece(p.X[sl], p.A[sl], p.closed if closed is None else closed, p.labels, p.ok[sl], p.crease[sl])


def _concat(a: _Piece, b: _Piece) -> _Piece:
    """The open run of ``a``'s nodes followed by ``b``'s."""
    return _Piece(
        np.vstack([a.X, b.X]),
        np.vstack([a.A, b.A]),
        False,
        a.labels + b.labels,
        np.concatenate([a.ok, b.ok]),
        np.concatenate([a.crease, b.crease]),
    )


def _blocking_nodes(out: list[_Piece], i: int, X: np.ndarray, end_len: float) -> tuple[np.ndarray, ...]:
    """Nodes a trace from the end of ``X`` (piece ``i``, traced end last) must stop at: every other
    piece's, and ``X``'s own beyond ``end_len`` of its end. Returns (owner, index, points)."""
    owner, index, nodes = [], [], []
    for j, p in enumerate(out):
        Xj = X if j == i else p.X
        sel = np.arange(len(Xj))
        if j == i:
            sel = sel[np.linalg.norm(Xj - Xj[-1], axis=1) >= end_len]
        owner.append(np.full(len(sel), j))
        index.append(sel)
        nodes.append(Xj[sel])
    return np.concatenate(owner), np.concatenate(index), np.vstack(nodes)


def _grow_end(tr: _Tracer, out: list[_Piece], i: int, e: int) -> int | None:
    """Trace end ``e`` (0 start, 1 end) of ``out[i]`` (:func:`grow_pieces`) and store the longer piece
    in ``out[i]`` (closed when the trace reached its own other end). When the trace ran into the end of
    piece j, the join (piece i, traced end last, then piece j) is appended to ``out`` and j returned."""
    piece = out[i] if e == 1 else _sub(out[i], slice(None, None, -1))
    end_len = 3.0 * tr.eps
    owner, index, nodes = _blocking_nodes(out, i, piece.X, end_len)
    grown, A, crease, hit = _trace_joint(tr, piece.X, piece.A, nodes)
    if len(grown):
        n = len(grown)
        piece = _concat(
            piece, _Piece(grown, A, False, np.zeros(6, dtype=np.int64), np.ones(n, dtype=bool), crease)
        )
    joined = None
    if hit >= 0:
        j, k = int(owner[hit]), int(index[hit])
        other = piece if j == i else out[j]
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(other.X, axis=0), axis=1))])
        d_end = _unit(piece.X[-1] - piece.X[-3])
        if j == i and s[k] <= end_len:  # reached its own other end: a loop, without overlap where it closes
            piece = _sub(piece, slice(_first_ahead(piece.X[: k + 1], piece.X[-1], d_end), None), closed=True)
        elif j != i and min(s[k], s[-1] - s[k]) <= end_len:
            tail = (
                other if s[k] <= s[-1] - s[k] else _sub(other, slice(None, None, -1))
            )  # end it ran into first
            a_end, a_tail = _unit(piece.A[-3:].mean(axis=0)), _unit(tail.A[:3].mean(axis=0))
            if float(a_end @ a_tail) >= np.cos(tr.max_join_angle):
                n_end = int(np.sum(np.linalg.norm(tail.X - tail.X[0], axis=1) <= end_len + tr.eps))
                start = _first_ahead(tail.X[:n_end], piece.X[-1], d_end)  # its nodes behind the trace: off
                joined = (j, _sub(tail, slice(start, None)))
    out[i] = piece if e == 1 else _sub(piece, slice(None, None, -1))
    if joined is None:
        return None
    out.append(_concat(piece, joined[1]))
    return joined[0]


def _first_ahead(X: np.ndarray, end: np.ndarray, d: np.ndarray) -> int:
    """Index of the first node of ``X`` lying ahead of ``end`` along ``d`` (len(X) when none does)."""
    ahead = np.flatnonzero((X - end) @ d > 0)
    return int(ahead[0]) if len(ahead) else len(X)


def _cloud_ends(tr: _Tracer, x: np.ndarray, d: np.ndarray) -> bool:
    """True where the cloud ends at ``x``: fewer than 6 points within ``tr.side_radius``, or they lie
    behind it along ``d`` on average (no surface ahead of the node)."""
    nb = tr.tree.query_ball_point(x, tr.side_radius)
    return len(nb) < 6 or float(np.mean((tr.P[nb] - x) @ d)) < -0.25 * tr.side_radius


def _crease_direction(tr: _Tracer, x: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Direction (sign of ``d``) of the intersection line of the two side planes fitted around ``x``
    within ``tr.side_radius``; ``d`` where they are nearly parallel."""
    _, valid, na, nb, in_a, Q = _sides_at(tr.P, tr.N, tr.tree, x[None], tr.side_radius, 256)
    na, _, nb, _, _, _, _ = _fit_two_planes(Q, valid, na, nb, in_a, behind_tol=BEHIND_TOL * tr.side_radius)
    u = np.cross(na[0], nb[0])
    if float(np.linalg.norm(u)) < np.sin(tr.min_crease_angle):
        return d
    u = _unit(u)
    return u if float(u @ d) >= 0 else -u


def _trace_joint(
    tr: _Tracer, X: np.ndarray, A: np.ndarray, block: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The nodes (n, 3), approaches (n, 3) and crease angles (n,) traced beyond the last node of ``X``
    (approaches ``A``; see :func:`grow_pieces`), and the index of the node of ``block`` the trace ran
    into (within ``tr.eps``; -1 when it stopped for another reason)."""
    chord = max(0.01, 3 * tr.spacing)
    d = _end_directions(X, tr.spacing, chord)[1]
    if float(np.linalg.norm(X[-1] - X[0])) < chord:  # a short piece: its chord is no direction
        d = _crease_direction(tr, X[-1], d)
    a = _unit(A[-5:].mean(axis=0))
    pos = X[-1]
    block_tree = cKDTree(block) if len(block) else None
    cos_turn, cos_app = np.cos(tr.max_turn), np.cos(tr.max_approach_turn)
    nodes, apps, creases, hit = [], [], [], -1
    for _ in range(tr.max_steps):
        if _cloud_ends(tr, pos + tr.spacing * d, d):  # the part or the scan ends ahead: no fit needed
            break
        Xn, An, ok, crease = _refine_nodes(
            tr.P,
            tr.N,
            tr.tree,
            (pos + tr.spacing * d)[None],
            tr.side_radius,
            tr.approach_radius,
            tr.min_crease_angle,
        )
        x, an = Xn[0], An[0]
        step = x - pos
        length = float(np.linalg.norm(step))
        if not ok[0] or length < 0.3 * tr.spacing or float(step @ d) < cos_turn * length or an @ a < cos_app:
            break
        if block_tree is not None:
            dist, k = block_tree.query(x)
            if dist < tr.eps:
                hit = int(k)
                break
        if _cloud_ends(tr, x, d):
            break
        nodes.append(x)
        apps.append(an)
        creases.append(float(crease[0]))
        d = _unit(d + step / length)
        a, pos = an, x
    if not nodes:
        return np.empty((0, 3)), np.empty((0, 3)), np.empty(0), hit
    return np.array(nodes), np.array(apps), np.array(creases), hit


def _smooth_positions(X: np.ndarray, window: int, closed: bool) -> np.ndarray:
    """Savitzky-Golay (quadratic) smoothing over ``window`` nodes: no shrinkage on curved seams."""
    n = len(X)
    w = min(int(window) | 1, n if closed else n - (1 - n % 2))
    if w < 5:
        return X
    if closed and w > n:
        w = n - (1 - n % 2)
    return savgol_filter(X, w, 2, axis=0, mode="wrap" if closed else "interp")


def _smooth_approach(
    A: np.ndarray, ok: np.ndarray, window: int, closed: bool, curved: bool = True
) -> np.ndarray:
    """Robust smoothing of the approach directions along a seam.

    A weighted moving average over ``window`` nodes (weight 0 where the side-plane fit failed) gives a
    reference; nodes further than 3x the median deviation (at least 2 deg) from it are dropped and the
    reference is taken again. On a ``curved`` seam the result is a local quadratic fit of the kept
    directions (a box average of a direction that turns along the seam is biased: by up to 2 deg on
    the Y-pipe's flanks); on a straight one, whose approach hardly turns, a quadratic Savitzky-Golay
    pass over the reference (the box average halves the noise a quadratic fit leaves: T-fillet 0.85
    vs 1.18 deg)."""
    if len(A) < 3:
        return _unit(A)
    mode = "wrap" if closed else "nearest"
    w = np.where(ok, 1.0, 1e-6)
    size = max(1, min(int(window), len(A)))
    for _ in range(2):
        num = uniform_filter1d(A * w[:, None], size=size, axis=0, mode=mode)
        den = uniform_filter1d(w, size=size, mode=mode)
        ref = _unit(num / np.maximum(den, 1e-12)[:, None])
        dev = np.arccos(np.clip(np.einsum("ij,ij->i", A, ref), -1.0, 1.0))
        lim = max(3.0 * float(np.median(dev[ok])) if ok.any() else 0.0, np.deg2rad(2.0))
        w = np.where(ok & (dev <= lim), 1.0, 1e-6)
    if not curved:
        return _unit(_smooth_positions(ref, window, closed))
    return _unit(_local_quadratic(A, w, window, closed))


def _local_quadratic(V: np.ndarray, w: np.ndarray, window: int, closed: bool) -> np.ndarray:
    """Weighted local quadratic regression of the rows of ``V`` (K, D) over ``window`` nodes (weights
    ``w``): a Savitzky-Golay filter that skips the down-weighted nodes. Open runs keep a full window at
    their ends (shifted inwards, as ``savgol_filter``'s ``interp`` mode)."""
    n = len(V)
    h = max(1, min(int(window), n) // 2)
    if not closed and n < 2 * h + 1:
        h = max(1, (n - 1) // 2)
    span = np.arange(-h, h + 1)
    if closed:
        idx = (np.arange(n)[:, None] + span[None, :]) % n
        s = np.broadcast_to(span.astype(float), idx.shape)
    else:
        lo = np.clip(np.arange(n) - h, 0, n - 2 * h - 1)
        idx = lo[:, None] + np.arange(2 * h + 1)[None, :]
        s = (idx - np.arange(n)[:, None]).astype(float)
    F = np.stack([np.ones_like(s), s, s * s], axis=-1)
    Fw = F * w[idx][..., None]
    M = np.matmul(Fw.transpose(0, 2, 1), F) + 1e-9 * np.eye(3)
    coef = np.linalg.solve(M, np.matmul(Fw.transpose(0, 2, 1), V[idx]))
    return coef[:, 0, :]


def _straight(X: np.ndarray, tol: float = 0.01) -> bool:
    """Whether the polyline ``X`` stays within ``tol`` x its length of its principal line."""
    C = X - X.mean(axis=0)
    u = np.linalg.svd(C, full_matrices=False)[2][0]
    off = np.linalg.norm(C - np.outer(C @ u, u), axis=1)
    return float(off.max()) <= tol * float(np.ptp(C @ u))


def _orthogonal_to_travel(X: np.ndarray, A: np.ndarray, closed: bool) -> np.ndarray:
    """The approach directions ``A`` without their component along the seam polyline ``X`` (central
    differences). Both side normals of a joint are perpendicular to its line, so their bisector is too;
    the fitted bisector is only perpendicular to the *fitted* crease line, whose direction is poorly
    determined where the side planes differ little or curve (the ~145 deg flanks and the acute toe of a
    pipe junction: 4-20 deg along the seam), while the smoothed polyline's is not. An open seam that
    stays within 1 % of its length of a straight line keeps its approach: its fitted crease direction is
    well determined, and the polyline's sub-millimetre steps (where pieces were joined) would tilt it by
    degrees (the demo job's V-groove: 0.67 -> 2.2 deg)."""
    if len(X) < 3 or (not closed and _straight(X)):
        return A
    T = (np.roll(X, -1, axis=0) - np.roll(X, 1, axis=0)) if closed else np.gradient(X, axis=0)
    T = _unit(T)
    return _unit(A - np.einsum("ij,ij->i", A, T)[:, None] * T)


def chain_seams(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    weld_idx: np.ndarray,
    weld_labels: np.ndarray,
    approach: np.ndarray,
    *,
    eps: float,
    spacing: float,
    side_radius: float,
    min_length: float,
    smooth_window: int,
    min_crease_angle: float,
    groove_max_angle: float = np.deg2rad(75.0),
    joints: tuple[str, ...] = ("concave", "groove"),
    max_approach_angle: float = np.deg2rad(60.0),
    min_fit_fraction: float = 0.6,
    refine: bool = True,
    max_gap: float = 0.03,
    max_gap_angle: float = np.deg2rad(20.0),
    smooth_length: float = 0.06,
    approach_radius: float = 0.0,
    max_grow: float = 0.3,
    grow_min_crease_angle: float = np.deg2rad(20.0),
    wall_radius: float = 0.0,
) -> list[SeamPolyline]:
    """Cluster the weldable points and turn the clusters into ordered, resampled polylines.

    Points are linked within ``eps`` when their approach directions differ by less than
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
    M = len(weld_idx)
    if M < 3:
        return []
    X = P[weld_idx]
    pairs = cKDTree(X).query_pairs(eps, output_type="ndarray")
    if len(pairs):
        agree = np.einsum("ij,ij->i", approach[pairs[:, 0]], approach[pairs[:, 1]])
        pairs = pairs[agree > np.cos(max_approach_angle)]
    i, j = pairs[:, 0], pairs[:, 1]
    w = np.linalg.norm(X[i] - X[j], axis=1) + 1e-12
    G = coo_matrix((w, (i, j)), shape=(M, M)).tocsr()
    n_comp, comp = connected_components(G, directed=False)
    G = G + G.T
    mst = minimum_spanning_tree(G)
    sizes = np.bincount(comp, minlength=n_comp)
    pieces = []
    big = np.flatnonzero(sizes >= 5)
    order = np.argsort(comp, kind="stable")
    members = np.split(order, np.cumsum(sizes)[:-1])
    groups = [members[c] for c in big[np.argsort(-sizes[big], kind="stable")]]
    raw = _cluster_pieces(X, approach, groups, G, mst, eps, spacing, weld_labels)
    raw = [p for p in raw if p is not None]
    if refine and raw:  # all pieces' nodes in one batch (one search, one set of plane fits)
        cuts = np.cumsum([len(p.X) for p in raw])[:-1]
        fits = _refine_nodes(
            P, N, tree, np.vstack([p.X for p in raw]), side_radius, approach_radius, min_crease_angle
        )
        per_piece = zip(*(np.split(a, cuts) for a in fits), strict=True)
    else:
        per_piece = [None] * len(raw)
    for piece, fit in zip(raw, per_piece, strict=True):
        if fit is not None:
            Xs, A_fit, ok, crease = fit
            if ok.mean() < min_fit_fraction:  # no two distinct side planes along most of it: not a joint
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
            piece = _Piece(Xs, As, piece.closed, piece.labels, ok, crease)
        pieces.append(piece)
    if max_grow > 0 and refine:
        pieces = grow_pieces(
            P,
            N,
            tree,
            pieces,
            spacing=spacing,
            eps=eps,
            side_radius=side_radius,
            approach_radius=approach_radius,
            min_crease_angle=min(min_crease_angle, grow_min_crease_angle),
            max_length=max_grow,
        )
    if max_gap > 0 and refine:
        pieces = bridge_pieces(
            P,
            N,
            tree,
            pieces,
            max_gap=max_gap,
            max_angle=max_gap_angle,
            spacing=spacing,
            side_radius=side_radius,
            min_crease_angle=min(min_crease_angle, grow_min_crease_angle),
            approach_radius=approach_radius,
        )
    window = max(int(smooth_window), int(round(smooth_length / spacing)) | 1)
    seams: list[SeamPolyline] = []
    for piece in sorted(pieces, key=lambda p: -len(p.X)):
        Xs, As, closed = piece.X, piece.A, piece.closed
        ok = piece.ok if piece.ok is not None else np.ones(len(Xs), dtype=bool)
        crease = piece.crease if piece.crease is not None else np.zeros(len(Xs))
        curved = closed or len(Xs) < 3 or not _straight(Xs)
        if refine and wall_radius > 0 and len(Xs) >= 3 and ok.any() and curved:
            Xw, Aw, ok_w = _curved_wall_nodes(P, N, tree, Xs, approach_radius, wall_radius, side_radius)
            use = ok & ok_w & (np.linalg.norm(Xw - Xs, axis=1) < side_radius / 6.0)
            Xs = np.where(use[:, None], Xw, Xs)
            As = np.where(use[:, None], Aw, As)
        # smoothing window: smooth_length, but at most 1/8 of the seam (a quadratic fit over more of a
        # small ring would shrink it)
        L = float(np.linalg.norm(np.diff(Xs, axis=0), axis=1).sum())
        w = max(int(smooth_window), min(window, int(L / (8.0 * spacing)) | 1))
        As = _smooth_approach(As, ok, w, closed, curved)
        Xr, Ar = _resample(Xs, As, spacing, closed)
        Xr = _smooth_positions(Xr, w, closed)
        Ar = _smooth_approach(Ar, np.ones(len(Ar), dtype=bool), w, closed, curved)
        if not closed:  # smoothing must not lengthen the seam, and the ends can still fold back: cut them
            end_len = max(0.01, 3 * spacing)
            d0, d1 = _end_directions(Xs, spacing, end_len)
            # only nodes near each end can overshoot it (a long seam that curves may pass behind the
            # plane through its far end)
            k_end = np.arange(len(Xr))
            near0 = k_end < max(3, int(round(end_len / spacing)))
            near1 = k_end >= len(Xr) - max(3, int(round(end_len / spacing)))
            inside = ~(near0 & (np.einsum("ij,j->i", Xr - Xs[0], d0) > 0)) & ~(
                near1 & (np.einsum("ij,j->i", Xr - Xs[-1], d1) > 0)
            )
            Xr, Ar = Xr[inside], Ar[inside]
            if len(Xr) < 3:
                continue
            sl = _trim_turning_ends(Xr)
            Xr, Ar = Xr[sl], Ar[sl]
        Xr, Ar = _resample(Xr, Ar, spacing, closed)  # smoothing moved the nodes: equal steps again
        # open ends again: a hook the resampling straightened into a fold, or an L (a trace that turned)
        for cut in () if closed else (_trim_turning_ends, _cut_end_corners):
            sl = cut(Xr)
            if sl != slice(0, len(Xr)):
                Xr, Ar = _resample(Xr[sl], Ar[sl], spacing, closed)
        ring = np.vstack([Xr, Xr[:1]]) if closed else Xr
        length = float(np.linalg.norm(np.diff(ring, axis=0), axis=1).sum())
        if length < min_length or len(Xr) < 2:
            continue
        Ar = _orthogonal_to_travel(Xr, Ar, closed)
        Xr, Ar = _orient(Xr, Ar, closed)
        if refine and ok.sum() >= 3:  # the included angle of the fitted side planes decides
            joint = "groove" if np.pi - np.median(crease[ok]) < groove_max_angle else "concave"
        else:
            joint = "groove" if piece.labels[GROOVE] > piece.labels[CONCAVE] else "concave"
        if joint not in joints:
            continue
        seams.append(SeamPolyline(len(seams), joint, Xr, Ar, bool(closed), length))
    return seams


# ----------------------------------------------------------------------------- public entry point


@dataclass
class EdgeScores:
    """Eqs. 11-17 on a cloud: ``intensity`` (N,) eq. 12, ``ratio`` (N,) eq. 16 (NaN where not computed,
    see :func:`edge_scores`), the radius ``r``, the KD-tree and the eq. 11 neighbourhood ``nb``."""

    intensity: np.ndarray
    ratio: np.ndarray
    radius: float
    tree: cKDTree
    nb: Neighbourhood


def edge_scores(
    points: np.ndarray,
    *,
    m: int = 12,
    radius: float | None = None,
    radius_factor: float = 3.0,
    k_max: int = 32,
    sigma: float | None = None,
    floor: float = 1.0,
    min_intensity: float = 0.0,
    neighbours: NeighbourTable | None = None,
) -> EdgeScores:
    """Eqs. 11-17 on ``points``.

    The edge test is ``ratio >= t`` *and* ``intensity >= min_intensity``, so the structure tensor and
    eq. 16 are evaluated only at the points that pass the intensity bound (NaN elsewhere in ``ratio``);
    the gradients (eq. 13) and ``Tr(H)`` (for the noise floor, a median over the whole cloud) of all
    points are still computed, so the ratio of every evaluated point is exactly that of the full
    computation (``min_intensity=0`` evaluates all points).

    ``neighbours``: a :class:`~weldcell.plugins.scan_plan.denoise.NeighbourTable` of these points (the
    one the denoising stage computed) replaces the KD-tree searches when it reaches far enough (its
    radius at least r); a table of other points or too short a reach is not used.
    """
    P = _as_points(points, m)
    tree = cKDTree(P)
    table = _usable_table(P, neighbours)
    if radius is None:
        if table is not None:
            d1 = table.dist[:, 1:].min(axis=1)
            d1 = d1[np.isfinite(d1)]
        else:
            d1 = tree.query(P, k=2, workers=-1)[0][:, 1]
        spacing = float(np.median(d1)) if len(d1) else 0.0
        if spacing <= 0:
            raise DataError("the cloud has duplicate points only", "pass a cloud of a real surface")
        radius = radius_factor * spacing
    nb = adaptive_neighbourhood(P, tree, float(radius), m, k_max, table)
    I = edge_intensity(P, nb)
    g = intensity_gradient(P, I, nb)
    w = tensor_weights(nb, sigma)
    eps = noise_floor(tensor_trace(g, nb, weights=w), floor)
    rows = np.flatnonzero(I >= min_intensity)
    ratio = np.full(len(P), np.nan)
    ratio[rows] = _floored_ratio(structure_tensor(g, nb, rows=rows, weights=w), eps)
    return EdgeScores(I, ratio, float(radius), tree, nb)


def _usable_table(P: np.ndarray, table: NeighbourTable | None) -> NeighbourTable | None:
    """``table`` when it belongs to ``P`` (same array, or equal points), else None."""
    if table is None:
        return None
    if not isinstance(table, NeighbourTable):
        raise DataError(
            f"neighbours must be a NeighbourTable, got {type(table).__name__}",
            "build it with weldcell.plugins.scan_plan.denoise.knn_table(points, k, radius)",
        )
    if table.points is P:
        return table
    if table.idx.shape[0] == len(P) and np.array_equal(table.points, P):
        return table
    return None


def extract_seams(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    *,
    m: int = 12,
    t: float = 40.0,
    sigma: float | None = None,
    radius: float | None = None,
    radius_factor: float = 3.0,
    k_max: int = 32,
    floor: float = 1.0,
    min_intensity: float = 0.15,
    up: tuple[float, float, float] = (0.0, 0.0, 1.0),
    joints: tuple[str, ...] = ("concave", "groove"),
    min_crease_angle: float = np.deg2rad(35.0),
    groove_max_angle: float = np.deg2rad(75.0),
    class_radius_factor: float = 2.0,
    cluster_eps: float | None = None,
    spacing: float | None = None,
    min_seam_length: float = 0.01,
    smooth_window: int = 5,
    refine: bool = True,
    fit_radius: float | None = None,
    max_gap: float = 0.03,
    max_grow: float = 0.3,
    smooth_length: float = 0.06,
    neighbours: NeighbourTable | None = None,
    viewpoints: np.ndarray | None = None,
    max_incidence: float = np.deg2rad(75.0),
    wall_radius: float | None = None,
) -> SeamExtraction:
    """Edge points (eqs. 11-17) and ordered weld seams of a cloud in metres.

    Args:
        points: (N, 3) cloud (ideally denoised and voxel down-sampled, spacing ~1-2 mm).
        normals: optional (N, 3) normals; only their orientation (sign) is used, to orient the PCA
            normals: pass them facing the sensor/outward. Without them the orientation heuristic of
            :func:`point_normals` (``up``) is used.
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
        neighbours: optional :class:`~weldcell.plugins.scan_plan.denoise.NeighbourTable` of ``points``
            (the denoising stage's shared search); replaces the KD-tree searches of eq. 11 and of the
            normals when it reaches at least r.
        viewpoints: optional (V, 3) camera positions of the scans (the job's ``meta["viewpoints"]``):
            a concave crease counts only when both its sides face a camera at less than
            ``max_incidence`` (rad) -- see :func:`classify_edges`.
        wall_radius: radius (m) of the quadric wall patches that place the nodes and approach of curved
            and closed seams (default 4 x ``fit_radius``, 32 mm; 0 keeps the side planes), see
            :mod:`~weldcell.plugins.scan_plan.wall_quadrics`.
    """
    if m < 3:
        raise DataError(f"m must be >= 3, got {m}", "use m of about 10-20 neighbours")
    if not np.isfinite(t) or t < 27.0:
        raise DataError(f"t must be >= 27 (the minimum of Tr^3/Det, eq. 16), got {t}", "use t of 30-100")
    for name in joints:
        if name not in WELDABLE:
            raise DataError(f"unknown joint class {name!r}", f"choose from {sorted(WELDABLE)}")
    _positive(radius, "radius")
    _positive(sigma, "sigma")
    _positive(spacing, "spacing")
    _positive(fit_radius, "fit_radius")
    if wall_radius is not None and (not np.isfinite(wall_radius) or wall_radius < 0):
        raise DataError(
            f"wall_radius must be >= 0 m, got {wall_radius}", "pass e.g. 0.024, 0 to keep the side planes"
        )
    if not np.isfinite(max_gap) or max_gap < 0:
        raise DataError(f"max_gap must be >= 0 m, got {max_gap}", "pass e.g. 0.03 (0 disables bridging)")
    if not np.isfinite(max_grow) or max_grow < 0:
        raise DataError(f"max_grow must be >= 0 m, got {max_grow}", "pass e.g. 0.3 (0 disables tracing)")
    _positive(smooth_length, "smooth_length")
    P = _as_points(points, m)
    es = edge_scores(
        P,
        m=m,
        radius=radius,
        radius_factor=radius_factor,
        k_max=k_max,
        sigma=sigma,
        floor=floor,
        min_intensity=min_intensity,
        neighbours=neighbours,
    )
    I, score, r, tree = es.intensity, es.ratio, es.radius, es.tree
    table = _usable_table(P, neighbours)
    with np.errstate(invalid="ignore"):
        edge = (score >= t) & (I >= min_intensity)
    oriented = None
    if normals is not None:
        oriented = np.asarray(normals, dtype=float)
        if oriented.shape != P.shape or not np.all(np.isfinite(oriented)):
            raise DataError(
                f"normals must be a finite {P.shape} array, got {oriented.shape}",
                "pass one normal per point or normals=None",
            )
    N = point_normals(P, tree, 10, oriented, np.asarray(up, dtype=float), table)
    labels = np.zeros(len(P), dtype=np.int8)
    cand = np.flatnonzero(edge)
    R = class_radius_factor * r
    seams: list[SeamPolyline] = []
    if len(cand):
        lab, appr = classify_edges(
            P,
            N,
            tree,
            cand,
            R,
            min_crease_angle=min_crease_angle,
            groove_max_angle=groove_max_angle,
            viewpoints=viewpoints,
            max_incidence=max_incidence,
        )
        labels[cand] = lab
        keep = np.isin(lab, [WELDABLE[j] for j in joints])
        approach_radius = fit_radius or max(R, 0.008)
        seams = chain_seams(
            P,
            N,
            tree,
            cand[keep],
            lab[keep],
            appr[keep],
            eps=cluster_eps or 2.0 * r,
            spacing=spacing or r,
            side_radius=max(R, 0.006),
            approach_radius=approach_radius,
            min_length=min_seam_length,
            smooth_window=smooth_window,
            min_crease_angle=min_crease_angle,
            groove_max_angle=groove_max_angle,
            joints=joints,
            refine=refine,
            max_gap=max_gap,
            max_grow=max_grow,
            smooth_length=smooth_length,
            wall_radius=4.0 * approach_radius if wall_radius is None else wall_radius,
        )
    params = dict(m=m, t=t, radius=r, sigma=sigma, floor=floor, min_intensity=min_intensity)
    return SeamExtraction(edge, score, I, labels, seams, r, params)
