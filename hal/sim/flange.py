"""Geometry of a simulated robot's tool flange and last link, for the depth cameras' ray-cast scene.

The tool flange is an ISO 9409-1 plate (pitch circle d1, centring hole d2, outer diameter d3, N tapped
holes d4 on d1 offset half a pitch from the positioning pin hole d5 on d1 at +x), modelled as real
geometry: the face annulus with its holes, the rim and hole walls, and a plate ``thickness`` deep.
Behind it sits the robot's last link, a cylinder wider than the plate whose end face closes the holes
(so the holes read as recesses, as on a real wrist). A segmentation must separate the flange face from
the link, as in a real scan (paper 003 §2.1.4).
The same plate on a pedestal is a fixed scene part (:func:`plate_workpiece`, kind ``iso9409-plate`` in
``[[sim.workpieces]]``): the feature a camera on the flange calibrates against (eye-in-hand).

Frames: the mesh lives in the flange frame (ISO 9409-1): origin at the face centre, z out of the face
(away from the robot), x toward the pin hole. Units: metres.

The ISO dimensions come from :mod:`weldcell.hal.iso9409` (nominal ISO 9409-1:2004 Table 1 values, the
one table shared with the hand-eye plugin's flange models). The link
diameters are approximate outer diameters of each arm's last wrist link (ASSUMED from product
drawings; only their being wider than the plate matters for the segmentation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from weldcell.hal.iso9409 import ISO9409_1, check_dimensions
from weldcell.hal.sim.workpieces import Workpiece
from weldcell.sdk.errors import DataError


@dataclass(frozen=True)
class FlangeGeometry:
    """An ISO 9409-1 flange plate and the last link behind it (metres)."""

    d1_mm: float = 50.0
    thickness: float = 0.006
    link_diameter: float = 0.090
    link_length: float = 0.12
    resolution: float = 0.0005
    dims_mm: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.dims_mm and float(self.d1_mm) not in ISO9409_1:
            raise DataError(
                f"no ISO 9409-1 flange with pitch circle {self.d1_mm} mm",
                f"use one of {sorted(ISO9409_1)} or give dims_mm (d1, d2, d3, d4, d5, n)",
            )
        if self.link_diameter <= self.outer_diameter:
            raise DataError(
                f"link diameter {self.link_diameter * 1e3:.1f} mm is not wider than the flange "
                f"({self.outer_diameter * 1e3:.1f} mm)",
                "give the wrist link's outer diameter",
            )
        if self.thickness <= 0 or self.link_length <= 0 or self.resolution <= 0:
            raise DataError(
                "flange thickness, link length and resolution must be > 0", "give positive lengths"
            )

    @property
    def dims(self) -> dict:
        """d1..d5 (m) and n."""
        if self.dims_mm:
            d = check_dimensions(self.dims_mm)
        else:
            d = {"d1": float(self.d1_mm), **ISO9409_1[float(self.d1_mm)]}
        return {**{k: float(d[k]) * 1e-3 for k in ("d1", "d2", "d3", "d4", "d5")}, "n": int(d["n"])}

    @property
    def outer_diameter(self) -> float:
        return self.dims["d3"]

    def holes(self) -> list[tuple[float, float, float]]:
        """(x, y, radius) of the tapped holes and the pin hole (at +x) on the pitch circle."""
        d = self.dims
        r = d["d1"] / 2
        ang = np.pi / d["n"] + 2 * np.pi * np.arange(d["n"]) / d["n"]
        out = [(r * np.cos(a), r * np.sin(a), d["d4"] / 2) for a in ang]
        out.append((r, 0.0, d["d5"] / 2))
        return out


#: robot model name -> its flange and last link (ASSUMED link diameters, see the module doc)
ROBOT_FLANGES: dict[str, FlangeGeometry] = {
    "ur5": FlangeGeometry(50.0, link_diameter=0.075),
    "ur10e": FlangeGeometry(50.0, link_diameter=0.090),
    "franka-panda": FlangeGeometry(50.0, link_diameter=0.080),
    "aubo-i5": FlangeGeometry(50.0, link_diameter=0.080),
    "abb-irb2600": FlangeGeometry(50.0, link_diameter=0.100),
}


def flange_for(model_name: str) -> FlangeGeometry:
    """The flange of a robot model (an ISO 50 plate on a 90 mm link for unknown names)."""
    return ROBOT_FLANGES.get(model_name, FlangeGeometry())


def _circle(cx: float, cy: float, r: float, step: float) -> np.ndarray:
    n = max(12, int(np.ceil(2 * np.pi * r / step)))
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([cx + r * np.cos(t), cy + r * np.sin(t)])


def _wall(ring: np.ndarray, z0: float, z1: float, offset: int) -> tuple[np.ndarray, np.ndarray]:
    """A vertical wall along a closed 2-D ring between heights z0 and z1."""
    n = len(ring)
    V = np.vstack([np.column_stack([ring, np.full(n, z0)]), np.column_stack([ring, np.full(n, z1)])])
    i = np.arange(n)
    j = (i + 1) % n
    F = np.vstack([np.column_stack([i, j, i + n]), np.column_stack([j, j + n, i + n])]) + offset
    return V, F


def _disc(r: float, z: float, step: float, offset: int) -> tuple[np.ndarray, np.ndarray]:
    ring = _circle(0.0, 0.0, r, step)
    V = np.vstack([[0.0, 0.0, z], np.column_stack([ring, np.full(len(ring), z)])])
    i = np.arange(len(ring))
    F = np.column_stack([np.zeros(len(ring), int), 1 + i, 1 + (i + 1) % len(ring)]) + offset
    return V, F


def _face(g: FlangeGeometry) -> tuple[np.ndarray, np.ndarray]:
    """The face annulus at z = 0 with its holes cut out (conforming Delaunay triangulation)."""
    from scipy.spatial import Delaunay

    d, step = g.dims, g.resolution
    r3, r2 = d["d3"] / 2, d["d2"] / 2
    holes = g.holes()
    rings = [_circle(0, 0, r3, step), _circle(0, 0, r2, step)] + [_circle(x, y, r, step) for x, y, r in holes]
    # interior points on a hexagonal grid, kept >= 2 boundary steps away from every boundary: the
    # dense boundary edges are then Gabriel edges, so the triangulation follows every circle
    h = 4 * step
    xs = np.arange(-r3, r3 + h, h)
    ys = np.arange(-r3, r3 + h, h * np.sqrt(3) / 2)
    X, Y = np.meshgrid(xs, ys)
    X = X + (np.arange(len(ys))[:, None] % 2) * h / 2
    grid = np.column_stack([X.ravel(), Y.ravel()])
    rho = np.linalg.norm(grid, axis=1)
    keep = (rho < r3 - 2 * step) & (rho > r2 + 2 * step)
    for x, y, r in holes:
        keep &= np.hypot(grid[:, 0] - x, grid[:, 1] - y) > r + 2 * step
    pts = np.vstack(rings + [grid[keep]])
    tri = Delaunay(pts).simplices
    c = pts[tri].mean(axis=1)
    rc = np.linalg.norm(c, axis=1)
    inside = (rc < r3) & (rc > r2)
    for x, y, r in holes:
        inside &= np.hypot(c[:, 0] - x, c[:, 1] - y) > r
    return np.column_stack([pts, np.zeros(len(pts))]), tri[inside]


def flange_mesh(g: FlangeGeometry | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (N, 3, flange frame, m) and triangles (M, 3) of the flange plate and the last link."""
    g = g or FlangeGeometry()
    d, step, t = g.dims, g.resolution, g.thickness
    parts = [_face(g)]

    def add(fn, *args) -> None:
        off = sum(len(V) for V, _ in parts)
        parts.append(fn(*args, off))

    add(_wall, _circle(0, 0, d["d3"] / 2, step), 0.0, -t)  # rim wall
    add(_wall, _circle(0, 0, d["d2"] / 2, step), 0.0, -t)  # centring hole wall
    for x, y, r in g.holes():
        add(_wall, _circle(x, y, r, step), 0.0, -t)
    rl = g.link_diameter / 2
    coarse = max(step, 0.002)
    add(_disc, rl, -t, coarse)  # the link's end face: floor of the holes, ring around the plate
    add(_wall, _circle(0, 0, rl, coarse), -t, -t - g.link_length)
    add(_disc, rl, -t - g.link_length, coarse)
    V = np.vstack([p[0] for p in parts])
    F = np.vstack([p[1] for p in parts]).astype(np.int64)
    return V, F


def posed_mesh(V: np.ndarray, F: np.ndarray, T_world_frame: np.ndarray):
    """An open3d tensor TriangleMesh of (V, F) placed by ``T_world_frame``."""
    import open3d as o3d

    T = np.asarray(T_world_frame, dtype=float)
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(
        np.ascontiguousarray(V @ T[:3, :3].T + T[:3, 3], dtype=np.float32)
    )
    mesh.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(F, dtype=np.int32))
    return mesh


def plate_workpiece(
    d1: float = 50.0, thickness: float = 0.012, pedestal_diameter: float = 0.1, pedestal_height: float = 0.1
) -> Workpiece:
    """A fixed ISO 9409-1 flange plate (pitch circle ``d1`` mm, with its holes) on a cylindrical
    pedestal ``pedestal_height`` high and wider than the plate, as a scene part without seams (the
    feature an eye-in-hand calibration looks at, paper 003 Fig. 14a). Its frame is the ISO flange
    frame (origin at the face centre, z out of the face, x toward the pin hole); place it with the
    [[sim.workpieces]] ``xyz``/``rpy`` of the face centre."""
    import open3d as o3d

    g = FlangeGeometry(float(d1), thickness, pedestal_diameter, pedestal_height)
    V, F = flange_mesh(g)
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32))
    )
    params = {
        "d1": d1,
        "thickness": thickness,
        "pedestal_diameter": pedestal_diameter,
        "pedestal_height": pedestal_height,
    }
    return Workpiece("iso9409-plate", "iso9409-plate", mesh, [], params)
