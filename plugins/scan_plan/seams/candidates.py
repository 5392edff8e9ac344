"""Edge points -> weld-seam candidates: oriented normals, the two sides of each edge point and its
joint class (concave / groove / convex / boundary / weak)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from ..cloud_numerics import (
    NeighbourTable,
    masked_covariance,
    offsets,
    smallest_eigvec,
)
from .model import BOUNDARY, CONCAVE, CONVEX, GROOVE, MIN_INCLUDED_ANGLE, WEAK, _unit
from .sides import _dot3, _fit_two_planes, _sides_at, _wsum3

# ----------------------------------------------------------------------------- normals and classes


def point_normals(
    P: np.ndarray,
    tree: cKDTree,
    k: int = 10,
    oriented: np.ndarray | None = None,
    up: np.ndarray | None = None,
    table: NeighbourTable | None = None,
    idx: np.ndarray | None = None,
) -> np.ndarray:
    """Unit PCA normals from the ``k`` nearest neighbours (the point itself included), oriented.

    ``table`` (a :class:`NeighbourTable` of ``P``) replaces the KD-tree query where its rows hold at
    least ``k - 1`` neighbours (the nearest ones are picked from the row); ``idx`` (N, k), the k nearest
    of each point (the point first), replaces both.

    Orientation: along ``oriented`` (given normals, e.g. facing the sensor) when given; else, with
    ``up``, the former weld-cell heuristic: towards ``up`` where the surface is not steep, and for steep
    (wall) normals away from the axis along ``up`` through the cloud centroid; with neither, the PCA
    normals' signs are arbitrary (:func:`~.orientation.scan_side_normals` orients them).
    """
    k = int(min(k, len(P)))
    if idx is not None:
        pass
    elif table is not None and table.k >= k - 1:
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
    elif up is None:
        return n
    else:
        u = _unit(np.asarray(up, dtype=float))
        out = P - P.mean(axis=0)
        out = out - np.outer(out @ u, u)
        steep = np.abs(n @ u) < 0.3
        ref = np.where(steep[:, None], out, u[None, :])
    flip = np.einsum("ij,ij->i", n, ref) < 0
    n[flip] *= -1.0
    return n


@dataclass(frozen=True)
class Classifying:
    """Settings of :func:`classify_edges` (angles in rad)."""

    k: int = 32  # at most this many neighbours per candidate
    min_crease_angle: float = np.deg2rad(35.0)  # sides differing less are no crease
    groove_max_angle: float = np.deg2rad(75.0)  # included angles below this are grooves
    boundary_shift: float = 0.25  # centroid shift (x radius) of a one-sided neighbourhood
    min_side_fraction: float = 0.2  # share of the neighbours each side of a concave crease holds
    max_incidence: float = np.deg2rad(75.0)  # each side faces some camera within this
    min_included_angle: float = MIN_INCLUDED_ANGLE  # narrower "creases" are folded surfaces


def classify_edges(
    P: np.ndarray,
    N: np.ndarray,
    tree: cKDTree,
    cand: np.ndarray,
    radius: float,
    settings: Classifying | None = None,
    *,
    viewpoints: np.ndarray | None = None,
    **overrides: float,
):
    """Class of each candidate edge point (indices ``cand``) from its neighbourhood within ``radius``.

    ``settings`` is a :class:`Classifying`; keyword ``overrides`` replace its fields (e.g.
    ``min_crease_angle=0.6``).

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
    c = replace(settings if settings is not None else Classifying(), **overrides)
    min_crease_angle, groove_max_angle = c.min_crease_angle, c.groove_max_angle
    X = P[cand]
    idx, valid, na, nbv, in_a, Q = _sides_at(P, N, tree, X, radius, c.k)
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
    labels[flat & (shift > c.boundary_shift)] = BOUNDARY
    labels[~flat & (front <= 0)] = CONVEX
    concave = ~flat & (front > 0)
    # a concave crease needs real surface on both sides: a scan border that curls (grazing views, noise)
    # has a narrow, sparse "second side" -> boundary
    na_cnt, nb_cnt = on_a.sum(1), on_b.sum(1)
    one_sided = np.minimum(na_cnt, nb_cnt) < c.min_side_fraction * np.maximum(na_cnt + nb_cnt, 1)
    if viewpoints is not None and len(viewpoints):
        one_sided |= ~_both_sides_seen(X, na, nbv, viewpoints, c.max_incidence)
    one_sided |= np.pi - crease < c.min_included_angle  # folded onto itself: no torch fits in
    labels[concave & one_sided] = BOUNDARY
    concave &= ~one_sided
    labels[concave] = np.where(np.pi - crease[concave] < groove_max_angle, GROOVE, CONCAVE)
    return labels, -bis


def _both_sides_seen(
    X: np.ndarray, na: np.ndarray, nb: np.ndarray, viewpoints: np.ndarray, max_incidence: float
) -> np.ndarray:
    """Whether both sides (normals ``na``, ``nb``) of each point ``X`` were seen by some camera at
    ``viewpoints`` at less than ``max_incidence``: a side that faces away from every camera, or is seen
    only at grazing incidence, is not measured surface."""
    V = np.asarray(viewpoints, dtype=float).reshape(-1, 3)
    view = V[None, :, :] - X[:, None, :]
    view /= np.maximum(np.linalg.norm(view, axis=2, keepdims=True), 1e-12)
    cos_min = np.cos(max_incidence)
    seen_a = (np.einsum("bvj,bj->bv", view, na) >= cos_min).any(axis=1)
    seen_b = (np.einsum("bvj,bj->bv", view, nb) >= cos_min).any(axis=1)
    return seen_a & seen_b
