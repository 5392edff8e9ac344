"""Polylines in the working plane: projection, tangents/normals, and test seams with vision error.

The tactile servo of paper 003 (§2.2.2, Fig. 8) works in the 2-D plane orthogonal to the base z axis.
A :class:`Polyline` keeps 3-D points (so heights can be followed) but projects and differentiates in xy.
Tangents are interpolated between vertex tangents, so a densely or coarsely sampled path gives the
same smooth direction field (the paper takes the nearest *point*, Algorithm 2 lines 10 and 22; we
project onto the segments, which removes the quantisation of the nearest-vertex rule).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from weldcell.sdk.errors import DataError


def left_normal(t: np.ndarray) -> np.ndarray:
    """Normal obtained by turning an xy tangent +90° (counter-clockwise seen from +z)."""
    t = np.asarray(t, dtype=float)
    return np.stack([-t[..., 1], t[..., 0]], axis=-1)


@dataclass(frozen=True)
class Projection:
    """Where a point falls on a :class:`Polyline`."""

    s: float  # arc length of the foot point (xy), clipped to [0, length]
    point: np.ndarray  # foot point (D,)
    tangent: np.ndarray  # unit xy tangent (2,)
    distance: float  # xy distance point-foot
    segment: int
    before_start: bool  # the point lies before the first vertex (foot clipped to s = 0)
    past_end: bool  # the point lies beyond the last vertex (foot clipped to s = length)


class Polyline:
    """An ordered path of 2-D or 3-D points, parameterised by xy arc length."""

    def __init__(self, points: np.ndarray, name: str = "path") -> None:
        P = np.asarray(points, dtype=float)
        if P.ndim != 2 or P.shape[1] not in (2, 3):
            raise DataError(
                f"{name}: expected an (N, 2) or (N, 3) array of points, got shape {P.shape}",
                "pass the path as a list of [x, y] or [x, y, z] points in metres",
            )
        if not np.all(np.isfinite(P)):
            raise DataError(f"{name}: contains NaN or infinite coordinates", "drop invalid points first")
        keep = np.ones(len(P), dtype=bool)
        if len(P) > 1:
            keep[1:] = np.linalg.norm(np.diff(P[:, :2], axis=0), axis=1) > 1e-9
        P = P[keep]
        if len(P) < 2:
            raise DataError(
                f"{name}: needs at least 2 distinct points in xy, got {len(P)}",
                "give a path with some length in the working plane",
            )
        self.name = name
        self.points = P
        self.xy = P[:, :2]
        d = np.diff(self.xy, axis=0)
        self.seg_len = np.linalg.norm(d, axis=1)
        self.seg_dir = d / self.seg_len[:, None]
        self.s = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        vt = np.empty_like(self.xy)
        vt[0], vt[-1] = self.seg_dir[0], self.seg_dir[-1]
        if len(P) > 2:
            mid = self.seg_dir[:-1] + self.seg_dir[1:]
            n = np.linalg.norm(mid, axis=1, keepdims=True)
            vt[1:-1] = np.where(n > 1e-9, mid / np.maximum(n, 1e-12), self.seg_dir[1:])
        self.vertex_tangent = vt

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def _tangent(self, seg: int, u: float) -> np.ndarray:
        t = (1.0 - u) * self.vertex_tangent[seg] + u * self.vertex_tangent[seg + 1]
        n = np.linalg.norm(t)
        return t / n if n > 1e-9 else self.seg_dir[seg].copy()

    def project(self, p: np.ndarray, s_hint: float | None = None, window: float | None = None) -> Projection:
        """Foot of ``p`` (xy) on the path; with ``s_hint``/``window`` only segments within ±window."""
        q = np.asarray(p, dtype=float)[:2]
        lo, hi = 0, len(self.seg_len)
        if s_hint is not None and window is not None:
            lo = max(0, int(np.searchsorted(self.s, s_hint - window, side="right")) - 1)
            hi = min(len(self.seg_len), int(np.searchsorted(self.s, s_hint + window, side="left")) + 1)
            hi = max(hi, lo + 1)
        A = self.xy[lo:hi]
        D = self.seg_dir[lo:hi]
        L = self.seg_len[lo:hi]
        w = np.einsum("ij,ij->i", q - A, D)
        u = np.clip(w / L, 0.0, 1.0)
        foot = A + (u * L)[:, None] * D
        dist = np.linalg.norm(q - foot, axis=1)
        k = int(np.argmin(dist))
        seg = lo + k
        uk = float(u[k])
        point = self.points[seg] + uk * (self.points[seg + 1] - self.points[seg])
        before = seg == 0 and w[k] < 0.0
        past = seg == len(self.seg_len) - 1 and w[k] > L[k]
        return Projection(
            float(self.s[seg] + uk * self.seg_len[seg]),
            point,
            self._tangent(seg, uk),
            float(dist[k]),
            seg,
            bool(before),
            bool(past),
        )

    def at(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        """Point (D,) and unit xy tangent at arc length ``s`` (clipped to the path)."""
        s = float(np.clip(s, 0.0, self.length))
        seg = int(np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.seg_len) - 1))
        u = (s - self.s[seg]) / self.seg_len[seg]
        return self.points[seg] + u * (self.points[seg + 1] - self.points[seg]), self._tangent(seg, u)

    def smooth_tangent(self, s: float, half_window: float) -> np.ndarray:
        """Unit xy tangent at ``s`` from a least-squares line through the vertices within ±half_window.

        Robust to per-point noise of measured paths (the refined path of Algorithm 2 records noisy
        tip positions every few tenths of a millimetre, whose segment directions are far noisier).
        """
        i0 = int(np.searchsorted(self.s, s - half_window, side="left"))
        i1 = int(np.searchsorted(self.s, s + half_window, side="right"))
        pts = self.xy[i0:i1]
        if len(pts) < 3:
            return self.at(s)[1]
        c = pts - pts.mean(axis=0)
        _, _, vt = np.linalg.svd(c, full_matrices=False)
        t = vt[0]
        ref = pts[-1] - pts[0]
        return t if t @ ref >= 0 else -t

    def distances(self, pts: np.ndarray) -> np.ndarray:
        """xy distance of each of (M, 2|3) points to the path (vectorised over points and segments)."""
        Q = np.asarray(pts, dtype=float).reshape(-1, np.asarray(pts).shape[-1])[:, :2]
        out = np.empty(len(Q))
        for i0 in range(0, len(Q), 2048):  # bound memory: block of points x all segments
            q = Q[i0 : i0 + 2048, None, :] - self.xy[None, :-1, :]
            w = np.clip(np.einsum("mkj,kj->mk", q, self.seg_dir) / self.seg_len, 0.0, 1.0)
            foot = q - (w * self.seg_len)[..., None] * self.seg_dir[None]
            out[i0 : i0 + 2048] = np.linalg.norm(foot, axis=2).min(axis=1)
        return out

    def resample(self, step: float) -> np.ndarray:
        """Points every ``step`` metres of xy arc length (ends included)."""
        n = max(2, int(np.ceil(self.length / step)) + 1)
        ss = np.linspace(0.0, self.length, n)
        return np.array([self.at(s)[0] for s in ss])


def vertex_normals(points: np.ndarray, side: str = "left") -> np.ndarray:
    """Horizontal unit normals (N, 3) at each vertex, on the ``side`` ('left'/'right') of travel."""
    line = Polyline(points)
    sign = 1.0 if side == "left" else -1.0
    if side not in ("left", "right"):
        raise DataError(
            f"side must be 'left' or 'right', got {side!r}", "say on which side of travel the wall is"
        )
    n2 = sign * left_normal(line.vertex_tangent)
    return np.column_stack([n2, np.zeros(len(n2))])


def offset_polyline(points: np.ndarray, offset: float, side: str = "left") -> np.ndarray:
    """Points shifted by ``offset`` along their horizontal vertex normals on ``side``."""
    P = np.asarray(points, dtype=float)
    n = vertex_normals(P, side)
    return P + offset * n[:, : P.shape[1]]


def straight_seam(
    length: float = 0.12,
    step: float = 0.001,
    z: float = 0.0,
    origin: tuple[float, float] = (0.4, -0.06),
    heading: float = np.pi / 2,
) -> np.ndarray:
    """A straight seam of ``length`` m along ``heading`` (rad, about base z) sampled every ``step``."""
    s = np.arange(0.0, length + 0.5 * step, step)
    return np.column_stack(
        [origin[0] + s * np.cos(heading), origin[1] + s * np.sin(heading), np.full_like(s, z)]
    )


def curved_seam(
    radius: float = 0.08,
    angle: float = 1.5,
    step: float = 0.001,
    z: float = 0.0,
    center: tuple[float, float] = (0.4, 0.0),
    start_angle: float = -0.75,
    lead_in: float = 0.02,
) -> np.ndarray:
    """A straight lead-in then a counter-clockwise circular arc (a saddle seam seen from above)."""
    a = np.linspace(start_angle, start_angle + angle, max(3, int(radius * angle / step) + 1))
    arc = np.column_stack(
        [center[0] + radius * np.cos(a), center[1] + radius * np.sin(a), np.full_like(a, z)]
    )
    t0 = np.array([-np.sin(start_angle), np.cos(start_angle), 0.0])
    k = max(2, int(lead_in / step) + 1)
    lead = arc[0] - np.outer(np.linspace(lead_in, 0.0, k), t0)
    return np.vstack([lead[:-1], arc])


def planned_path_with_error(
    seam: np.ndarray,
    offset: float = 0.002,
    drift: float = 0.01,
    wobble: float = 0.0003,
    wobble_period: float = 0.05,
    noise: float = 0.0001,
    side: str = "left",
    seed: int = 0,
    end_error: float = 0.0,
) -> np.ndarray:
    """The seam as a 3-D scanner would plan it: lateral offset + slow drift + wobble + noise.

    The lateral error at arc length s is ``offset + drift*s + wobble*sin(2πs/period) + N(0, noise)``
    (metres, along the horizontal normal on ``side`` of travel). ``end_error`` lengthens (>0) or
    shortens (<0) the plan at its end, as a badly extracted seam end would.
    """
    line = Polyline(seam, "seam")
    rng = np.random.default_rng(seed)
    P = np.asarray(seam, dtype=float)
    s = line.s
    e = offset + drift * s + wobble * np.sin(2 * np.pi * s / wobble_period) + rng.normal(0.0, noise, len(s))
    n = vertex_normals(P, side)
    out = P + e[:, None] * n[:, : P.shape[1]]
    if end_error > 0:
        t = np.concatenate([line.vertex_tangent[-1], [0.0]])[: P.shape[1]]
        step = float(np.median(line.seg_len))
        extra = out[-1] + np.outer(np.arange(1, int(end_error / step) + 1) * step, t)
        out = np.vstack([out, extra])
    elif end_error < 0:
        out = out[s <= line.length + end_error]
    return out
