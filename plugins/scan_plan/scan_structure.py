"""How a cloud was sampled, from the cloud alone: area scan, or line scan (slices), its spacings and noise.

A laser line profiler or a 2-D lidar swept by a robot records one *profile* per pose: every point of a
profile lies in the laser sheet, one plane, whatever the range noise (the noise is along the ray, in the
sheet). The cloud is a stack of planar *slices*: points close along a line (0.3-1 mm), lines several mm
apart. Every estimator built on k nearest neighbours then sees one slice: its plane is the laser sheet,
not the surface; its residual is the sheet's flatness (micrometres), not the surface noise (a millimetre);
its "coarse" spacing is the band's width. :func:`scan_structure` finds the slices and measures across them.

Method (no viewpoint, no orientation assumed; every threshold relative to the cloud's own scales):

1. *Sheet test.* For each of ``sample`` random points p, the plane of its :data:`SHEET_K` nearest points
   (normal ``s``, RMS thickness ``t``; where they are collinear, the line). Its neighbours' offsets
   ``h = (q - p) . s`` are read in growing reaches: the nearest :data:`REACH_K` points of nested random
   subsets of the cloud, each :data:`THIN` x smaller (the offsets of a subset's points are exact: a
   slice's points stay in its plane however few are kept). A point is *on a slice* when the nearest
   neighbour off its plane (``|h| > tau = 4 t``, at least :data:`FLOOR` x the spacing) lies at least
   :data:`GAP` x ``tau`` off it -- nothing between the sheet and the next one -- with the next sheets on
   both sides. On a smooth surface of any noise the offsets grow continuously (noise, curvature, edges):
   the nearest off-plane neighbour lies just beyond ``tau``. A step between parallel faces is one-sided.
2. *Decision.* The cloud is line-structured when at least :data:`LINE_SHARE` of the sampled points are
   on slices.
3. *Spacings.* ``sheet_gap``: median of the smallest ``|h|`` of the neighbouring slices (the distance
   between adjacent profiles' planes); ``along_spacing``: median distance to the nearest neighbour in the
   same sheet. On the surface, lines are ``line_spacing = sheet_gap / sin(angle(surface, sheet))`` apart,
   with the surface normal from a plane fit across the slices (step 4).
4. *Noise and normals across lines.* Each sampled point's plane is fitted to the points within
   ``1.5 sheet_gap`` (line scans: at least two sheets) or ``3 x spacing`` (area scans, the reach of
   :func:`~weldcell.plugins.scan_plan.cloud_numerics.noise_level` in the seam stage), taken from the
   subset level whose reach covers that radius; ``noise`` is the median of their residual RMS
   (unbiased: ``sqrt(SS / (k - 3))``).
5. *Reach.* ``span_radius = 1.25 x`` the upper quartile of the on-surface line spacing: a disc that holds
   the next line on each side for three quarters of the points, and ``span_neighbours`` the points such a
   disc holds in the full cloud (median). On an area scan the same rule with the nearest-neighbour
   distance.

Cost: one KD-tree (pass the caller's), a few small ones on subsets, ~``sample`` x 32 neighbours per level.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from weldcell.sdk.cloud import ScanStructure
from weldcell.sdk.errors import DataError

from .cloud_numerics import as_points, sym3_eigvals, sym3_eigvec

__all__ = ["ScanStructure", "scan_structure"]

#: points of the plane fitted at each sampled point to find its sheet (itself included): few, so that on a
#: profiler with 1 mm along a line and 5 mm between lines it stays in one line
SHEET_K = 7
#: neighbours read per reach level (each level a THIN x smaller random subset of the cloud)
REACH_K = 32
#: size ratio of consecutive subsets (reach grows ~sqrt(THIN) per level on a surface)
THIN = 8
#: the smallest subset searched (points)
MIN_LEVEL = 400
#: a point is on a slice when the nearest neighbour off its plane is at least this x tau off it. Measured
#: (benchmarks/scan_structure_eval.py): slices 20-inf (real lidar sheets ~75), smooth surfaces 1.0-1.6
GAP = 3.0
#: the in-sheet band tau is at least this x the median nearest-neighbour spacing (float precision)
FLOOR = 1e-3
#: the cloud is line-structured when at least this share of the sampled points lie on slices. Measured
#: (benchmarks/scan_structure_eval.py, docs/methods/seams-and-paths.md): generated RGB-D and structured-light
#: scans 0.00, a real RealSense frame 0.00; generated profiler sweeps 0.09-0.95 (two crossing sweeps: the
#: least), the real lidar sweeps 0.09-0.60. Between 0.01 and 0.09 (their geometric mean ~0.03), with margin
LINE_SHARE = 0.04
#: a slice's neighbouring sheets are at least this x farther than its nearest point in its own sheet: the
#: sheets of a line scan are farther apart than the points along a line (measured: 4-7 x), the iso-depth
#: terraces of a quantised depth frame (a real RealSense frame: steps of 0.5-0.9 mm) are closer (0.3 x)
ANISOTROPY = 2.0
#: a slice's sheet is tilted at most this much from the surface (|sin| floor of line_spacing's formula)
MIN_SIN = 0.2


@dataclass
class _Levels:
    """Nested random subsets of the cloud (level 0 = all of it) and their KD-trees (built when first used)."""

    P: np.ndarray
    order: np.ndarray
    sizes: list[int]
    trees: dict

    @classmethod
    def of(cls, P: np.ndarray, tree: cKDTree, rng: np.random.Generator) -> _Levels:
        sizes = [len(P)]
        while sizes[-1] // THIN >= MIN_LEVEL:
            sizes.append(sizes[-1] // THIN)
        return cls(P, rng.permutation(len(P)), sizes, {0: tree})

    def query(self, X: np.ndarray, level: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Distances and points (n, k') of the ``k`` nearest of ``X`` in subset ``level``."""
        if level not in self.trees:
            sub = self.P[self.order[: self.sizes[level]]]
            self.trees[level] = cKDTree(sub, balanced_tree=False, compact_nodes=False)
        tree = self.trees[level]
        k = int(min(k, tree.n))
        d, i = tree.query(X, k=k, workers=-1)
        d, i = d.reshape(len(X), k), i.reshape(len(X), k)
        return d, tree.data[i]


def scan_structure(
    points: np.ndarray, tree: cKDTree | None = None, sample: int = 1500, seed: int = 0
) -> ScanStructure:
    """The sampling structure of an unorganised cloud (module docstring): line scan or area scan, spacings
    along and across lines, surface noise and the neighbourhood reach that spans two lines.

    ``tree``: a KD-tree of ``points`` to reuse; ``sample``: points the medians are taken over (seeded).
    """
    P = as_points(points, "cloud", min_points=SHEET_K + 4)
    if not sample >= 50:
        raise DataError(f"sample must be at least 50 points, got {sample}", "pass sample=1500 (the default)")
    tree = tree if tree is not None else cKDTree(P, balanced_tree=False, compact_nodes=False)
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(P), int(sample), replace=False) if len(P) > sample else np.arange(len(P))
    X = P[rows]
    d64, i64 = tree.query(X, k=min(2 * REACH_K, len(P)), workers=-1)  # level 0, also for step 4
    d0, i0 = d64[:, :REACH_K], i64[:, :REACH_K]
    nn = _first_positive(d0)
    if not len(nn):
        raise DataError("the cloud's points are all duplicates of each other", "pass a scan of a surface")
    spacing = float(np.median(nn))
    levels = _Levels.of(P, tree, rng)
    s, t, line = _sheets(P[i0[:, :SHEET_K]] - X[:, None, :])
    tau = 4.0 * t + FLOOR * spacing
    fit_reach = np.maximum(d0[:, min(SHEET_K, d0.shape[1]) - 1], FLOOR * spacing)
    on, gap, along = _slices(X, s, (tau, fit_reach), line, d0, P[i0], levels)
    with np.errstate(invalid="ignore"):
        on &= gap >= ANISOTROPY * along  # sheets closer than the points in them: depth quantisation terraces
    share = float(on.mean())
    structured = share >= LINE_SHARE and np.count_nonzero(on) >= 10
    fit = _surface(X[on], levels, 1.5 * float(np.median(gap[on]))) if structured else None
    structured = fit is not None
    if structured:
        g = float(np.median(gap[on]))
        n, noise, count, level = fit
        sin = np.sqrt(np.maximum(1.0 - np.einsum("ij,ij->i", n, s[on]) ** 2, MIN_SIN**2))
        L = gap[on] / sin
        line_spacing, hi = float(np.median(L)), float(np.quantile(L, 0.75))
        along_spacing, thickness = float(np.median(along[on])), float(np.median(t[on]))
        reach = 1.5 * g
    else:
        fit = _surface(X, levels, 3.0 * spacing, first=(d64, P[i64]))
        if fit is None:
            raise DataError(
                "no neighbourhood of the cloud holds 6 points within 3 x its point spacing",
                "pass a scan of a surface (not isolated points or a single line)",
            )
        n, noise, count, level = fit
        g = line_spacing = along_spacing = spacing
        hi, thickness, reach = float(np.quantile(nn, 0.75)), 0.0, 3.0 * spacing
    span = 1.25 * hi
    density = np.median(count) * (len(P) / levels.sizes[level]) / (np.pi * reach**2)
    return ScanStructure(
        line_structured=bool(structured),
        line_share=share,
        spacing=spacing,
        mean_spacing=float(np.mean(nn)),
        along_spacing=along_spacing,
        sheet_gap=g,
        line_spacing=line_spacing,
        line_spacing_hi=hi,
        sheet_thickness=thickness,
        noise=float(np.median(noise)),
        span_radius=span,
        span_neighbours=int(np.ceil(density * np.pi * span**2)),
        sample=len(rows),
    )


def _first_positive(d: np.ndarray) -> np.ndarray:
    """Per row, the first positive distance (duplicates of a point are not its neighbours)."""
    pos = d > 0
    j = np.argmax(pos, axis=1)
    out = d[np.arange(len(d)), j]
    return out[pos.any(axis=1)]


def _sheets(D: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plane of each row's offsets ``D`` (n, k, 3): unit normal (n, 3), unbiased RMS thickness (n,), and
    whether the points are collinear (then the normal is the line's direction, see :func:`_offsets`)."""
    k = D.shape[1]
    Dc = D - D.mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", Dc, Dc) / k
    lam = np.maximum(sym3_eigvals(C), 0.0)
    line = lam[:, 1] <= 1e-6 * lam[:, 2]  # a noise-free profile on a flat face: one line, no sheet
    s = sym3_eigvec(C, np.where(line, lam[:, 2], lam[:, 0]))
    t = np.sqrt(np.where(line, lam[:, 1], lam[:, 0]) * k / (k - 3))
    return s, t, line


def _offsets(Q: np.ndarray, X: np.ndarray, s: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Signed offsets (n, k) of the points ``Q`` (n, k, 3) from the sheet through ``X`` of normal ``s``; for
    collinear rows, the distance from the line through ``X`` along ``s`` (unsigned)."""
    D = Q - X[:, None, :]
    h = np.einsum("nkj,nj->nk", D, s)
    if line.any():
        perp = np.sqrt(np.maximum(np.einsum("nkj,nkj->nk", D[line], D[line]) - h[line] ** 2, 0.0))
        h[line] = perp
    return h


def _slices(X, s, tau, line, d0, Q0, levels: _Levels):
    """``tau``: (in-sheet band at the fit's reach (n,), that reach (n,)). Per sampled point: on a slice
    (bool), the distance to the neighbouring sheets (m, NaN when not on a
    slice) and to its nearest neighbour in its own sheet, reading growing reaches until the nearest
    neighbour off the sheet is found (module docstring, step 1)."""
    tau0, fit_reach = tau
    n = len(X)
    on = np.zeros(n, dtype=bool)
    gap = np.full(n, np.nan)
    h0 = _offsets(Q0, X, s, line)
    inside = np.where((np.abs(h0) <= _band(tau0, fit_reach, d0)) & (d0 > 0), d0, np.inf)
    along = inside.min(axis=1)
    todo = np.arange(n)
    for level in range(len(levels.sizes)):
        if not len(todo):
            break
        if level == 0:
            d, h = d0[todo], h0[todo]
        else:
            d, Q = levels.query(X[todo], level, REACH_K)
            h = _offsets(Q, X[todo], s[todo], line[todo])
        a = np.abs(h)
        band = _band(tau0[todo], fit_reach[todo], d)
        off = a > band
        found = off.any(axis=1)
        j = np.argmin(np.where(off, d, np.inf), axis=1)
        far = GAP * band
        clear = found & (a >= far)[np.arange(len(todo)), j]
        # both neighbouring sheets (collinear rows: offsets are unsigned, one side suffices), nothing between
        near = d <= 2.5 * d[np.arange(len(todo)), j][:, None]
        mid = (off & ~(a >= far) & near).any(axis=1)
        pos = ((h >= far) & near).any(axis=1)
        neg = ((h <= -far) & near).any(axis=1) | line[todo]
        ok = clear & ~mid & pos & neg
        rows = todo[ok]
        on[rows] = True
        gap[rows] = np.where(off & near, a, np.inf)[ok].min(axis=1)
        todo = todo[~found | (clear & ~mid & ~(pos & neg))]  # no decision yet: reach further
    return on, gap, along


def _band(tau: np.ndarray, fit_reach: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The in-sheet band (n, k) at neighbour distances ``d``: ``tau`` within the sheet fit's reach, growing
    linearly beyond it (the fitted plane's tilt error, ~thickness / reach, extrapolated)."""
    return tau[:, None] * np.maximum(1.0, d / fit_reach[:, None])


def _surface(X: np.ndarray, levels: _Levels, radius: float, first: tuple | None = None):
    """Plane fits to the points within ``radius`` of each of ``X``, from the finest subset whose
    :data:`REACH_K` nearest reach ``radius`` (median): normals (n, 3), unbiased residual RMS, the points
    within ``radius`` (of the rows with at least 6) and the level used; None when no row has 6.
    ``first``: the 2 x :data:`REACH_K` nearest of ``X`` in the whole cloud (distances, points)."""
    if first is not None and np.median(first[0][:, -1]) >= radius:
        (d, Q), level = first, 0  # the caller's level-0 search of these points reaches far enough
    else:
        level = 0
        for lv in range(len(levels.sizes)):
            level = lv
            d, Q = levels.query(X[: min(len(X), 200)], lv, 2 * REACH_K)
            if np.median(d[:, -1]) >= radius:
                break
        d, Q = levels.query(X, level, 2 * REACH_K)
    w = (d <= radius).astype(float)
    cnt = w.sum(axis=1)
    ok = cnt >= 6
    w, Q, d, cnt = w[ok], Q[ok], d[ok], cnt[ok]
    if not len(cnt):
        return None
    mean = np.einsum("nk,nkj->nj", w, Q) / cnt[:, None]
    D = (Q - mean[:, None, :]) * np.sqrt(w)[:, :, None]
    C = np.einsum("nki,nkj->nij", D, D)
    lam = np.maximum(sym3_eigvals(C), 0.0)
    normal = sym3_eigvec(C, lam[:, 0])
    noise = np.sqrt(lam[:, 0] / (cnt - 3.0))
    full = np.zeros((len(X), 3))
    full[ok] = normal
    return _fill(full, ok), noise, cnt, level


def _fill(normals: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Rows without a fit get the z axis (they are few; only their sines are used, clipped)."""
    out = normals.copy()
    out[~ok] = (0.0, 0.0, 1.0)
    return out
