"""Synthetic inspections for tests and benchmarks of the localization method.

A placed (and optionally CAD-deviating) template is scanned along polylines by a laser displacement
sensor model like the optoNCDT 1402 of the paper (§II): Gaussian depth noise of 0.288 mm, the 0.4 mm
robot-sensor coupling (an XY error constant along each scan line, 0.2 mm per axis), shearing at edges
(readings within the spot radius of a drop are mixed heights or out of range) and rare random dropouts.
Scan lines come from two simple plan generators (zig-zag across each member's major axis, a spiral along
the workpiece's principal axes, §III-C); the cell's real plans live in the job's own module.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .pose import rot2
from .scan_io import LaserScan
from .template import Template


@dataclass
class SensorModel:
    """Laser displacement sensor + robot: ``noise`` depth σ (m); ``coupling`` XY σ per axis per line (m);
    ``shear`` radius around a drop with unreadable heights (m); ``shear_dropout`` probability such a
    reading is out of range; ``dropout`` random out-of-range probability; ``rate`` (Hz), ``speed`` (m/s)."""

    noise: float = 0.288e-3
    coupling: float = 0.2e-3
    shear: float = 0.2e-3
    shear_dropout: float = 0.5
    dropout: float = 1e-3
    rate: float = 1500.0
    speed: float = 0.2

    @property
    def step(self) -> float:
        return self.speed / self.rate


def member_variations(tpl: Template, rng: np.random.Generator, amount: float = 2e-3) -> list[np.ndarray]:
    """Per member, a 3x3 planar transform that moves it off CAD by up to ``amount``: a random shift and a
    rotation about its centre, scaled so that its farthest vertex moves by a uniform [0, amount]."""
    out = []
    for m in tpl.members:
        c = m.outline.mean(axis=0)
        half = np.linalg.norm(m.outline - c, axis=1).max()
        shift, turn = rng.uniform(-1, 1, 2), rng.uniform(-1, 1) / max(half, 1e-3)
        worst = np.linalg.norm(shift) + abs(turn) * half
        k = amount * rng.uniform() / max(worst, 1e-12)
        R = rot2(turn * k)
        T = np.eye(3)
        T[:2, :2] = R
        T[:2, 2] = c - R @ c + shift * k
        out.append(T)
    return out


def apply_variations(tpl: Template, transforms: list[np.ndarray]) -> Template:
    """A copy with each member moved by its 3x3 transform (welds unchanged: they follow their members)."""
    out = copy.deepcopy(tpl)
    for m, T in zip(out.members, transforms, strict=True):
        m.outline = m.outline @ T[:2, :2].T + T[:2, 2]
    return out


def vary_members(tpl: Template, rng: np.random.Generator, amount: float = 2e-3) -> Template:
    """A copy whose members each deviate from CAD by up to ``amount`` (see :func:`member_variations`)."""
    return apply_variations(tpl, member_variations(tpl, rng, amount))


def _resample(poly: np.ndarray, step: float) -> np.ndarray:
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    u = np.arange(0.0, s[-1], step)
    return np.column_stack([np.interp(u, s, poly[:, 0]), np.interp(u, s, poly[:, 1])])


def _axes(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = xy.mean(axis=0)
    w, v = np.linalg.eigh(np.cov((xy - c).T))
    return c, v[:, ::-1]  # columns: major, minor


def zigzag_plan(tpl: Template, spacing: float = 0.02, span: float = 0.04) -> list[np.ndarray]:
    """Local inspection: per member, lines across its major axis every ``spacing``, reaching ``span``
    beyond each long side; alternating direction (a zig-zag). Returns one (2, 2) polyline per line."""
    lines = []
    for m in tpl.members:
        c, ax = _axes(_densify(m.outline))
        uv = (m.outline - c) @ ax
        (u0, v0), (u1, v1) = uv.min(axis=0), uv.max(axis=0)
        n = max(int((u1 - u0) // spacing), 1)
        us = u0 + (u1 - u0 - (n - 1) * spacing) / 2 + spacing * np.arange(n)
        for k, u in enumerate(us):
            a, b = np.array([u, v0 - span]), np.array([u, v1 + span])
            if k % 2:
                a, b = b, a
            lines.append(np.array([a, b]) @ ax.T + c)
    return lines


def _densify(outline: np.ndarray, n: int = 20) -> np.ndarray:
    closed = np.vstack([outline, outline[:1]])
    t = np.linspace(0, 1, n, endpoint=False)
    return np.concatenate([p + t[:, None] * (q - p) for p, q in zip(closed[:-1], closed[1:], strict=True)])


def spiral_plan(tpl: Template, pitch: float = 0.012, margin: float = 0.06) -> list[np.ndarray]:
    """Global inspection: an elliptic Archimedean spiral along the workpiece's principal axes, covering its
    extent + ``margin``; one polyline per quarter turn."""
    pts = np.concatenate([_densify(m.outline) for m in tpl.members])
    c, ax = _axes(pts)
    uv = (pts - c) @ ax
    a, b = np.abs(uv).max(axis=0) * np.sqrt(2) + margin
    turns = b / pitch
    phi = np.linspace(0, 2 * np.pi * turns, int(turns * 720))
    r = phi / phi[-1]
    path = np.column_stack([a * r * np.cos(phi), b * r * np.sin(phi)]) @ ax.T + c
    q = np.floor(phi / (np.pi / 2)).astype(int)
    return [path[q == k] for k in range(q.max() + 1) if (q == k).sum() > 1]


def _inside(outline: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Whether each point lies strictly inside the closed outline: a convex outline by the signs of its
    edges' cross products (vectorised, as shapely.contains_xy but an order faster), others by shapely."""
    P = np.asarray(outline, float)
    d = np.roll(P, -1, axis=0) - P
    turn = d[:, 0] * np.roll(d, -1, axis=0)[:, 1] - d[:, 1] * np.roll(d, -1, axis=0)[:, 0]
    if not (np.all(turn >= 0) or np.all(turn <= 0)):
        import shapely
        from shapely.geometry import Polygon

        return shapely.contains_xy(Polygon(P), xy[:, 0], xy[:, 1])
    sign = 1.0 if turn.sum() > 0 else -1.0
    lo, hi = P.min(axis=0), P.max(axis=0)
    box = (xy[:, 0] > lo[0]) & (xy[:, 0] < hi[0]) & (xy[:, 1] > lo[1]) & (xy[:, 1] < hi[1])
    idx = np.flatnonzero(box)
    q = xy[idx]
    ok = np.ones(len(idx), bool)
    for a, e in zip(P, d, strict=True):
        ok &= sign * (e[0] * (q[:, 1] - a[1]) - e[1] * (q[:, 0] - a[0])) > 0
    out = np.zeros(len(xy), bool)
    out[idx[ok]] = True
    return out


def height_at(tpl: Template, xy: np.ndarray) -> np.ndarray:
    """Surface height under each XY: the highest member top containing it, else the table."""
    z = np.full(len(xy), tpl.table_z)
    for m in tpl.members:
        inside = _inside(m.outline, xy)
        z = np.where(inside, np.maximum(z, m.top), z)
    return z


def scan_lines(
    truth: Template, lines: list[np.ndarray], rng: np.random.Generator, sensor: SensorModel | None = None
) -> LaserScan:
    """Scan ``truth`` (the part as it lies) along ``lines`` (polylines in the base frame)."""
    s = sensor or SensorModel()
    xy_parts, idx_parts = [], []
    for k, poly in enumerate(lines):
        pts = _resample(np.asarray(poly, dtype=float), s.step)
        xy_parts.append(pts)
        idx_parts.append(np.full(len(pts), k))
    xy = np.concatenate(xy_parts)
    line = np.concatenate(idx_parts)
    offset = rng.normal(0.0, s.coupling, (len(lines), 2))[line]
    true_xy = xy + offset
    z = height_at(truth, true_xy)
    zs = [height_at(truth, true_xy + d) for d in s.shear * np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])]
    zmin, zmax = np.minimum(z, np.min(zs, axis=0)), np.maximum(z, np.max(zs, axis=0))
    shear = zmax > zmin
    z = np.where(shear, rng.uniform(zmin, zmax), z) + rng.normal(0.0, s.noise, len(z))
    lost = (shear & (rng.random(len(z)) < s.shear_dropout)) | (rng.random(len(z)) < s.dropout)
    z[lost] = np.nan
    t = np.arange(len(z)) / s.rate
    return LaserScan(t, np.column_stack([xy, z]), line)


def true_welds(tpl: Template, pose, variations: list[np.ndarray]) -> list[np.ndarray]:
    """Where each weld (XY, (K, 2) per weld) really is when ``tpl`` is placed by ``pose`` (about its
    centroid) with members off CAD by ``variations`` (3x3, :func:`member_variations`): a weld lies against
    the side faces of the members it joins (those within 3 mm of it), so it follows each member across that
    member's axis (:func:`~.refine.fuse_across`)."""
    from shapely import distance, points
    from shapely.geometry import Polygon

    from .refine import fuse_across, member_axis

    c = tpl.centroid
    P = np.eye(3)
    P[:2, :2] = rot2(pose[2])
    P[:2, 2] = c + np.asarray(pose[:2]) - rot2(pose[2]) @ c
    polys = [Polygon(m.outline) for m in tpl.members]
    out = []
    for w in tpl.welds:
        pts = points(w.points[:, :2])
        joined = [k for k, poly in enumerate(polys) if distance(poly, pts).min() <= 3e-3]
        h = np.column_stack([w.points[:, :2], np.ones(len(w.points))])
        placed = h @ P[:2].T
        disp, normals = [], []
        for k in joined:
            T = P @ variations[k]
            u = T[:2, :2] @ member_axis(tpl.members[k].outline)
            disp.append(h @ T[:2].T - placed)
            normals.append(np.array([-u[1], u[0]]))
        out.append(placed + fuse_across(disp, normals))
    return out
