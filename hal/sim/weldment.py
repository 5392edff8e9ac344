"""A flat weldment in the simulated cell: members extruded from their top-view outlines, and what a
worker does to it (places it with an error; the real members differ from CAD by a little).

Plain arrays in, so hal needs no plugin: ``outlines`` is a list of (K, 2) closed polygons (metres, the
frame the template is drawn in), ``tops`` their top heights above the table, ``welds`` a list of (P, 3)
seam polylines. :func:`weldment_workpiece` turns them into a :class:`Workpiece` (mesh + seams) the
sensors see; :func:`perturb_members` makes the as-built members; :func:`placement_error` draws the
worker's rigid error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from weldcell.hal.sim.workpieces import SeamTruth, Workpiece
from weldcell.sdk.errors import DataError


def extrude(outline: np.ndarray, z0: float, z1: float) -> o3d.geometry.TriangleMesh:
    """A prism from a closed polygon (K, 2) between heights ``z0 < z1`` (trimesh's triangulation)."""
    import trimesh
    from shapely.geometry import Polygon

    P = np.asarray(outline, dtype=float).reshape(-1, 2)
    if len(P) > 1 and np.allclose(P[0], P[-1]):
        P = P[:-1]
    poly = Polygon(P)
    if len(P) < 3 or not poly.is_valid or poly.area <= 0:
        raise DataError(
            "a member outline is not a valid polygon", "give a closed, non-self-intersecting outline"
        )
    if z1 <= z0:
        raise DataError(f"member top {z1:.4f} m is not above the table {z0:.4f} m", "check the member's top")
    m = trimesh.creation.extrude_polygon(poly, z1 - z0)
    m.apply_translation([0.0, 0.0, z0])
    out = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(m.vertices)), o3d.utility.Vector3iVector(np.asarray(m.faces))
    )
    out.compute_triangle_normals()
    return out


def _travel(points: np.ndarray) -> np.ndarray:
    v = np.gradient(points, axis=0)
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.maximum(n, 1e-12)


def weldment_workpiece(
    outlines: list[np.ndarray],
    tops: list[float],
    welds: list[np.ndarray],
    weld_ids: list[str] | None = None,
    table_z: float = 0.0,
    name: str = "weldment",
) -> Workpiece:
    """The weldment as one workpiece in the frame of its outlines (world = that frame when unplaced).

    Seams are the weld polylines, densified to 0.5 mm, approached from above (torch z = -z).
    """
    if len(outlines) != len(tops) or not outlines:
        raise DataError("a weldment needs one top height per member outline", "pass matching lists")
    mesh = o3d.geometry.TriangleMesh()
    for P, top in zip(outlines, tops, strict=True):
        mesh += extrude(P, table_z, table_z + float(top))
    seams = []
    ids = weld_ids or [f"w{i}" for i in range(len(welds))]
    for wid, W in zip(ids, welds, strict=True):
        W = np.asarray(W, dtype=float).reshape(-1, 3)
        L = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(W, axis=0), axis=1))]
        if len(W) < 2 or L[-1] <= 0:
            continue
        s = np.linspace(0.0, L[-1], max(2, int(np.ceil(L[-1] / 0.0005)) + 1))
        pts = np.column_stack([np.interp(s, L, W[:, i]) for i in range(3)])
        seams.append(
            SeamTruth(str(wid), "fillet", pts, np.tile([0.0, 0.0, -1.0], (len(pts), 1)), _travel(pts))
        )
    return Workpiece(name, "weldment", mesh, seams)


@dataclass(frozen=True)
class MemberVariation:
    """How an as-built member differs from CAD: its length grows by ``dlength`` (m) along its major axis
    ``major`` about its centre ``centre``, whose half-length is ``half``; then it is shifted by ``offset``."""

    dlength: float
    offset: np.ndarray
    centre: np.ndarray
    major: np.ndarray
    half: float

    def displace(self, xy: np.ndarray) -> np.ndarray:
        """Where CAD points (N, 2) of this member are on the as-built member (N, 2)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        along = (xy - self.centre) @ self.major
        return xy + np.outer(along / self.half * self.dlength / 2, self.major) + self.offset


def perturb_members(
    outlines: list[np.ndarray], amount: float, rng: np.random.Generator
) -> tuple[list[np.ndarray], list[MemberVariation]]:
    """As-built outlines: each member's length changed by U(-amount, amount) and its position shifted by
    U(-amount/2, amount/2) per axis, so no outline point moves by more than ~``amount`` (the ±2 mm of
    members cut and tacked by hand)."""
    out, var = [], []
    for P in outlines:
        P = np.asarray(P, dtype=float).reshape(-1, 2)
        c = P.mean(axis=0)
        w, V = np.linalg.eigh(np.cov((P - c).T))
        major = V[:, int(np.argmax(w))]
        half = max(float(np.max(np.abs((P - c) @ major))), 1e-9)
        dl = float(rng.uniform(-amount, amount)) if amount > 0 else 0.0
        off = rng.uniform(-amount / 2, amount / 2, size=2) if amount > 0 else np.zeros(2)
        v = MemberVariation(dl, off, c, major, half)
        out.append(v.displace(P))
        var.append(v)
    return out, var


def placement_error(
    max_offset: float, max_angle: float, rng: np.random.Generator
) -> tuple[float, float, float]:
    """The worker's rigid error (dx, dy, dtheta): uniform in ±``max_offset`` per axis and ±``max_angle``."""
    return (
        float(rng.uniform(-max_offset, max_offset)),
        float(rng.uniform(-max_offset, max_offset)),
        float(rng.uniform(-max_angle, max_angle)),
    )


def rigid_2d(dx: float, dy: float, dtheta: float, centre: np.ndarray) -> np.ndarray:
    """``M`` (4, 4): rotation by ``dtheta`` about the vertical axis through ``centre`` (2,), then (dx, dy)."""
    c, s = np.cos(dtheta), np.sin(dtheta)
    M = np.eye(4)
    M[:2, :2] = [[c, -s], [s, c]]
    cx, cy = float(centre[0]), float(centre[1])
    M[:2, 3] = [cx - (c * cx - s * cy) + dx, cy - (s * cx + c * cy) + dy]
    return M
