"""Flat weldments like the paper's Fig. 12, as templates at a planned position (base frame, m).

* :func:`ladder_frame`: two rails and four rungs of rectangular tube (butt joints, two top heights);
* :func:`warren_truss`: top and bottom chords with diagonals mitred against them (one top height);
* :func:`spaceframe_member`: a trapezoidal frame with mitred corners and a brace, like Fig. 3.

Each returns a :class:`~weldcell.plugins.localize.template.Template` whose welds are the contact lines
between members; ``center`` is where the workpiece's centroid is planned (e.g. the middle of the robot's
reachable envelope).
"""

from __future__ import annotations

import numpy as np

from .cad import derive_welds
from .template import Member, Template

WORKPIECES = ("ladder", "truss", "spaceframe")


def _rect(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def _bar(p: np.ndarray, q: np.ndarray, width: float) -> np.ndarray:
    """A straight bar of ``width`` from p to q (square ends)."""
    d = (q - p) / np.linalg.norm(q - p)
    n = np.array([-d[1], d[0]]) * width / 2
    return np.array([p - n, q - n, q + n, p + n])


def _finish(members: list[Member], center, table_z: float) -> Template:
    tpl = Template(members, [], table_z)
    shift = np.asarray(center, dtype=float) - tpl.centroid
    for m in tpl.members:
        m.outline = m.outline + shift
    tpl.welds = derive_welds(tpl.members, table_z)
    return tpl


def ladder_frame(center=(1.0, 0.0), table_z: float = 0.0) -> Template:
    """Rails 1000 x 50 mm (50 mm tall), rungs 40 mm wide (40 mm tall) at uneven spacing."""
    rail_w, gap = 0.05, 0.40
    members = [
        Member("rail-a", table_z + 0.05, _rect(0.0, 0.0, 1.0, rail_w)),
        Member("rail-b", table_z + 0.05, _rect(0.0, rail_w + gap, 1.0, 2 * rail_w + gap)),
    ]
    for k, x in enumerate((0.04, 0.33, 0.61, 0.92)):
        members.append(Member(f"rung-{k + 1}", table_z + 0.04, _rect(x, rail_w, x + 0.04, rail_w + gap)))
    return _finish(members, center, table_z)


def _mitred(p: np.ndarray, q: np.ndarray, width: float, y_lo: float, y_hi: float) -> np.ndarray:
    """A diagonal bar from chord to chord with its ends cut along y = y_lo and y = y_hi (mitre)."""
    d = (q - p) / np.linalg.norm(q - p)
    n = np.array([-d[1], d[0]]) * width / 2
    out = []
    for side in (-n, n):
        a, v = p + side, d
        for y in (y_lo, y_hi):
            s = (y - a[1]) / v[1]
            out.append(a + s * v)
    return np.array([out[0], out[1], out[3], out[2]])


def warren_truss(center=(1.0, 0.0), table_z: float = 0.0) -> Template:
    """Chords 900 x 40 mm and four 30 mm diagonals mitred against them; all 40 mm tall."""
    chord_w, depth, top = 0.04, 0.30, table_z + 0.04
    members = [
        Member("chord-bottom", top, _rect(0.0, 0.0, 0.9, chord_w)),
        Member("chord-top", top, _rect(0.0, chord_w + depth, 0.9, 2 * chord_w + depth)),
    ]
    pairs = ((0.05, 0.20), (0.40, 0.25), (0.45, 0.60), (0.85, 0.65))  # (bottom x, top x) of each diagonal
    for k, (xb, xt) in enumerate(pairs):
        p, q = np.array([xb, chord_w]), np.array([xt, chord_w + depth])
        members.append(Member(f"diag-{k + 1}", top, _mitred(p, q, 0.03, chord_w, chord_w + depth)))
    return _finish(members, center, table_z)


def spaceframe_member(center=(1.0, 0.0), table_z: float = 0.0) -> Template:
    """A trapezoid (base 800 mm, top 400 mm, 450 mm tall) of 40 mm tubes, mitred corners, one brace."""
    w = 0.04
    outer = np.array([[0.0, 0.0], [0.8, 0.0], [0.6, 0.45], [0.2, 0.45]])
    # inner trapezoid offset by the tube width (shapely's parallel offset keeps the mitres exact)
    from shapely.geometry import Polygon

    inner = np.asarray(Polygon(outer).buffer(-w, join_style="mitre").exterior.coords)[:-1]
    # match inner vertices to outer ones (nearest)
    order = [int(np.argmin(np.linalg.norm(inner - v, axis=1))) for v in outer]
    inner = inner[order]
    members = []
    names = ("base", "side-right", "top", "side-left")
    for k in range(4):
        j = (k + 1) % 4
        members.append(Member(names[k], table_z + 0.05, np.array([outer[k], outer[j], inner[j], inner[k]])))
    # a brace from the base to the top member, 30 mm wide, 30 mm tall (a second level)
    p, q = np.array([0.30, w]), np.array([0.52, 0.45 - w])
    members.append(Member("brace", table_z + 0.03, _mitred(p, q, 0.03, w, 0.45 - w)))
    return _finish(members, center, table_z)


def make_workpiece(name: str, center=(1.0, 0.0), table_z: float = 0.0) -> Template:
    """One of :data:`WORKPIECES` by name."""
    makers = {"ladder": ladder_frame, "truss": warren_truss, "spaceframe": spaceframe_member}
    if name not in makers:
        raise KeyError(f"unknown workpiece {name!r}; one of {', '.join(WORKPIECES)}")
    return makers[name](center=center, table_z=table_z)
