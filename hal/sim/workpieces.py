"""Parametric workpieces of the simulated cell, each with its ground-truth weld seams.

Every builder returns a :class:`Workpiece`: an Open3D triangle mesh in metres in the workpiece frame
(z up, resting on z = 0, centred on the origin in x and y) and a list of :class:`SeamTruth`. Seams
are computed from the analytic geometry (never read back from the mesh), sampled densely along travel
(``seam_spacing``, 0.5 mm by default), with a nominal torch approach direction that points from free
space into the joint (the bisector of the two faces for fillet-like joints) and a unit travel direction.
The torch frame of a seam point is ``z = approach``, ``x = travel``, ``y = z × x`` (see
:meth:`SeamTruth.torch_frames`).

Builders (``WORKPIECES``): ``v-groove-butt``, ``fillet-t``, ``lap``, ``corner``, ``cylinder-on-plate``,
``y-pipe``. ``make_workpiece(kind, **params)`` builds one by name. See docs/simulated-cell.md.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import open3d as o3d
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid, transform_points, transform_vectors

JOINTS = ("butt", "fillet", "lap", "corner", "saddle", "pipe-junction")
SEAM_SPACING = 0.0005
"""Default distance (m) between consecutive ground-truth seam points."""


def rad(deg: float) -> float:
    """Degrees to radians (for readable defaults)."""
    return math.radians(deg)


# --------------------------------------------------------------------------------------------------
# Seams and workpieces
# --------------------------------------------------------------------------------------------------


def _unit_rows(v: np.ndarray, what: str) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    if np.any(n < 1e-12) or not np.all(np.isfinite(v)):
        raise DataError(f"seam {what} has zero-length or non-finite vectors", "give unit direction vectors")
    return v / n


@dataclass
class SeamTruth:
    """A ground-truth seam: points (K, 3) ordered along travel, unit approach and travel (K, 3).

    ``closed`` seams are loops: the last point connects back to the first (the first point is not
    repeated). ``approach`` points from free space toward the work (torch z); ``travel`` is torch x.
    """

    id: str
    joint: str
    points: np.ndarray
    approach: np.ndarray
    travel: np.ndarray
    closed: bool = False

    def __post_init__(self) -> None:
        if self.joint not in JOINTS:
            raise DataError(
                f"seam '{self.id}': unknown joint '{self.joint}'", f"use one of {', '.join(JOINTS)}"
            )
        self.points = np.asarray(self.points, dtype=float).reshape(-1, 3)
        k = len(self.points)
        if k < 2:
            raise DataError(
                f"seam '{self.id}' has {k} points; at least 2 are needed", "sample the seam densely"
            )
        for name in ("approach", "travel"):
            v = np.asarray(getattr(self, name), dtype=float).reshape(-1, 3)
            if len(v) != k:
                raise DataError(
                    f"seam '{self.id}' has {k} points but {len(v)} {name} vectors", "give one per point"
                )
            setattr(self, name, _unit_rows(v, name))

    def __len__(self) -> int:
        return len(self.points)

    @property
    def length(self) -> float:
        """Length of the seam (m), including the closing segment of a loop."""
        return float(self.segment_lengths().sum())

    def segment_lengths(self) -> np.ndarray:
        """Distances between consecutive points (and last→first for a closed seam)."""
        p = np.vstack([self.points, self.points[:1]]) if self.closed else self.points
        return np.linalg.norm(np.diff(p, axis=0), axis=1)

    def transformed(self, T: np.ndarray) -> SeamTruth:
        """This seam mapped by ``T`` (``T_new_old``)."""
        return replace(
            self,
            points=transform_points(T, self.points),
            approach=transform_vectors(T, self.approach),
            travel=transform_vectors(T, self.travel),
        )

    def torch_frames(self) -> np.ndarray:
        """(K, 4, 4) torch frames: z = approach, x = travel orthogonalised, y = z × x, origin = point."""
        z = self.approach
        x = self.travel - np.sum(self.travel * z, axis=1, keepdims=True) * z
        x = _unit_rows(x, "travel (orthogonal to approach)")
        y = np.cross(z, x)
        T = np.zeros((len(self), 4, 4))
        T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = x, y, z, self.points
        T[:, 3, 3] = 1.0
        return T


@dataclass
class Workpiece:
    """A workpiece mesh (workpiece frame, metres) with its ground-truth seams and where it is placed."""

    name: str
    kind: str
    mesh: o3d.geometry.TriangleMesh
    seams: list[SeamTruth]
    params: dict = field(default_factory=dict)
    T_world_workpiece: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        self.T_world_workpiece = _check_T(self.T_world_workpiece, "T_world_workpiece")

    def placed(self, T_world_workpiece: np.ndarray) -> Workpiece:
        """A new workpiece, the same part placed at ``T_world_workpiece`` (the mesh is copied)."""
        return Workpiece(
            self.name,
            self.kind,
            o3d.geometry.TriangleMesh(self.mesh),
            list(self.seams),
            dict(self.params),
            _check_T(T_world_workpiece, "T_world_workpiece"),
        )

    def mesh_in_world(self) -> o3d.geometry.TriangleMesh:
        """A copy of the mesh transformed into the world frame."""
        m = o3d.geometry.TriangleMesh(self.mesh)
        m.transform(self.T_world_workpiece)
        return m

    def seams_in_world(self) -> list[SeamTruth]:
        """The seams transformed into the world frame."""
        return [s.transformed(self.T_world_workpiece) for s in self.seams]

    def seam(self, seam_id: str) -> SeamTruth:
        """The seam called ``seam_id`` (workpiece frame)."""
        for s in self.seams:
            if s.id == seam_id:
                return s
        raise DataError(
            f"workpiece '{self.name}' has no seam '{seam_id}'",
            f"use one of {', '.join(s.id for s in self.seams)}",
        )

    def sample_surface(
        self, n: int, rng: np.random.Generator | int | None = None, frame: str = "world"
    ) -> PointCloud:
        """``n`` points sampled uniformly by area on the surface, with face normals, in ``frame``
        ('world' or 'workpiece')."""
        if frame not in ("world", "workpiece"):
            raise DataError(f"unknown frame '{frame}'", "use 'world' or 'workpiece'")
        if n < 1:
            raise DataError(f"cannot sample {n} points", "ask for at least one point")
        rng = np.random.default_rng(rng)
        V = np.asarray(self.mesh.vertices)
        F = np.asarray(self.mesh.triangles)
        a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        cr = np.cross(b - a, c - a)
        area = np.linalg.norm(cr, axis=1)
        idx = rng.choice(len(F), size=n, p=area / area.sum())
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        w0, w1, w2 = 1.0 - s, s * (1.0 - r2), s * r2
        pts = w0[:, None] * a[idx] + w1[:, None] * b[idx] + w2[:, None] * c[idx]
        nrm = cr[idx] / np.maximum(area[idx], 1e-300)[:, None]
        cloud = PointCloud(pts, normals=nrm, frame="workpiece", meta={"workpiece": self.name})
        if frame == "world":
            cloud = cloud.transformed(self.T_world_workpiece, frame="world")
        return cloud


def _check_T(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if not is_rigid(T):
        raise DataError(
            f"{what} is not a rigid 4x4 transform", "give a 4x4 matrix with an orthonormal rotation"
        )
    return T.copy()


# --------------------------------------------------------------------------------------------------
# Mesh helpers
# --------------------------------------------------------------------------------------------------


def _mesh(V: np.ndarray, F: np.ndarray) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.ascontiguousarray(V, dtype=float)),
        o3d.utility.Vector3iVector(np.ascontiguousarray(F, dtype=np.int32)),
    )
    m.compute_triangle_normals()
    m.compute_vertex_normals()
    return m


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    Vs, Fs, off = [], [], 0
    for V, F in parts:
        Vs.append(V)
        Fs.append(F + off)
        off += len(V)
    return np.vstack(Vs), np.vstack(Fs)


def _ear_clip(poly: np.ndarray) -> np.ndarray:
    """Triangulate a simple counter-clockwise polygon (M, 2); triangles are counter-clockwise."""
    idx = list(range(len(poly)))
    tris = []

    def cross(o, a, b) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3 and guard < 10000:
        guard += 1
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if cross(a, b, c) <= 1e-15:
                continue  # reflex or degenerate corner
            inside = False
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                p = poly[j]
                if cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0:
                    inside = True
                    break
            if not inside:
                tris.append((i0, i1, i2))
                idx.pop(k)
                break
        else:  # pragma: no cover - only for non-simple polygons
            raise DataError("cross-section polygon is not simple", "check the workpiece parameters")
    tris.append(tuple(idx))
    return np.array(tris, dtype=np.int64)


def _extrude(poly_yz: np.ndarray, x0: float, x1: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed prism: a counter-clockwise (y, z) polygon extruded along x from x0 to x1, faces outward."""
    P = np.asarray(poly_yz, dtype=float)
    m = len(P)
    V = np.vstack([np.column_stack([np.full(m, x0), P]), np.column_stack([np.full(m, x1), P])])
    i = np.arange(m)
    j = (i + 1) % m
    # side quad (x0,p_i) (x0,p_j) (x1,p_j) (x1,p_i): normal (0, dz, -dy) = outward for a CCW polygon
    sides = np.vstack([np.column_stack([i, j, m + j]), np.column_stack([i, m + j, m + i])])
    cap = _ear_clip(P)  # CCW in (y, z) -> normal +x
    F = np.vstack([sides, cap[:, [0, 2, 1]], cap + m])
    return V, F


def _orient(V: np.ndarray, F: np.ndarray, outward: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Flip triangles whose normal points against ``outward(centroids)``."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    flip = np.sum(n * outward((a + b + c) / 3.0), axis=1) < 0
    F = F.copy()
    F[flip] = F[flip][:, [0, 2, 1]]
    return F


def _disc(center: np.ndarray, ring: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fan of triangles closing a ring of vertices (M, 3) around ``center``, facing ``normal``."""
    m = len(ring)
    V = np.vstack([center[None], ring])
    i = np.arange(m)
    F = np.column_stack([np.zeros(m, dtype=np.int64), 1 + i, 1 + (i + 1) % m])
    F = _orient(V, F, lambda c: np.broadcast_to(normal, c.shape))
    return V, F


def _line_seam(seam_id: str, joint: str, p0, p1, approach, spacing: float) -> SeamTruth:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    k = int(math.ceil(np.linalg.norm(p1 - p0) / spacing)) + 1
    s = np.linspace(0.0, 1.0, k)[:, None]
    pts = p0 + s * (p1 - p0)
    travel = np.broadcast_to((p1 - p0) / np.linalg.norm(p1 - p0), pts.shape)
    return SeamTruth(seam_id, joint, pts, np.broadcast_to(np.asarray(approach, float), pts.shape), travel)


def _segments(circumference: float, max_sagitta: float = 1e-5, minimum: int = 64) -> int:
    """Number of polygon sides so the chord sagitta of a circle stays below ``max_sagitta``."""
    r = circumference / (2 * math.pi)
    return max(minimum, int(math.ceil(math.pi / math.acos(max(1.0 - max_sagitta / r, -1.0)))))


# --------------------------------------------------------------------------------------------------
# Argument checks
# --------------------------------------------------------------------------------------------------


def _positive(kind: str, **values: float) -> None:
    for name, v in values.items():
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise DataError(
                f"{kind}: {name} must be a positive length in metres, got {v!r}", f"give {name} > 0"
            )


def _nonnegative(kind: str, **values: float) -> None:
    for name, v in values.items():
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise DataError(f"{kind}: {name} must be >= 0 (metres), got {v!r}", f"give {name} >= 0")


def _check_spacing(kind: str, seam_spacing: float) -> None:
    _positive(kind, seam_spacing=seam_spacing)
    if seam_spacing > 0.001:
        raise DataError(
            f"{kind}: seam_spacing {seam_spacing * 1e3:.3g} mm is coarser than 1 mm",
            "give seam_spacing <= 0.001 (m)",
        )


def _require(ok: bool, message: str, fix: str) -> None:
    if not ok:
        raise DataError(message, fix)


# --------------------------------------------------------------------------------------------------
# Builders
# --------------------------------------------------------------------------------------------------


def v_groove_butt(
    length: float = 0.5,
    width: float = 0.15,
    thickness: float = 0.01,
    bevel_angle: float = rad(30),
    root_gap: float = 0.001,
    root_face: float = 0.001,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """Two plates butted along x with a single-V groove on top.

    ``width`` is the width of the whole assembly (each plate ``(width - root_gap) / 2``),
    ``bevel_angle`` the bevel of each plate from the vertical (the included angle is twice that),
    ``root_gap`` the opening between the plates and ``root_face`` the height of the unbevelled land.
    Seam ``groove``: the centre of the root opening at the top of the root faces (y = 0, z = root_face)
    along +x, approach straight down (-z). With a root gap the seam is ``root_gap / 2`` from either
    root face (it lies in the opening, where the root pass is aimed).
    """
    kind = "v-groove-butt"
    _positive(kind, length=length, width=width, thickness=thickness, bevel_angle=bevel_angle)
    _nonnegative(kind, root_gap=root_gap, root_face=root_face)
    _check_spacing(kind, seam_spacing)
    _require(
        bevel_angle < rad(80),
        f"{kind}: bevel_angle {math.degrees(bevel_angle):.3g}° is too wide",
        "give bevel_angle in radians below rad(80) (it is per side, from the vertical)",
    )
    _require(
        root_face < thickness,
        f"{kind}: root_face {root_face * 1e3:.3g} mm is not below thickness {thickness * 1e3:.3g} mm",
        "give root_face < thickness",
    )
    g2 = root_gap / 2
    top = g2 + (thickness - root_face) * math.tan(bevel_angle)
    _require(
        top < width / 2,
        f"{kind}: the groove ({2 * top * 1e3:.3g} mm wide at the top) does not fit in width "
        f"{width * 1e3:.3g} mm",
        "increase width or reduce root_gap / bevel_angle",
    )
    left = np.array(
        [[-width / 2, 0], [-g2, 0], [-g2, root_face], [-top, thickness], [-width / 2, thickness]], dtype=float
    )
    right = left[::-1] * np.array([-1.0, 1.0])  # mirror in y, reverse to stay counter-clockwise
    V, F = _merge([_extrude(left, -length / 2, length / 2), _extrude(right, -length / 2, length / 2)])
    seam = _line_seam(
        "groove", "butt", [-length / 2, 0, root_face], [length / 2, 0, root_face], [0, 0, -1], seam_spacing
    )
    params = dict(
        length=length,
        width=width,
        thickness=thickness,
        bevel_angle=bevel_angle,
        root_gap=root_gap,
        root_face=root_face,
        seam_spacing=seam_spacing,
    )
    return Workpiece(kind, kind, _mesh(V, F), [seam], params)


def fillet_t(
    length: float = 0.3,
    base_width: float = 0.2,
    web_height: float = 0.1,
    thickness: float = 0.01,
    web_thickness: float | None = None,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """A T joint: a web (``web_thickness``, default ``thickness``) standing centred on a base plate.

    Seams ``fillet-1`` (the +y side of the web) and ``fillet-2`` (the -y side), both along +x, at the
    corner between the web face and the base top; approach bisects the two faces, pointing into the
    corner: (0, -1, -1)/√2 and (0, +1, -1)/√2.
    """
    kind = "fillet-t"
    tw = thickness if web_thickness is None else web_thickness
    _positive(
        kind,
        length=length,
        base_width=base_width,
        web_height=web_height,
        thickness=thickness,
        web_thickness=tw,
    )
    _check_spacing(kind, seam_spacing)
    _require(
        tw < base_width,
        f"{kind}: web_thickness {tw * 1e3:.3g} mm does not fit on base_width {base_width * 1e3:.3g} mm",
        "give web_thickness < base_width",
    )
    b, t, h = base_width / 2, thickness, web_height
    poly = np.array(
        [[-b, 0], [b, 0], [b, t], [tw / 2, t], [tw / 2, t + h], [-tw / 2, t + h], [-tw / 2, t], [-b, t]],
        dtype=float,
    )
    V, F = _extrude(poly, -length / 2, length / 2)
    s2 = 1 / math.sqrt(2)
    seams = [
        _line_seam(
            "fillet-1",
            "fillet",
            [-length / 2, tw / 2, t],
            [length / 2, tw / 2, t],
            [0, -s2, -s2],
            seam_spacing,
        ),
        _line_seam(
            "fillet-2",
            "fillet",
            [-length / 2, -tw / 2, t],
            [length / 2, -tw / 2, t],
            [0, s2, -s2],
            seam_spacing,
        ),
    ]
    params = dict(
        length=length,
        base_width=base_width,
        web_height=web_height,
        thickness=thickness,
        web_thickness=tw,
        seam_spacing=seam_spacing,
    )
    return Workpiece(kind, kind, _mesh(V, F), seams, params)


def lap(
    length: float = 0.3,
    width: float = 0.15,
    thickness: float = 0.006,
    overlap: float = 0.04,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """A lap joint: an upper plate (+y side) lying on a lower plate (-y side), overlapping by ``overlap``.

    Both plates are ``width`` wide and ``thickness`` thick; the assembly is centred on y = 0, so the
    upper plate's edge is at y = -overlap/2. Seam ``lap``: that edge against the lower plate's top
    surface (z = thickness), along +x; approach bisects the edge face and the lower top: (0, 1, -1)/√2.
    """
    kind = "lap"
    _positive(kind, length=length, width=width, thickness=thickness, overlap=overlap)
    _check_spacing(kind, seam_spacing)
    _require(
        overlap < width,
        f"{kind}: overlap {overlap * 1e3:.3g} mm is not less than the plate width {width * 1e3:.3g} mm",
        "give overlap < width",
    )
    total = 2 * width - overlap
    yl0, yl1 = -total / 2, -total / 2 + width
    yu0, yu1 = total / 2 - width, total / 2
    t = thickness
    poly = np.array(
        [[yl0, 0], [yl1, 0], [yl1, t], [yu1, t], [yu1, 2 * t], [yu0, 2 * t], [yu0, t], [yl0, t]], dtype=float
    )
    V, F = _extrude(poly, -length / 2, length / 2)
    s2 = 1 / math.sqrt(2)
    seam = _line_seam("lap", "lap", [-length / 2, yu0, t], [length / 2, yu0, t], [0, s2, -s2], seam_spacing)
    params = dict(length=length, width=width, thickness=thickness, overlap=overlap, seam_spacing=seam_spacing)
    return Workpiece(kind, kind, _mesh(V, F), [seam], params)


def corner(
    length: float = 0.3,
    width: float = 0.15,
    thickness: float = 0.01,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """An outside corner joint (full-open corner): two plates at 90° touching along one edge.

    In the L's own section one plate lies flat and the other hangs from it; their edge faces leave a
    90° V-shaped notch on the outside of the corner. The L is turned 45° about x so the notch opens
    upward (flat welding position): the plates form a roof resting on their far edges on z = 0.
    Seam ``corner``: the bottom of the notch (where the plates touch), along +x, approach -z (the
    bisector of the two edge faces).
    """
    kind = "corner"
    _positive(kind, length=length, width=width, thickness=thickness)
    _check_spacing(kind, seam_spacing)
    _require(
        thickness < width,
        f"{kind}: thickness {thickness * 1e3:.3g} mm is not less than width {width * 1e3:.3g} mm",
        "give thickness < width",
    )
    w, t = width, thickness
    plate_h = np.array([[0, -t], [w, -t], [w, 0], [0, 0]], dtype=float)  # (u, v), counter-clockwise
    plate_v = np.array([[-t, -t - w], [0, -t - w], [0, -t], [-t, -t]], dtype=float)
    corner_uv = np.array([0.0, -t])
    a = rad(-45)
    Rm = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])

    def to_yz(p: np.ndarray) -> np.ndarray:
        return (p - corner_uv) @ Rm.T  # rotation keeps counter-clockwise order

    ph, pv = to_yz(plate_h), to_yz(plate_v)
    z0 = min(ph[:, 1].min(), pv[:, 1].min())
    shift = np.array([0.0, -z0])
    V, F = _merge(
        [_extrude(ph + shift, -length / 2, length / 2), _extrude(pv + shift, -length / 2, length / 2)]
    )
    zc = shift[1]
    seam = _line_seam("corner", "corner", [-length / 2, 0, zc], [length / 2, 0, zc], [0, 0, -1], seam_spacing)
    params = dict(length=length, width=width, thickness=thickness, seam_spacing=seam_spacing)
    return Workpiece(kind, kind, _mesh(V, F), [seam], params)


def _cylinder_z(radius: float, z0: float, z1: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder wall about the z axis between z0 and z1 with a top cap (open at the bottom), outward.

    The bottom ring (the first ``n`` vertices) is left open so it can be stitched to a hole.
    """
    phi = 2 * np.pi * np.arange(n) / n
    ring = np.column_stack([radius * np.cos(phi), radius * np.sin(phi)])
    V = np.vstack([np.column_stack([ring, np.full(n, z0)]), np.column_stack([ring, np.full(n, z1)])])
    i = np.arange(n)
    j = (i + 1) % n
    F = np.vstack([np.column_stack([i, j, n + j]), np.column_stack([i, n + j, n + i])])
    F = _orient(V, F, lambda c: np.column_stack([c[:, 0], c[:, 1], np.zeros(len(c))]))
    top = _disc(np.array([0, 0, z1]), V[n:], np.array([0, 0, 1.0]))
    return _merge([(V, F), top])


def _plate_with_hole(half: float, t: float, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Square plate (side 2 ``half``, z in [0, t]) whose top face has a hole bounded by ``ring`` (M, 2)."""
    from scipy.spatial import Delaunay

    box = np.array([[-half, 0], [half, 0], [half, t], [-half, t]], dtype=float)
    V, F = _extrude(box, -half, half)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    is_top = np.isclose(a[:, 2], t) & np.isclose(b[:, 2], t) & np.isclose(c[:, 2], t)
    F = F[~is_top]
    # top face: the square's corners (shared with the sides: no T-junctions) around the ring
    square = np.array([[-half, -half], [half, -half], [half, half], [-half, half]], dtype=float)
    uv = np.vstack([ring, square])
    tri = Delaunay(uv).simplices
    tri = tri[np.any(tri >= len(ring), axis=1)]  # triangles of ring vertices only fill the (convex) hole
    Vt = np.column_stack([uv, np.full(len(uv), t)])
    Ft = _orient(Vt, tri, lambda c: np.broadcast_to(np.array([0, 0, 1.0]), c.shape))
    return _merge([(V, F), (Vt, Ft)])


def cylinder_on_plate(
    radius: float = 0.05,
    height: float = 0.12,
    plate: float = 0.3,
    thickness: float = 0.01,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """A closed cylinder (tube end capped) standing on the centre of a square plate (``plate`` a side).

    Seam ``saddle``: the closed circle where the cylinder wall meets the plate top (radius ``radius``,
    z = ``thickness``). It starts at (radius, 0, thickness) and travels counter-clockwise seen from
    above (+φ); approach bisects the wall and the plate: (-cos φ, -sin φ, -1)/√2.
    """
    kind = "cylinder-on-plate"
    _positive(kind, radius=radius, height=height, plate=plate, thickness=thickness)
    _check_spacing(kind, seam_spacing)
    _require(
        2 * radius < plate,
        f"{kind}: a cylinder of diameter {2 * radius * 1e3:.3g} mm does not fit on a "
        f"{plate * 1e3:.3g} mm plate",
        "give radius < plate / 2",
    )
    t = thickness
    n = _segments(2 * math.pi * radius)
    Vc, Fc = _cylinder_z(radius, t, t + height, n)
    V, F = _merge([_plate_with_hole(plate / 2, t, Vc[:n, :2]), (Vc, Fc)])
    mesh = _mesh(V, F)
    mesh.merge_close_vertices(1e-9)
    mesh.remove_duplicated_vertices()
    mesh.compute_triangle_normals()
    mesh.compute_vertex_normals()
    k = int(math.ceil(2 * math.pi * radius / seam_spacing))
    phi = 2 * np.pi * np.arange(k) / k
    c, s = np.cos(phi), np.sin(phi)
    pts = np.column_stack([radius * c, radius * s, np.full(k, t)])
    approach = np.column_stack([-c, -s, -np.ones(k)]) / math.sqrt(2)
    travel = np.column_stack([-s, c, np.zeros(k)])
    seam = SeamTruth("saddle", "saddle", pts, approach, travel, closed=True)
    params = dict(
        radius=radius,
        height=height,
        plate=plate,
        thickness=thickness,
        seam_spacing=seam_spacing,
        seam_start=pts[0].tolist(),
        seam_travel=travel[0].tolist(),
    )
    return Workpiece(kind, kind, mesh, [seam], params)


@dataclass(frozen=True)
class _YPipeGeometry:
    """Analytic junction of a main cylinder (axis x through (0, 0, R)) and a branch (axis b through it)."""

    R: float
    r: float
    beta: float

    @property
    def b(self) -> np.ndarray:
        return np.array([math.cos(self.beta), 0.0, math.sin(self.beta)])

    @property
    def e1(self) -> np.ndarray:
        return np.array([0.0, 1.0, 0.0])

    @property
    def e2(self) -> np.ndarray:
        return np.array([-math.sin(self.beta), 0.0, math.cos(self.beta)])

    def s_of(self, theta: np.ndarray) -> np.ndarray:
        """Distance along the branch axis where its generator at angle θ enters the main pipe.

        On the branch surface p = s b + r (cos θ e1 + sin θ e2) (relative to the axis point); it meets
        the main cylinder y² + z² = R² where s sin β + r sin θ cos β = +sqrt(R² - r² cos² θ).
        """
        R, r, be = self.R, self.r, self.beta
        return (np.sqrt(R**2 - (r * np.cos(theta)) ** 2) - r * np.sin(theta) * math.cos(be)) / math.sin(be)

    def ds_of(self, theta: np.ndarray) -> np.ndarray:
        R, r, be = self.R, self.r, self.beta
        c, s = np.cos(theta), np.sin(theta)
        return ((r**2 * c * s) / np.sqrt(R**2 - (r * c) ** 2) - r * c * math.cos(be)) / math.sin(be)

    def branch_point(self, theta: np.ndarray, s: np.ndarray) -> np.ndarray:
        radial = np.outer(np.cos(theta), self.e1) + np.outer(np.sin(theta), self.e2)
        return np.asarray(s)[..., None] * self.b + self.r * radial

    def curve(self, theta: np.ndarray) -> np.ndarray:
        return self.branch_point(theta, self.s_of(theta))

    def curve_tangent(self, theta: np.ndarray) -> np.ndarray:
        d = np.outer(self.ds_of(theta), self.b) + self.r * (
            np.outer(-np.sin(theta), self.e1) + np.outer(np.cos(theta), self.e2)
        )
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def resample(self, spacing: float) -> np.ndarray:
        """Angles θ that space the intersection curve evenly by arc length (<= ``spacing``)."""
        dense = np.linspace(0.0, 2 * np.pi, 20001)
        p = self.curve(dense)
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        k = int(math.ceil(cum[-1] / spacing))
        return np.interp(np.linspace(0.0, cum[-1], k, endpoint=False), cum, dense)


def y_pipe(
    radius: float = 0.04,
    branch_radius: float = 0.03,
    branch_angle: float = rad(45),
    length: float = 0.4,
    branch_length: float | None = None,
    mesh_resolution: float = 0.002,
    seam_spacing: float = SEAM_SPACING,
) -> Workpiece:
    """A main pipe lying along x (resting on z = 0, axis at z = ``radius``) with a branch pipe joined at
    ``branch_angle`` to the main axis (leaning toward +x, rising in +z; the axes meet at the origin's
    vertical above the centre).

    The surface is the boundary of the union of the two solid cylinders: the main pipe has a hole where
    the branch enters, the branch is trimmed exactly at the intersection curve, and both share the seam
    vertices, so the junction is a real concave groove. ``branch_length`` (default ``length / 2``) is
    measured along the branch axis from the main axis; ``mesh_resolution`` is the main-pipe triangle
    size. Seam ``junction`` (joint ``pipe-junction``, closed): the analytic intersection curve, from the
    branch generator on the +y flank (θ = 0) with increasing θ; approach = -(n_main + n_branch)
    normalised, the bisector of the two surface normals pointing into the groove.
    """
    kind = "y-pipe"
    branch_length = length / 2 if branch_length is None else branch_length
    _positive(
        kind,
        radius=radius,
        branch_radius=branch_radius,
        branch_angle=branch_angle,
        length=length,
        branch_length=branch_length,
        mesh_resolution=mesh_resolution,
    )
    _check_spacing(kind, seam_spacing)
    _require(
        branch_radius < 0.98 * radius,
        f"{kind}: branch_radius {branch_radius * 1e3:.3g} mm must be below the main radius "
        f"{radius * 1e3:.3g} mm (equal radii give a tangent, unweldable junction)",
        "give branch_radius < 0.98 * radius",
    )
    _require(
        rad(20) <= branch_angle <= rad(90),
        f"{kind}: branch_angle {math.degrees(branch_angle):.3g}° is outside 20°..90°",
        "give branch_angle in radians between rad(20) and rad(90)",
    )
    _require(
        mesh_resolution <= radius / 4,
        f"{kind}: mesh_resolution {mesh_resolution * 1e3:.3g} mm is too coarse for radius "
        f"{radius * 1e3:.3g} mm",
        "give mesh_resolution <= radius / 4",
    )
    g = _YPipeGeometry(radius, branch_radius, branch_angle)
    R, r = radius, branch_radius
    axis0 = np.array([0.0, 0.0, R])
    s_max = float(g.s_of(np.linspace(0, 2 * np.pi, 721)).max())
    _require(
        branch_length > s_max + r,
        f"{kind}: branch_length {branch_length * 1e3:.3g} mm does not reach out of the main pipe "
        f"(needs > {(s_max + r) * 1e3:.3g} mm)",
        "increase branch_length or branch_angle",
    )
    theta = g.resample(seam_spacing)
    curve = g.curve(theta)  # relative to axis0
    _require(
        np.abs(curve[:, 0]).max() < length / 2 - 2 * mesh_resolution,
        f"{kind}: the junction spans x = ±{np.abs(curve[:, 0]).max() * 1e3:.3g} mm, beyond the main pipe "
        f"(length {length * 1e3:.3g} mm)",
        "increase length or branch_angle, or reduce branch_radius",
    )

    # main pipe: Delaunay in the unrolled (x, arc) plane, hole bounded exactly by the seam curve
    from matplotlib.path import Path as MplPath
    from scipy.spatial import Delaunay, cKDTree

    n_arc = int(math.ceil(2 * math.pi * R / mesh_resolution))
    n_x = int(math.ceil(length / mesh_resolution)) + 1
    xs = np.linspace(-length / 2, length / 2, n_x)
    phis = np.linspace(-np.pi / 2, 3 * np.pi / 2, n_arc + 1)
    gx, gp = np.meshgrid(xs, phis, indexing="ij")
    grid = np.column_stack([gx.ravel(), R * gp.ravel()])
    hole = np.column_stack([curve[:, 0], R * np.arctan2(curve[:, 2], curve[:, 1])])
    hole_path = MplPath(hole)
    near = cKDTree(hole).query(grid, k=1)[0] < 0.6 * mesh_resolution
    keep = ~(hole_path.contains_points(grid) | near)
    uv = np.vstack([grid[keep], hole])
    tri = Delaunay(uv).simplices
    cent = uv[tri].mean(axis=1)
    tri = tri[~hole_path.contains_points(cent)]
    phi = uv[:, 1] / R
    Vm = np.column_stack([uv[:, 0], R * np.cos(phi), R + R * np.sin(phi)])
    Fm = _orient(Vm, tri, lambda c: np.column_stack([np.zeros(len(c)), c[:, 1], c[:, 2] - R]))
    ring_phi = phis[:-1]
    caps = [
        _disc(
            np.array([x, 0, R]),
            np.column_stack([np.full(n_arc, x), R * np.cos(ring_phi), R + R * np.sin(ring_phi)]),
            np.array([np.sign(x), 0, 0.0]),
        )
        for x in (-length / 2, length / 2)
    ]

    # branch: ruled quads from the seam curve out to the end cap (parallel generators -> exact planes)
    k = len(theta)
    m = max(1, int(math.ceil((branch_length - float(g.s_of(theta).min())) / 0.02)))
    s0 = g.s_of(theta)
    frac = np.linspace(0.0, 1.0, m + 1)
    S = s0[None, :] + frac[:, None] * (branch_length - s0[None, :])  # (m+1, k)
    Vb = (g.branch_point(np.tile(theta, m + 1), S.ravel()) + axis0).reshape(-1, 3)
    Vb[:k] = curve + axis0  # identical to the hole boundary
    i = np.arange(k)
    j = (i + 1) % k
    Fb = np.vstack(
        [
            np.vstack(
                [
                    np.column_stack([a * k + i, a * k + j, (a + 1) * k + j]),
                    np.column_stack([a * k + i, (a + 1) * k + j, (a + 1) * k + i]),
                ]
            )
            for a in range(m)
        ]
    )
    b_axis = g.b

    def branch_out(c: np.ndarray) -> np.ndarray:
        rel = c - axis0
        return rel - np.outer(rel @ b_axis, b_axis)

    Fb = _orient(Vb, Fb, branch_out)
    cap_b = _disc(axis0 + branch_length * b_axis, Vb[m * k :], b_axis)

    V, F = _merge([(Vm, Fm), *caps, (Vb, Fb), cap_b])
    mesh = _mesh(V, F)
    mesh.merge_close_vertices(1e-9)
    mesh.remove_duplicated_vertices()
    mesh.remove_degenerate_triangles()
    mesh.compute_triangle_normals()
    mesh.compute_vertex_normals()

    n_main = curve / np.linalg.norm(curve * np.array([0, 1, 1]), axis=1, keepdims=True) * np.array([0, 1, 1])
    n_branch = np.outer(np.cos(theta), g.e1) + np.outer(np.sin(theta), g.e2)
    approach = -(n_main + n_branch)
    seam = SeamTruth(
        "junction", "pipe-junction", curve + axis0, approach, g.curve_tangent(theta), closed=True
    )
    params = dict(
        radius=radius,
        branch_radius=branch_radius,
        branch_angle=branch_angle,
        length=length,
        branch_length=branch_length,
        mesh_resolution=mesh_resolution,
        seam_spacing=seam_spacing,
        seam_start=seam.points[0].tolist(),
        seam_travel=seam.travel[0].tolist(),
    )
    return Workpiece(kind, kind, mesh, [seam], params)


WORKPIECES: dict[str, Callable[..., Workpiece]] = {
    "v-groove-butt": v_groove_butt,
    "fillet-t": fillet_t,
    "lap": lap,
    "corner": corner,
    "cylinder-on-plate": cylinder_on_plate,
    "y-pipe": y_pipe,
}


def workpiece_parameters(kind: str) -> dict[str, object]:
    """The keyword parameters of a workpiece kind and their defaults (metres / radians)."""
    builder = _builder(kind)
    return {n: p.default for n, p in inspect.signature(builder).parameters.items()}


def _builder(kind: str) -> Callable[..., Workpiece]:
    key = str(kind).strip().lower().replace("_", "-")
    if key not in WORKPIECES:
        raise DataError(f"unknown workpiece kind '{kind}'", f"use one of {', '.join(WORKPIECES)}")
    return WORKPIECES[key]


def make_workpiece(kind: str, **params: float) -> Workpiece:
    """Build the workpiece ``kind`` (a key of ``WORKPIECES``) with the given keyword parameters."""
    builder = _builder(kind)
    valid = list(inspect.signature(builder).parameters)
    unknown = sorted(set(params) - set(valid))
    if unknown:
        raise DataError(
            f"workpiece '{kind}' has no parameter {', '.join(repr(u) for u in unknown)}",
            f"use only {', '.join(valid)} (metres / radians)",
        )
    return builder(**params)
