"""CAD readers for the localization template (paper 002, §III-A): DXF through ezdxf, meshes through trimesh.

DXF conventions (documented in docs/methods/localization.md):

* ``$INSUNITS`` gives the units (in, ft, mm, cm, m); a unitless drawing is refused unless ``units`` is given.
* Every closed outline is a member: a closed LWPOLYLINE/POLYLINE (bulges flattened to ``chord_tolerance``),
  or LINE/ARC/open-polyline pieces of one layer (or one block insert) chained end to end into a closed loop.
  Loops nested inside another loop of the same layer/block (holes) are ignored with a warning.
* Members are grouped by block insert (one INSERT = one member group, transformed) else by layer. The id is
  the INSERT's ``ID`` attribute, else the block or layer name (``#k`` appended for several loops).
* The top height (drawing units, above z = 0 of the drawing) comes from, in order: XDATA of app ``WELDCELL``
  holding ``top=<value>``; an INSERT attribute ``TOP``; a layer or block name containing ``top<value>``
  (``m1_top50``, ``RAIL-TOP=40``); else the ``top`` argument (metres; CLI ``--top``).
* Entities on layers whose name starts with ``WELD`` are weld seams (their 3-D vertices); when the drawing
  has none, welds are derived where two members' outlines touch (:func:`derive_welds`).

Meshes: every connected body is a member; its outline is the union of its triangles projected on XY, its
top the body's highest z; the table is the lowest z of the mesh; welds are derived.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
from weldcell.sdk.errors import DataError

from .template import UNIT_SCALE, Member, Template, Weld

INSUNITS = {1: "in", 2: "ft", 4: "mm", 5: "cm", 6: "m"}
_SCALE = {**UNIT_SCALE, "ft": 0.3048}
_TOP_RE = re.compile(r"top\s*[_=:\-]?\s*(\d+(?:\.\d+)?)", re.IGNORECASE)
CHAIN_TOL = 1e-6  # m: endpoints closer than this are the same vertex when chaining lines


def _units_scale(doc, units: str | None, path: Path) -> float:
    if units is not None:
        if units not in _SCALE:
            raise DataError(f"unknown units '{units}'", f"use one of {', '.join(_SCALE)}")
        return _SCALE[units]
    code = int(doc.header.get("$INSUNITS", 0))
    if code not in INSUNITS:
        what = "unitless ($INSUNITS = 0)" if code == 0 else f"in unsupported units ($INSUNITS = {code})"
        raise DataError(
            f"{path}: the drawing is {what}, so its size is unknown",
            "save the DXF with units (mm or m), or pass --units mm",
        )
    return _SCALE[INSUNITS[code]]


def _top_of(entity, insert, name: str) -> float | None:
    """Top height in drawing units from XDATA, INSERT attribute or the layer/block name; None if absent."""
    for src in (entity, insert):
        if src is None:
            continue
        try:
            tags = src.get_xdata("WELDCELL")
        except Exception:  # noqa: BLE001 - ezdxf raises DXFValueError when the app has no XDATA
            tags = None
        for code, value in tags or []:
            m = _TOP_RE.search(str(value)) if code == 1000 else None
            if m:
                return float(m.group(1))
    if insert is not None:
        for att in insert.attribs:
            if att.dxf.tag.upper() == "TOP":
                return float(att.dxf.text)
    m = _TOP_RE.search(name)
    return float(m.group(1)) if m else None


def _flatten(entity, tol: float) -> np.ndarray | None:
    from ezdxf import path as ezpath

    try:
        p = ezpath.make_path(entity)
    except (TypeError, ValueError):
        return None
    pts = np.array([tuple(v) for v in p.flattening(tol)], dtype=float)
    return pts if len(pts) >= 2 else None


def _chain(pieces: list[np.ndarray], tol: float) -> tuple[list[np.ndarray], int]:
    """Chain open polylines (K, 2) end to end into closed loops; returns loops and the pieces left over."""
    left = [p for p in pieces]
    loops = []
    while left:
        cur = left.pop(0)
        grown = True
        while grown and np.linalg.norm(cur[0] - cur[-1]) > tol:
            grown = False
            for k, p in enumerate(left):
                if np.linalg.norm(p[0] - cur[-1]) <= tol:
                    cur = np.vstack([cur, p[1:]])
                elif np.linalg.norm(p[-1] - cur[-1]) <= tol:
                    cur = np.vstack([cur, p[::-1][1:]])
                else:
                    continue
                left.pop(k)
                grown = True
                break
        if np.linalg.norm(cur[0] - cur[-1]) <= tol and len(cur) >= 4:
            loops.append(cur[:-1])
        elif not grown:
            return loops, len(left) + 1
    return loops, 0


def _groups(msp):
    """Yield (group name, insert or None, entities) for block inserts and for layers of plain entities."""
    by_layer: dict[str, list] = {}
    for e in msp:
        if e.dxftype() == "INSERT":
            yield e.dxf.name, e, [v for v in e.virtual_entities() if v.dxftype() != "INSERT"]
        else:
            by_layer.setdefault(e.dxf.layer, []).append(e)
    for layer, ents in by_layer.items():
        yield layer, None, ents


def read_dxf(path: Path, units: str | None = None, top: float | None = None, chord_tolerance: float = 1e-4):
    """Read a flat weldment's template from a DXF (see the module docstring for the conventions)."""
    import ezdxf
    from shapely.geometry import Polygon

    try:
        doc = ezdxf.readfile(str(path))
    except (OSError, ezdxf.DXFError) as e:
        raise DataError(f"{path}: not a readable DXF ({e})", "export the drawing again as DXF") from None
    s = _units_scale(doc, units, path)
    tol = chord_tolerance / s
    members: list[Member] = []
    welds: list[Weld] = []
    open_left = 0
    for name, insert, ents in _groups(doc.modelspace()):
        if name.upper().startswith("WELD"):
            for e in ents:
                pts = _flatten(e, tol)
                if pts is not None:
                    welds.append(Weld(f"w{len(welds) + 1}", pts * s))
            continue
        loops, pieces, tops = [], [], []
        for e in ents:
            pts = _flatten(e, tol)
            if pts is None:
                continue
            closed = np.linalg.norm(pts[0, :2] - pts[-1, :2]) <= tol * 1e-3 + 1e-9 and len(pts) >= 4
            (loops if closed else pieces).append(pts[:-1, :2] if closed else pts[:, :2])
            tops.append(_top_of(e, insert, name))
        chained, n_left = _chain(pieces, CHAIN_TOL / s)
        loops += chained
        open_left += n_left
        polys = [Polygon(lp) for lp in loops]
        outer = [
            k for k, p in enumerate(polys) if not any(j != k and q.contains(p) for j, q in enumerate(polys))
        ]
        if len(outer) < len(loops):
            warnings.warn(
                f"{path}: {len(loops) - len(outer)} nested loop(s) on '{name}' ignored", stacklevel=2
            )
        h = next((t for t in tops if t is not None), None)
        att_id = (
            next((a.dxf.text for a in insert.attribs if a.dxf.tag.upper() == "ID"), None) if insert else None
        )
        for n, k in enumerate(outer):
            top_m = h * s if h is not None else top
            mid = att_id or name
            mid = mid if len(outer) == 1 else f"{mid}#{n + 1}"
            if top_m is None:
                raise DataError(
                    f"{path}: member '{mid}' has no top height",
                    "name its layer like 'm1_top50' (drawing units), add XDATA WELDCELL 'top=50' "
                    "or pass --top",
                )
            members.append(Member(mid, float(top_m), loops[k] * s))
    if not members:
        extra = f" ({open_left} open chain(s) do not close)" if open_left else ""
        raise DataError(
            f"{path}: no closed outline found{extra}",
            "draw each member as a closed polyline (or lines that meet end to end) on its own layer or block",
        )
    if open_left:
        warnings.warn(f"{path}: {open_left} open line chain(s) ignored (they do not close)", stacklevel=2)
    if not welds:
        welds = derive_welds(members, 0.0)
    return Template(members, welds, 0.0)


def read_mesh(path: Path, units: str = "mm") -> Template:
    """Read a flat weldment mesh: one member per connected body (outline = union of projected triangles)."""
    import shapely
    import trimesh
    from shapely.geometry import Polygon

    if units not in _SCALE:
        raise DataError(f"unknown units '{units}'", f"use one of {', '.join(_SCALE)}")
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as e:  # noqa: BLE001 - trimesh raises many types on bad files
        raise DataError(
            f"{path}: not a readable mesh ({e})", "export the part again as STL, PLY or OBJ"
        ) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise DataError(f"{path}: the mesh has no faces", "export the part again as a triangle mesh")
    mesh.apply_scale(_SCALE[units])
    ext = float(np.ptp(mesh.vertices[:, :2], axis=0).max())
    if not 0.005 <= ext <= 50.0:
        raise DataError(
            f"{path}: the part spans {ext:g} m in '{units}'", "pass the mesh's units with --units"
        )
    table_z = float(mesh.vertices[:, 2].min())
    bodies = mesh.split(only_watertight=False)
    members = []
    for body in bodies:
        tri = body.triangles[:, :, :2]
        u, v = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
        shape = shapely.union_all([Polygon(t) for t in tri[area > 1e-12]]).buffer(0)
        if shape.geom_type == "MultiPolygon":
            shape = max(shape.geoms, key=lambda g: g.area)
        if shape.is_empty:
            continue
        shape = shape.simplify(1e-6)
        members.append((float(body.vertices[:, 2].max()), np.asarray(shape.exterior.coords)[:-1]))
    members.sort(key=lambda m: (round(m[1][:, 0].mean(), 4), round(m[1][:, 1].mean(), 4)))
    out = [Member(f"m{k + 1}", top, xy) for k, (top, xy) in enumerate(members)]
    return Template(out, derive_welds(out, table_z), table_z)


def derive_welds(members: list[Member], table_z: float, touch: float = 1e-3, min_length: float = 5e-3):
    """Weld seams where two members' outlines touch (within ``touch``): the contact line at the lower top."""
    from shapely.geometry import Polygon
    from shapely.ops import linemerge

    polys = [Polygon(m.outline) for m in members]
    welds = []
    for i in range(len(members)):
        for j in range(i + 1, len(members)):
            contact = polys[i].boundary.intersection(polys[j].buffer(touch))
            if contact.is_empty or contact.length < min_length:
                continue
            merged = linemerge(contact) if contact.geom_type == "MultiLineString" else contact
            lines = list(merged.geoms) if hasattr(merged, "geoms") else [merged]
            line = max(lines, key=lambda g: g.length)
            xy = np.asarray(line.coords)[[0, -1]]
            z = min(members[i].top, members[j].top)
            welds.append(Weld(f"w{len(welds) + 1}", np.column_stack([xy, [z, z]])))
    return welds
