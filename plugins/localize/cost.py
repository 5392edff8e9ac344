"""The fit error of eq. (3) (paper 002, §IV) and its fast look-up.

Edge points are moved into the template's planned frame by the inverse pose, so the segments stay fixed;
the distance of a point to the nearest template segment is computed for all points and all segments at
once (numpy broadcasting, no Python loop). :class:`DistanceField` samples the same distance on a grid
(``scipy.ndimage.distance_transform_edt`` of the rasterised outlines) for the global search.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .pose import inverse_xy
from .template import Template


@dataclass
class Segments:
    """Template segments in the planned frame: ``a`` (S, 2), ``d`` = b - a, ``len2`` = |d|^2, ``owner``."""

    a: np.ndarray
    d: np.ndarray
    len2: np.ndarray
    owner: np.ndarray
    center: np.ndarray

    @property
    def array(self) -> np.ndarray:
        """(S, 2, 2) endpoints."""
        return np.stack([self.a, self.a + self.d], axis=1)

    @classmethod
    def of(cls, tpl: Template) -> Segments:
        segs, owner = tpl.segments()
        a, d = segs[:, 0], segs[:, 1] - segs[:, 0]
        return cls(a, d, np.maximum((d * d).sum(axis=1), 1e-18), owner, tpl.centroid)

    @classmethod
    def from_array(cls, segments: np.ndarray, center, owner=None) -> Segments:
        a, d = segments[:, 0], segments[:, 1] - segments[:, 0]
        own = np.zeros(len(a), int) if owner is None else np.asarray(owner)
        return cls(a, d, np.maximum((d * d).sum(axis=1), 1e-18), own, np.asarray(center, float))

    def subset(self, keep: np.ndarray) -> Segments:
        return Segments(self.a[keep], self.d[keep], self.len2[keep], self.owner[keep], self.center)


def nearest(q: np.ndarray, segs: Segments) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For points ``q`` (N, 2) in the planned frame: distance to the nearest segment (N,), its index (N,),
    and the closest point on it (N, 2)."""
    rel = q[:, None, :] - segs.a[None, :, :]
    t = np.clip((rel * segs.d[None]).sum(axis=2) / segs.len2[None], 0.0, 1.0)
    diff = rel - t[:, :, None] * segs.d[None]
    d2 = (diff * diff).sum(axis=2)
    j = d2.argmin(axis=1)
    rows = np.arange(len(q))
    closest = segs.a[j] + t[rows, j, None] * segs.d[j]
    return np.sqrt(d2[rows, j]), j, closest


def distances(pose, xy: np.ndarray, segs: Segments, fld: DistanceField | None = None) -> np.ndarray:
    """Distance of each edge point (found frame) to the nearest segment of the template moved by pose
    (all points x all segments; with ``fld``, the O(N) Voronoi-label evaluation of :func:`nearest_fast`)."""
    if fld is not None:
        return _fast_distances(pose, xy, segs, fld)
    q = inverse_xy(pose, segs.center, xy)
    rel = q[:, None, :] - segs.a[None, :, :]
    t = np.clip((rel * segs.d[None]).sum(axis=2) / segs.len2[None], 0.0, 1.0)
    diff = rel - t[:, :, None] * segs.d[None]
    return np.sqrt((diff * diff).sum(axis=2).min(axis=1))


def fit_error(pose, xy: np.ndarray, segs: Segments) -> float:
    """Eq. (3): the sum over edge points of the distance to the nearest template segment (m)."""
    return float(distances(pose, xy, segs).sum())


@dataclass
class DistanceField:
    """Distance (m) to the nearest template segment on a grid of ``res`` covering the template + ``margin``,
    truncated at ``cap`` (for the global search), and the index of that nearest segment per cell (``label``,
    a Voronoi map from the same transform) so that the exact distance of a point is one segment away."""

    field: np.ndarray
    label: np.ndarray
    origin: np.ndarray
    res: float
    cap: float

    @classmethod
    def of(cls, segments: np.ndarray, res: float, margin: float, cap: float) -> DistanceField:
        """From segments (S, 2, 2) in the planned frame."""
        from scipy.ndimage import distance_transform_edt

        pts = segments.reshape(-1, 2)
        lo = pts.min(axis=0) - margin
        shape = np.ceil((pts.max(axis=0) + margin - lo) / res).astype(int) + 1
        ids = np.full(shape[::-1], -1, dtype=np.int32)  # rows = y, cols = x
        for k, (a, b) in enumerate(segments):
            n = int(np.ceil(np.linalg.norm(b - a) / (res * 0.5))) + 1
            t = np.linspace(0.0, 1.0, n)[:, None]
            ij = np.round((a + t * (b - a) - lo) / res).astype(int)
            ids[ij[:, 1], ij[:, 0]] = k
        f, ind = distance_transform_edt(ids < 0, return_indices=True)
        label = ids[ind[0], ind[1]]
        return cls(np.minimum(f * res, cap).astype(np.float32), label.astype(np.int32), lo, res, cap)

    def cells(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat cell index of planned-frame points and whether they fall inside the grid."""
        h, w = self.field.shape
        ij = np.round((q - self.origin) / self.res).astype(np.int64)
        inside = (ij[..., 0] >= 0) & (ij[..., 0] < w) & (ij[..., 1] >= 0) & (ij[..., 1] < h)
        return np.clip(ij[..., 1], 0, h - 1) * w + np.clip(ij[..., 0], 0, w - 1), inside

    def lookup_flat(self, q: np.ndarray) -> np.ndarray:
        return self.cells(q)[0]

    def bilinear(self, q: np.ndarray) -> np.ndarray:
        h, w = self.field.shape
        g = (q - self.origin) / self.res
        x0 = np.clip(np.floor(g[:, 0]).astype(np.int64), 0, w - 2)
        y0 = np.clip(np.floor(g[:, 1]).astype(np.int64), 0, h - 2)
        fx, fy = np.clip(g[:, 0] - x0, 0, 1), np.clip(g[:, 1] - y0, 0, 1)
        f = self.field
        return (
            f[y0, x0] * (1 - fx) * (1 - fy)
            + f[y0, x0 + 1] * fx * (1 - fy)
            + f[y0 + 1, x0] * (1 - fx) * fy
            + f[y0 + 1, x0 + 1] * fx * fy
        )


def nearest_fast(q: np.ndarray, segs: Segments, fld: DistanceField | None):
    """:func:`nearest` in O(N): the segment is the cell's Voronoi label, the distance to it exact. Points
    outside the grid get the full search. Near a medial axis the label may be the runner-up segment, whose
    distance differs by less than a cell."""
    if fld is None:
        return nearest(q, segs)
    flat, inside = fld.cells(q)
    j = fld.label.ravel()[flat].astype(np.int64)
    rel = q - segs.a[j]
    t = np.clip((rel * segs.d[j]).sum(axis=1) / segs.len2[j], 0.0, 1.0)
    cp = segs.a[j] + t[:, None] * segs.d[j]
    d = np.linalg.norm(q - cp, axis=1)
    if not inside.all():
        out = ~inside
        d[out], j[out], cp[out] = nearest(q[out], segs)
    return d, j, cp


def _fast_distances(pose, xy: np.ndarray, segs: Segments, fld: DistanceField) -> np.ndarray:
    """:func:`distances` through the Voronoi labels, written for the optimiser's inner loop."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    cx, cy = segs.center
    px, py = xy[:, 0] - (cx + pose[0]), xy[:, 1] - (cy + pose[1])
    qx, qy = c * px + s * py + cx, c * py - s * px + cy
    h, w = fld.label.shape
    ix = np.rint((qx - fld.origin[0]) / fld.res).astype(np.int64)
    iy = np.rint((qy - fld.origin[1]) / fld.res).astype(np.int64)
    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    if not inside.all():
        return nearest_fast(np.column_stack([qx, qy]), segs, fld)[0]
    j = fld.label[iy, ix]
    ax, ay, dx, dy = segs.a[j, 0], segs.a[j, 1], segs.d[j, 0], segs.d[j, 1]
    rx, ry = qx - ax, qy - ay
    t = np.clip((rx * dx + ry * dy) / segs.len2[j], 0.0, 1.0)
    ex, ey = rx - t * dx, ry - t * dy
    return np.sqrt(ex * ex + ey * ey)


def _clip01(t: np.ndarray) -> None:
    """Clip to [0, 1] in place (two ufunc calls: np.clip's Python wrapper costs more than the work)."""
    np.maximum(t, 0.0, out=t)
    np.minimum(t, 1.0, out=t)


class Eq3:
    """Eq. (3) at a pose, for one set of edge points, written for the optimiser's inner loop.

    Points are complex numbers in grid cells (``z = (p - c) / res``); the inverse pose is one complex
    multiply, ``q = (z - t) e^{-i theta} + c``. With ``fld``, the nearest segment of each point is its cell's
    Voronoi label and the distance to that segment is exact (O(N), about 20 numpy operations per call;
    a point off the grid falls back to the full search); with ``exact=True`` (or no field) every point is
    measured against every segment, the paper's eq. (3) as written. Returns the sum in metres, the same
    value as ``distances(pose, xy, segs, fld).sum()``."""

    def __init__(self, xy: np.ndarray, segs: Segments, fld: DistanceField | None, exact: bool = False):
        self.xy, self.segs, self.fld = np.asarray(xy, float), segs, fld
        self.exact = exact or fld is None
        self.res = res = fld.res if fld is not None else 1e-3
        o = fld.origin if fld is not None else np.zeros(2)
        half = 0.5 + 0.5j  # cell centres: floor(g + 0.5) by truncation of non-negative g
        cx, cy = segs.center
        self.z = ((self.xy[:, 0] - cx) + 1j * (self.xy[:, 1] - cy)) / res
        self.c0 = complex(cx - o[0], cy - o[1]) / res + half
        self.a = ((segs.a[:, 0] - o[0]) + 1j * (segs.a[:, 1] - o[1])) / res + half
        self.d = (segs.d[:, 0] + 1j * segs.d[:, 1]) / res
        self.dc = np.conj(self.d)
        self.il = res * res / segs.len2
        if fld is not None:
            self.h, self.w = fld.label.shape
            self.label = np.ascontiguousarray(fld.label.ravel().astype(np.intp))

    def __call__(self, pose) -> float:
        e = complex(math.cos(pose[2]), -math.sin(pose[2]))
        q = self.z * e + (self.c0 - complex(pose[0], pose[1]) / self.res * e)
        if self.exact:
            return self._all_pairs(q)
        qr, qi = q.real, q.imag
        if q.view(np.float64).min() < 0 or qr.max() >= self.w or qi.max() >= self.h:
            return self._all_pairs(q)
        j = self.label[qi.astype(np.intp) * self.w + qr.astype(np.intp)]
        rel = q - self.a[j]
        t = (rel * self.dc[j]).real * self.il[j]
        _clip01(t)
        rel -= t * self.d[j]
        return float(np.abs(rel).sum()) * self.res

    def _all_pairs(self, q: np.ndarray) -> float:
        rel = q[:, None] - self.a[None]
        t = (rel * self.dc[None]).real * self.il[None]
        _clip01(t)
        rel -= t * self.d[None]
        return float(np.abs(rel).min(axis=1).sum()) * self.res


class Eq3Near:
    """The exact eq. (3) (every point against every segment, as :class:`Eq3` with ``exact=True``) near a
    pose ``pose0``, evaluated on each point's candidate segments only.

    A point's candidates are the segments within ``2 * margin`` of its nearest one at ``pose0``. Between two
    poses every point moves (relative to the template) by at most ``m = |t - t0| + |theta - theta0| * r``
    (``r`` the points' largest distance from the pivot), so each distance changes by at most ``m``: while
    ``m <= margin`` no other segment can be nearest, and the sum is exactly the all-pairs one. Farther
    from ``pose0`` it falls back to the all-pairs evaluation. Used by the polish (a fraction of a mm)."""

    def __init__(self, xy: np.ndarray, segs: Segments, pose0, margin: float = 1e-3):
        self.full = Eq3(xy, segs, None, exact=True)
        f = self.full
        self.p0 = np.asarray(pose0, float).copy()
        self.margin = margin
        self.r = float(np.abs(f.z - complex(self.p0[0], self.p0[1]) / f.res).max()) * f.res
        e = complex(math.cos(self.p0[2]), -math.sin(self.p0[2]))
        q = f.z * e + (f.c0 - complex(self.p0[0], self.p0[1]) / f.res * e)
        rel = q[:, None] - f.a[None]
        t = (rel * f.dc[None]).real * f.il[None]
        _clip01(t)
        d = np.abs(rel - t * f.d[None]) * f.res  # (N, S) m
        dmin = d.min(axis=1, keepdims=True)
        cand = d <= dmin + 2.0 * margin
        k = int(cand.sum(axis=1).max())
        order = np.argsort(np.where(cand, d, np.inf), axis=1, kind="stable")[:, :k]
        first = order[:, :1]
        order = np.where(np.take_along_axis(cand, order, axis=1), order, first)  # pad with the nearest
        self.a, self.dc, self.d, self.il = f.a[order], f.dc[order], f.d[order], f.il[order]

    def __call__(self, pose) -> float:
        f = self.full
        m = math.hypot(pose[0] - self.p0[0], pose[1] - self.p0[1])
        m += abs(pose[2] - self.p0[2]) * (self.r + m)
        if m > self.margin:
            return f(pose)
        e = complex(math.cos(pose[2]), -math.sin(pose[2]))
        q = f.z * e + (f.c0 - complex(pose[0], pose[1]) / f.res * e)
        rel = q[:, None] - self.a
        t = (rel * self.dc).real * self.il
        _clip01(t)
        rel -= t * self.d
        return float(np.abs(rel).min(axis=1).sum()) * f.res


_FIELDS: dict[tuple, DistanceField] = {}


def field_for(segments: np.ndarray, res: float, margin: float, cap: float) -> DistanceField:
    """The cached :class:`DistanceField` of these segments (built once per geometry and process)."""
    import hashlib

    key = (hashlib.sha1(np.ascontiguousarray(segments).tobytes()).hexdigest(), res, margin, cap)
    if key not in _FIELDS:
        if len(_FIELDS) > 8:
            _FIELDS.clear()
        _FIELDS[key] = DistanceField.of(segments, res, margin, cap)
    return _FIELDS[key]
