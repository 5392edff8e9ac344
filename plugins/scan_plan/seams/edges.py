"""Eqs. 11-17 of paper 000: adaptive neighbourhood, edge intensity, its 3-D gradient, the structure
tensor with the Gaussian of eq. 17, and the eigenvalue-free edge test ``Tr(H)^3 / Det(H) >= t``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from weldcell.sdk.arrays import row_sums
from weldcell.sdk.errors import DataError

from ..cloud_numerics import (
    NeighbourTable,
    knn_table,
    offsets,
)
from .model import _as_points

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


@dataclass
class EdgeScores:
    """Eqs. 11-17 on a cloud: ``intensity`` (N,) eq. 12, ``ratio`` (N,) eq. 16 (NaN where not computed,
    see :func:`edge_scores`), the radius ``r``, the KD-tree and the eq. 11 neighbourhood ``nb``."""

    intensity: np.ndarray
    ratio: np.ndarray
    radius: float
    tree: cKDTree
    nb: Neighbourhood


def edge_scores(  # 11 params by design: the terms of eqs. 11-17 (m, r, sigma, floor, I_min) + a reused search
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
    min_radius: float = 0.0,
    tree: cKDTree | None = None,
) -> EdgeScores:
    """Eqs. 11-17 on ``points``.

    The edge test is ``ratio >= t`` *and* ``intensity >= min_intensity``, so the structure tensor and
    eq. 16 are evaluated only at the points that pass the intensity bound (NaN elsewhere in ``ratio``);
    the gradients (eq. 13) and ``Tr(H)`` (for the noise floor, a median over the whole cloud) of all
    points are still computed, so the ratio of every evaluated point is exactly that of the full
    computation (``min_intensity=0`` evaluates all points).

    ``neighbours``: a :class:`~weldcell.plugins.scan_plan.cloud_numerics.NeighbourTable` of these points (the
    one the denoising stage computed) replaces the KD-tree searches when it reaches far enough (its
    radius at least r); a table of other points or too short a reach is not used.

    ``min_radius`` (m): r is at least this (an anisotropic scan's coarser spacing, see
    :func:`~.pipeline.extract_seams`); ``tree``: a KD-tree of ``points`` to reuse.
    """
    P = _as_points(points, m)
    tree = tree if tree is not None else cKDTree(P)
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
        radius = max(radius_factor * spacing, min_radius)
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
            "build it with weldcell.plugins.scan_plan.cloud_numerics.knn_table(points, k, radius)",
        )
    if table.points is P:
        return table
    if table.idx.shape[0] == len(P) and np.array_equal(table.points, P):
        return table
    return None
