"""The 2-D workpiece template of the localization method (paper 002, §III-A).

Each member of a flat weldment is a closed outline (its top-view boundary, a group of line segments)
with its top height; the CAD weld seams ride along. The template sits at the *planned* position in the
robot base frame (metres). ``weldcell/template@1`` JSON::

    {"schema": "weldcell/template@1", "units": "m", "frame": "base", "table_z": 0.0,
     "members": [{"id": "m1", "top": 0.05, "outline": [[x, y], ...]}, ...],
     "welds": [{"id": "w1", "points": [[x, y, z], ...]}, ...]}

``load_template`` reads that JSON, a DXF (through ezdxf) or a mesh (STL/PLY/OBJ, through trimesh);
see :mod:`weldcell.plugins.localize.cad` for the CAD conventions.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from weldcell.sdk.artifacts import read_json, write_json
from weldcell.sdk.errors import DataError

SCHEMA = "weldcell/template@1"
UNIT_SCALE = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "in": 0.0254}
MESH_SUFFIXES = (".stl", ".ply", ".obj", ".off", ".glb", ".gltf")


@dataclass
class Member:
    """One member: ``outline`` (K, 2) closed polygon in m (last vertex not repeated), ``top`` z in m."""

    id: str
    top: float
    outline: np.ndarray

    def __post_init__(self) -> None:
        self.outline = np.asarray(self.outline, dtype=float).reshape(-1, 2)
        if len(self.outline) > 1 and np.allclose(self.outline[0], self.outline[-1]):
            self.outline = self.outline[:-1]

    def segments(self) -> np.ndarray:
        """(K, 2, 2) line segments of the closed outline."""
        return np.stack([self.outline, np.roll(self.outline, -1, axis=0)], axis=1)


@dataclass
class Weld:
    """A CAD weld seam: ``points`` (P, 3) in m, base frame, at the planned position."""

    id: str
    points: np.ndarray

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=float).reshape(-1, 3)


@dataclass
class Template:
    """Members + welds at the planned position (base frame, m); the table is z = ``table_z``."""

    members: list[Member]
    welds: list[Weld] = field(default_factory=list)
    table_z: float = 0.0
    frame: str = "base"
    source: str = ""

    # ---------------------------------------------------------------- geometry
    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """All outline segments (S, 2, 2) and the index of the member each belongs to (S,)."""
        segs = [m.segments() for m in self.members]
        owner = np.concatenate([np.full(len(s), i) for i, s in enumerate(segs)])
        return np.concatenate(segs, axis=0), owner

    @property
    def centroid(self) -> np.ndarray:
        """Area-weighted centroid of the members' outlines (the pivot of ``theta``)."""
        areas, cents = [], []
        for m in self.members:
            a, c = polygon_area_centroid(m.outline)
            areas.append(abs(a))
            cents.append(c)
        w = np.asarray(areas)
        return (np.asarray(cents) * w[:, None]).sum(axis=0) / max(w.sum(), 1e-18)

    @property
    def radius(self) -> float:
        """Largest distance of an outline vertex from the centroid (m)."""
        pts = np.concatenate([m.outline for m in self.members])
        return float(np.linalg.norm(pts - self.centroid, axis=1).max())

    def levels(self) -> np.ndarray:
        """Distinct surface heights (table first, then member tops), ascending."""
        tops = sorted({round(m.top, 6) for m in self.members} | {round(self.table_z, 6)})
        return np.asarray(tops, dtype=float)

    def member_index(self, member_id: str) -> int:
        for i, m in enumerate(self.members):
            if m.id == member_id:
                return i
        raise KeyError(member_id)

    # ---------------------------------------------------------------- validation and files
    def validate(self, allow_single_member: bool = False, what: str = "template") -> list[str]:
        """Check outlines (closed, simple, non-degenerate), heights and ids; returns warnings."""
        from shapely.geometry import Polygon
        from shapely.validation import explain_validity

        if not self.members:
            raise DataError(f"{what} has no member", "draw each member as a closed outline")
        ids = [m.id for m in self.members]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise DataError(f"{what}: member ids repeated: {', '.join(dup)}", "give every member its own id")
        for m in self.members:
            if len(m.outline) < 3 or not np.isfinite(m.outline).all():
                raise DataError(
                    f"{what}: member '{m.id}' outline has {len(m.outline)} vertices or non-finite values",
                    "an outline is a closed polygon of at least 3 finite [x, y] vertices",
                )
            poly = Polygon(m.outline)
            if not poly.is_valid:
                raise DataError(
                    f"{what}: member '{m.id}' outline is self-intersecting ({explain_validity(poly)})",
                    "fix the outline in CAD so that its edges do not cross",
                )
            if poly.area < 1e-8:
                raise DataError(f"{what}: member '{m.id}' outline has no area", "check the outline")
            if not math.isfinite(m.top) or m.top <= self.table_z:
                raise DataError(
                    f"{what}: member '{m.id}' top {m.top * 1000:.1f} mm is not above the table "
                    f"({self.table_z * 1000:.1f} mm)",
                    "give each member its top height above the table (e.g. layer 'm1_top50' in a DXF)",
                )
        notes = []
        if len(self.members) == 1:
            msg = (
                f"{what} has a single member: its pose is under-constrained along its major axis and "
                "symmetric under 180 deg (paper §IV: neighbouring members constrain the sliding)"
            )
            if not allow_single_member:
                raise DataError(msg, "localize the whole weldment, or pass --allow-single-member")
            notes.append(msg)
            warnings.warn(msg, stacklevel=2)
        return notes

    def to_json(self) -> dict:
        """``weldcell/template@1`` as a JSON-ready dict (metres)."""
        return {
            "schema": SCHEMA,
            "units": "m",
            "frame": self.frame,
            "table_z": float(self.table_z),
            "members": [
                {"id": m.id, "top": float(m.top), "outline": np.round(m.outline, 9).tolist()}
                for m in self.members
            ],
            "welds": [{"id": w.id, "points": np.round(w.points, 9).tolist()} for w in self.welds],
        }

    def save(self, path: str | Path) -> Path:
        return write_json(path, self.to_json())


def polygon_area_centroid(xy: np.ndarray) -> tuple[float, np.ndarray]:
    """Signed area and centroid of a closed polygon (shoelace)."""
    x, y = xy[:, 0], xy[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    a = cross.sum() / 2.0
    if abs(a) < 1e-18:
        return 0.0, xy.mean(axis=0)
    cx = ((x + xn) * cross).sum() / (6 * a)
    cy = ((y + yn) * cross).sum() / (6 * a)
    return float(a), np.array([cx, cy])


# -------------------------------------------------------------------------------- JSON
_TOP_KEYS = {"schema", "units", "frame", "members", "welds", "table_z", "name", "source"}


def _refuse_unknown(obj: dict, allowed: set[str], where: str) -> None:
    extra = sorted(set(obj) - allowed)
    if extra:
        raise DataError(
            f"{where}: unknown keys {', '.join(map(repr, extra))}",
            f"allowed keys: {', '.join(sorted(allowed))}",
        )


def template_from_json(data: object, what: str = "template") -> Template:
    """Parse a ``weldcell/template@1`` dict (unknown keys refused; ``units`` m/mm/cm/in converted to m)."""
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        got = data.get("schema") if isinstance(data, dict) else type(data).__name__
        raise DataError(
            f"{what}: schema is {got!r}, expected '{SCHEMA}'", "write the template with `weldcell template`"
        )
    _refuse_unknown(data, _TOP_KEYS, what)
    units = data.get("units", "m")
    if units not in UNIT_SCALE:
        raise DataError(f"{what}: unknown units {units!r}", f"use one of {', '.join(UNIT_SCALE)}")
    s = UNIT_SCALE[units]
    if data.get("frame", "base") != "base":
        raise DataError(
            f"{what}: frame {data.get('frame')!r}", "templates are in the robot base frame ('base')"
        )
    members_raw = data.get("members")
    if not isinstance(members_raw, list):
        raise DataError(f"{what}: 'members' must be a list", "see docs/methods/localization.md")
    members = []
    try:
        for k, m in enumerate(members_raw):
            _refuse_unknown(m, {"id", "top", "outline"}, f"{what}: members[{k}]")
            members.append(
                Member(str(m.get("id", f"m{k + 1}")), float(m["top"]) * s, np.asarray(m["outline"]) * s)
            )
        welds = []
        for k, w in enumerate(data.get("welds", [])):
            _refuse_unknown(w, {"id", "points"}, f"{what}: welds[{k}]")
            welds.append(Weld(str(w.get("id", f"w{k + 1}")), np.asarray(w["points"], dtype=float) * s))
        table_z = float(data.get("table_z", 0.0)) * s
    except (KeyError, TypeError, ValueError) as e:
        raise DataError(
            f"{what}: malformed member or weld ({type(e).__name__}: {e})", "see the format above"
        ) from None
    tpl = Template(members, welds, table_z, "base", what)
    ext = np.ptp(np.concatenate([m.outline for m in members]), axis=0).max()
    if not 0.005 <= ext <= 50.0:
        raise DataError(
            f"{what}: the template spans {ext:g} m, implausible for a weldment in {units!r}",
            'check \'units\' (a drawing in millimetres needs "units": "mm")',
        )
    return tpl


def load_template(
    path: str | Path,
    units: str | None = None,
    top: float | None = None,
    allow_single_member: bool = False,
    chord_tolerance: float = 1e-4,
) -> Template:
    """Read a template from ``weldcell/template@1`` JSON, DXF or a mesh (STL/PLY/OBJ), validated.

    ``units`` overrides the file's (DXF ``$INSUNITS``; a mesh has none: default mm); ``top`` (m) is the
    top height of members whose DXF gives none; ``chord_tolerance`` (m) flattens arcs and bulges.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"template file not found: {path}", "check the path")
    suffix = path.suffix.lower()
    if suffix == ".json":
        tpl = template_from_json(read_json(path), what=str(path))
    elif suffix == ".dxf":
        from weldcell.plugins.localize.cad import read_dxf

        tpl = read_dxf(path, units=units, top=top, chord_tolerance=chord_tolerance)
    elif suffix in MESH_SUFFIXES:
        from weldcell.plugins.localize.cad import read_mesh

        tpl = read_mesh(path, units=units or "mm")
    else:
        raise DataError(
            f"{path}: unsupported template format '{suffix}'",
            "use a weldcell/template@1 .json, a .dxf, or a mesh (.stl, .ply, .obj)",
        )
    tpl.source = str(path)
    tpl.validate(allow_single_member=allow_single_member, what=str(path))
    return tpl
