"""Workpieces with curved seams: a cylinder on a plate (saddle) and a Y-shaped pipe junction.

Both seams are computed from the analytic intersection of the surfaces; the meshes share the seam
vertices, so the junction is a real concave groove in the mesh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from weldcell.hal.sim.mesh_tools import (
    check_positive,
    check_spacing,
    circle_segments,
    extrude_yz,
    fan_disc,
    merge_parts,
    orient_faces,
    require,
    triangle_mesh,
)
from weldcell.hal.sim.workpiece_model import SEAM_SPACING, SeamTruth, Workpiece, rad

Parts = list[tuple[np.ndarray, np.ndarray]]
"""Mesh pieces as (vertices (V, 3), faces (F, 3)) pairs, merged by :func:`merge_parts`."""


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
    F = orient_faces(V, F, lambda c: np.column_stack([c[:, 0], c[:, 1], np.zeros(len(c))]))
    top = fan_disc(np.array([0, 0, z1]), V[n:], np.array([0, 0, 1.0]))
    return merge_parts([(V, F), top])


def _plate_with_hole(half: float, t: float, ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Square plate (side 2 ``half``, z in [0, t]) whose top face has a hole bounded by ``ring`` (M, 2)."""
    from scipy.spatial import Delaunay

    box = np.array([[-half, 0], [half, 0], [half, t], [-half, t]], dtype=float)
    V, F = extrude_yz(box, -half, half)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    is_top = np.isclose(a[:, 2], t) & np.isclose(b[:, 2], t) & np.isclose(c[:, 2], t)
    F = F[~is_top]
    # top face: the square's corners (shared with the sides: no T-junctions) around the ring
    square = np.array([[-half, -half], [half, -half], [half, half], [-half, half]], dtype=float)
    uv = np.vstack([ring, square])
    tri = Delaunay(uv).simplices
    tri = tri[np.any(tri >= len(ring), axis=1)]  # triangles of ring vertices only fill the (convex) hole
    Vt = np.column_stack([uv, np.full(len(uv), t)])
    Ft = orient_faces(Vt, tri, lambda c: np.broadcast_to(np.array([0, 0, 1.0]), c.shape))
    return merge_parts([(V, F), (Vt, Ft)])


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
    check_positive(kind, radius=radius, height=height, plate=plate, thickness=thickness)
    check_spacing(kind, seam_spacing)
    require(
        2 * radius < plate,
        f"{kind}: a cylinder of diameter {2 * radius * 1e3:.3g} mm does not fit on a "
        f"{plate * 1e3:.3g} mm plate",
        "give radius < plate / 2",
    )
    t = thickness
    n = circle_segments(2 * math.pi * radius)
    Vc, Fc = _cylinder_z(radius, t, t + height, n)
    V, F = merge_parts([_plate_with_hole(plate / 2, t, Vc[:n, :2]), (Vc, Fc)])
    mesh = triangle_mesh(V, F)
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
    _check_y_pipe(radius, branch_radius, branch_angle, length, branch_length, mesh_resolution, seam_spacing)
    g = _YPipeGeometry(radius, branch_radius, branch_angle)
    R, r = radius, branch_radius
    axis0 = np.array([0.0, 0.0, R])
    s_max = float(g.s_of(np.linspace(0, 2 * np.pi, 721)).max())
    require(
        branch_length > s_max + r,
        f"{kind}: branch_length {branch_length * 1e3:.3g} mm does not reach out of the main pipe "
        f"(needs > {(s_max + r) * 1e3:.3g} mm)",
        "increase branch_length or branch_angle",
    )
    theta = g.resample(seam_spacing)
    curve = g.curve(theta)  # relative to axis0
    require(
        np.abs(curve[:, 0]).max() < length / 2 - 2 * mesh_resolution,
        f"{kind}: the junction spans x = ±{np.abs(curve[:, 0]).max() * 1e3:.3g} mm, beyond the main pipe "
        f"(length {length * 1e3:.3g} mm)",
        "increase length or branch_angle, or reduce branch_radius",
    )
    main = _main_pipe_parts(R, length, mesh_resolution, curve)
    branch = _branch_parts(g, theta, curve, axis0, branch_length)
    V, F = merge_parts([*main, *branch])
    mesh = triangle_mesh(V, F)
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


def _check_y_pipe(
    radius: float,
    branch_radius: float,
    branch_angle: float,
    length: float,
    branch_length: float,
    mesh_resolution: float,
    seam_spacing: float,
) -> None:
    """The argument checks of :func:`y_pipe` that need no geometry."""
    kind = "y-pipe"
    check_positive(
        kind,
        radius=radius,
        branch_radius=branch_radius,
        branch_angle=branch_angle,
        length=length,
        branch_length=branch_length,
        mesh_resolution=mesh_resolution,
    )
    check_spacing(kind, seam_spacing)
    require(
        branch_radius < 0.98 * radius,
        f"{kind}: branch_radius {branch_radius * 1e3:.3g} mm must be below the main radius "
        f"{radius * 1e3:.3g} mm (equal radii give a tangent, unweldable junction)",
        "give branch_radius < 0.98 * radius",
    )
    require(
        rad(20) <= branch_angle <= rad(90),
        f"{kind}: branch_angle {math.degrees(branch_angle):.3g}° is outside 20°..90°",
        "give branch_angle in radians between rad(20) and rad(90)",
    )
    require(
        mesh_resolution <= radius / 4,
        f"{kind}: mesh_resolution {mesh_resolution * 1e3:.3g} mm is too coarse for radius "
        f"{radius * 1e3:.3g} mm",
        "give mesh_resolution <= radius / 4",
    )


def _main_pipe_parts(R: float, length: float, mesh_resolution: float, curve: np.ndarray) -> Parts:
    """The main pipe's wall with the hole bounded exactly by the seam ``curve`` (relative to the axis
    point), and its two end caps.

    Delaunay in the unrolled (x, arc) plane; grid points inside or near the hole are dropped.
    """
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
    Fm = orient_faces(Vm, tri, lambda c: np.column_stack([np.zeros(len(c)), c[:, 1], c[:, 2] - R]))
    ring_phi = phis[:-1]
    caps = [
        fan_disc(
            np.array([x, 0, R]),
            np.column_stack([np.full(n_arc, x), R * np.cos(ring_phi), R + R * np.sin(ring_phi)]),
            np.array([np.sign(x), 0, 0.0]),
        )
        for x in (-length / 2, length / 2)
    ]
    return [(Vm, Fm), *caps]


def _branch_parts(
    g: _YPipeGeometry, theta: np.ndarray, curve: np.ndarray, axis0: np.ndarray, branch_length: float
) -> Parts:
    """The branch wall as ruled quads from the seam curve out to its end cap, and the cap.

    Generators are parallel to the branch axis, so the quads are exact planes; the first ring of
    vertices is the seam curve itself, identical to the main pipe's hole boundary.
    """
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

    Fb = orient_faces(Vb, Fb, branch_out)
    cap_b = fan_disc(axis0 + branch_length * b_axis, Vb[m * k :], b_axis)
    return [(Vb, Fb), cap_b]
