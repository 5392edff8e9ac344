"""A simulated construction / maintenance site for a mobile welding robot (paper 004, cell 4).

The site is a 36 m x 12 m yard (x east, y north, z up; the world frame of the simulated cell) with
steel portal frames (columns and beams), a steel roof over part of it (the GNSS receiver loses its
fix beneath), standing steel plates, pipe racks, container-like walls along the edges, and the
weld regions: fixed-size steel plates on stands (the paper's AE targets, with known corners) plus
the profile's ``[[sim.workpieces]]``. Every part is a :class:`~weldcell.hal.sim.workpieces.Workpiece`
(plates carry no seam truth: their corners are the AE truth), so the depth cameras ray-cast them
like any workpiece.

A :class:`MobileBase` drives a :class:`Route`: a smooth closed path through waypoints, with a speed
profile (cruise between work areas, slow near them, acceleration limited, standing still at both
ends) whose ground-truth pose, velocity, acceleration and angular rate are known at every instant
(C2 cubic splines of position and of yaw/pitch/roll over time). The base frame is x forward, y left,
z up; sensors mount on the live world frame ``base`` (the robot's base: in a profile without an arm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline, splev, splprep
from weldcell.hal.sim.workpieces import Workpiece
from weldcell.sdk.errors import DataError

BASE_FRAME = "base"
"""Name of the mobile base's live frame in the simulated world."""

GRAVITY = 9.80665


# --------------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------------


def _box(center, size, name: str, kind: str = "steel", seams: list | None = None) -> Workpiece:
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(np.asarray(center, float) - np.asarray(size, float) / 2)
    return Workpiece(name, kind, m, seams or [], {"size": list(map(float, size))})


def _cylinder(p0, p1, radius: float, name: str) -> Workpiece:
    import open3d as o3d

    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    m = o3d.geometry.TriangleMesh.create_cylinder(radius, length, resolution=24, split=1)
    z = axis / length
    x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = (p0 + p1) / 2
    m.transform(T)
    return Workpiece(name, "pipe", m, [], {"radius": radius, "length": length})


@dataclass(frozen=True)
class WeldPlate:
    """A fixed-size steel plate lying on a stand: its four top corners are the AE ground truth."""

    name: str
    center: np.ndarray
    size: tuple[float, float, float]
    yaw: float = 0.0

    @property
    def corners(self) -> np.ndarray:
        """(4, 3) top-face corners in the world frame (counter-clockwise seen from above)."""
        hx, hy = self.size[0] / 2, self.size[1] / 2
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        xy = local @ np.array([[c, s], [-s, c]]) + self.center[:2]
        return np.column_stack([xy, np.full(4, self.center[2] + self.size[2] / 2)])

    def workpiece(self) -> Workpiece:
        import open3d as o3d

        m = o3d.geometry.TriangleMesh.create_box(*self.size)
        m.translate(-np.asarray(self.size) / 2)
        T = np.eye(4)
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:3, 3] = self.center
        m.transform(T)
        return Workpiece(self.name, "weld-plate", m, [], {"size": list(self.size)})


@dataclass
class SiteLayout:
    """Static parts of the site: structures (no seams) and the weld regions (plates + workpieces)."""

    structures: list[Workpiece]
    plates: list[WeldPlate]
    roofs: list[tuple[float, float, float, float, float]]
    """Roofed areas (x0, y0, x1, y1, height): no sky view beneath."""
    steel_points: np.ndarray
    """(N, 3) centres of large steel masses (magnetometer disturbance sources)."""
    extent: tuple[float, float, float, float] = (0.0, 0.0, 36.0, 12.0)

    def weld_regions(self, extra: list[Workpiece] = ()) -> list[Workpiece]:
        return [p.workpiece() for p in self.plates] + list(extra)


def default_layout(seed: int = 0) -> SiteLayout:
    """The embedded default site: 36 m x 12 m with portal frames, a roof, plates, pipes and walls."""
    rng = np.random.default_rng(seed)
    parts: list[Workpiece] = [_box([18, 6, -0.05], [44, 20, 0.1], "ground", "ground")]
    steel: list[list[float]] = []
    # container-like walls around the yard (texture for the forward camera at all times)
    parts += [
        _box([18, -1.5, 1.3], [40, 0.3, 2.6], "wall-south", "wall"),
        _box([18, 13.5, 1.3], [40, 0.3, 2.6], "wall-north", "wall"),
        _box([-2.0, 6, 1.3], [0.3, 15, 2.6], "wall-west", "wall"),
        _box([38.0, 6, 1.3], [0.3, 15, 2.6], "wall-east", "wall"),
    ]
    # portal frames: columns at y = 0.5 and 11.5 every 6 m, beams across at 4.5 m
    for i, x in enumerate(np.arange(3.0, 34.0, 6.0)):
        for y in (0.4, 11.6):
            parts.append(_box([x, y, 2.25], [0.3, 0.3, 4.5], f"column-{i}-{y:.0f}", "steel"))
            steel.append([x, y, 1.0])
        parts.append(_box([x, 6.0, 4.6], [0.25, 11.5, 0.35], f"beam-{i}", "steel"))
    # a steel roof over x 15..27 (GNSS shadow)
    roof = (15.0, 0.0, 27.0, 12.0, 4.9)
    parts.append(_box([21.0, 6.0, 4.9], [12.0, 12.0, 0.05], "roof", "steel"))
    # standing plates and pipe racks along the walls
    for j, (x, y) in enumerate([(6, 1.6), (14, 10.6), (24, 1.6), (31, 10.6), (10, 10.8), (28, 1.4)]):
        w = 1.2 + rng.random() * 1.0
        parts.append(_box([x, y, 0.9], [w, 0.04, 1.8], f"plate-standing-{j}", "steel"))
        steel.append([x, y, 0.9])
    for j, (y, z) in enumerate([(12.6, 0.8), (12.6, 1.6), (-0.6, 1.2)]):
        parts.append(_cylinder([2.0, y, z], [34.0, y, z], 0.12 + 0.04 * j, f"pipe-{j}"))
    # stands with the weld plates (the paper's fixed-size steel plates)
    plates = []
    for j, (x, y, yaw) in enumerate([(9.0, 3.0, 0.3), (21.0, 9.0, -0.2), (27.5, 3.2, 0.0), (12.0, 9.2, 0.5)]):
        # a pedestal smaller than the plate: the plate overhangs it, its outline is free (AE)
        parts.append(_box([x, y, 0.4], [0.3, 0.2, 0.8], f"stand-{j}", "stand"))
        plates.append(WeldPlate(f"weld-plate-{j}", np.array([x, y, 0.81]), (0.6, 0.4, 0.02), yaw))
        steel.append([x, y, 0.5])
    return SiteLayout(parts, plates, [roof], np.asarray(steel, float))


# --------------------------------------------------------------------------------------------------
# Route and ground truth
# --------------------------------------------------------------------------------------------------

DEFAULT_WAYPOINTS = np.array(
    [
        [2.0, 6.0],
        [5.0, 3.6],
        [9.0, 4.6],
        [13.0, 6.5],
        [18.0, 7.4],
        [21.0, 7.6],
        [24.0, 5.0],
        [27.5, 4.8],
        [32.0, 6.0],
        [33.0, 8.5],
        [29.0, 9.0],
        [24.0, 8.6],
        [18.0, 6.2],
        [12.0, 7.8],
        [7.0, 8.4],
        [3.5, 8.6],
    ]
)
"""The default loop through the yard (x, y in metres), passing every weld plate."""


@dataclass
class RouteSettings:
    """How the base drives: speeds (m/s), acceleration (m/s^2), route length (m), ground roughness."""

    cruise_speed: float = 1.2
    work_speed: float = 0.3
    work_radius: float = 2.5
    max_accel: float = 0.4
    length: float = 100.0
    standstill: float = 2.0
    roughness: float = 0.01
    height: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0 < self.work_speed <= self.cruise_speed <= 5.0:
            raise DataError(
                f"route speeds {self.work_speed}/{self.cruise_speed} m/s are not 0 < work <= cruise <= 5",
                "the paper's robot drives at most 5 m/s; "
                "give cruise_speed <= 5 and work_speed <= cruise_speed",
            )
        if self.length <= 1.0 or self.max_accel <= 0:
            raise DataError("route length must be > 1 m and max_accel > 0", "give e.g. length = 100")


@dataclass
class Route:
    """A timed path: ground-truth pose and its derivatives at any time ``t`` in [0, duration]."""

    pos: CubicSpline
    yaw: CubicSpline
    pitch: CubicSpline
    roll: CubicSpline
    duration: float
    length: float
    settings: RouteSettings = field(default_factory=RouteSettings)

    @classmethod
    def build(
        cls,
        settings: RouteSettings,
        waypoints: np.ndarray | None = None,
        work_points: np.ndarray | None = None,
    ) -> Route:
        wp = DEFAULT_WAYPOINTS if waypoints is None else np.asarray(waypoints, float)
        closed = np.vstack([wp, wp[:1]])
        tck, _ = splprep(closed.T, s=0.0, per=1)
        u = np.linspace(0, 1, 4000)
        xy = np.array(splev(u, tck)).T
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        s_loop = np.concatenate([[0.0], np.cumsum(seg)])
        laps = int(np.ceil(settings.length / s_loop[-1]))
        s_all = np.concatenate([s_loop[:-1] + k * s_loop[-1] for k in range(laps)] + [[laps * s_loop[-1]]])
        xy_all = np.vstack([np.tile(xy[:-1], (laps, 1)), xy[-1:]])
        ds = 0.05
        s = np.arange(0.0, settings.length + ds / 2, ds)
        P = np.column_stack([np.interp(s, s_all, xy_all[:, 0]), np.interp(s, s_all, xy_all[:, 1])])
        v = np.full(len(s), settings.cruise_speed)
        if work_points is not None and len(work_points):
            d = np.min(np.linalg.norm(P[:, None, :] - np.asarray(work_points)[None, :, :2], axis=2), axis=1)
            v[d < settings.work_radius] = settings.work_speed
        v[0] = v[-1] = 0.0
        a = settings.max_accel
        for i in range(1, len(v)):  # acceleration limit forward and backward
            v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * a * ds))
        for i in range(len(v) - 2, -1, -1):
            v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * a * ds))
        dt = 2 * ds / np.maximum(v[1:] + v[:-1], 1e-6)
        heading = np.gradient(P, axis=0)
        yaw_s = np.unwrap(np.arctan2(heading[:, 1], heading[:, 0]))
        t = settings.standstill + np.concatenate([[0.0], np.cumsum(dt)])
        t = np.concatenate([[0.0], t, [t[-1] + settings.standstill]])
        P = np.vstack([P[:1], P, P[-1:]])
        yaw_s = np.concatenate([yaw_s[:1], yaw_s, yaw_s[-1:]])
        tu = np.arange(0.0, t[-1], 0.02)
        Pu = np.column_stack([np.interp(tu, t, P[:, 0]), np.interp(tu, t, P[:, 1])])
        Pu = _smooth(Pu, 15)
        yaw_u = _smooth(np.interp(tu, t, yaw_s)[:, None], 15)[:, 0]
        rng = np.random.default_rng(settings.seed)
        rough = [_rough(tu, rng, settings.roughness) for _ in range(3)]
        xyz = np.column_stack([Pu, settings.height + rough[2] * 0.5])
        return cls(
            CubicSpline(tu, xyz, bc_type="clamped"),
            CubicSpline(tu, yaw_u, bc_type="clamped"),
            CubicSpline(tu, rough[0], bc_type="clamped"),
            CubicSpline(tu, rough[1], bc_type="clamped"),
            float(tu[-1]),
            float(settings.length),
            settings,
        )

    def rotation(self, t) -> np.ndarray:
        """(N, 3, 3) R_world_base = Rz(yaw) Ry(pitch) Rx(roll) at times ``t``."""
        t = np.clip(np.atleast_1d(np.asarray(t, float)), 0.0, self.duration)
        y, p, r = self.yaw(t), self.pitch(t), self.roll(t)
        return _rzyx(y, p, r)

    def pose(self, t: float) -> np.ndarray:
        """T_world_base (4x4) at time ``t`` (clamped to the route's time span)."""
        tc = float(np.clip(t, 0.0, self.duration))
        T = np.eye(4)
        T[:3, :3] = self.rotation(tc)[0]
        T[:3, 3] = self.pos(tc)
        return T

    def poses(self, t) -> np.ndarray:
        """(N, 4, 4) T_world_base at times ``t``."""
        t = np.clip(np.atleast_1d(np.asarray(t, float)), 0.0, self.duration)
        T = np.tile(np.eye(4), (len(t), 1, 1))
        T[:, :3, :3] = self.rotation(t)
        T[:, :3, 3] = self.pos(t)
        return T

    def kinematics(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """R_world_base (N,3,3), velocity and acceleration (world, N×3) and angular rate (base, N×3)."""
        t = np.atleast_1d(np.asarray(t, float))
        inside = (t >= 0) & (t <= self.duration)
        tc = np.clip(t, 0.0, self.duration)
        R = self.rotation(tc)
        vel = self.pos(tc, 1) * inside[:, None]
        acc = self.pos(tc, 2) * inside[:, None]
        y, p = self.yaw(tc), self.pitch(tc)
        yd, pd, rd = (self.yaw(tc, 1) * inside, self.pitch(tc, 1) * inside, self.roll(tc, 1) * inside)
        z = np.array([0.0, 0.0, 1.0])
        Rz = _rzyx(y, np.zeros_like(y), np.zeros_like(y))
        Rzy = _rzyx(y, p, np.zeros_like(y))
        w_world = yd[:, None] * z + pd[:, None] * Rz[:, :, 1] + rd[:, None] * Rzy[:, :, 0]
        w_body = np.einsum("nji,nj->ni", R, w_world)
        return R, vel, acc, w_body

    def speed(self, t) -> np.ndarray:
        return np.linalg.norm(self.pos(np.clip(np.atleast_1d(t), 0, self.duration), 1), axis=1)


def _rzyx(y, p, r) -> np.ndarray:
    cy, sy, cp, sp, cr, sr = np.cos(y), np.sin(y), np.cos(p), np.sin(p), np.cos(r), np.sin(r)
    R = np.empty((len(y), 3, 3))
    R[:, 0, 0] = cy * cp
    R[:, 0, 1] = cy * sp * sr - sy * cr
    R[:, 0, 2] = cy * sp * cr + sy * sr
    R[:, 1, 0] = sy * cp
    R[:, 1, 1] = sy * sp * sr + cy * cr
    R[:, 1, 2] = sy * sp * cr - cy * sr
    R[:, 2, 0] = -sp
    R[:, 2, 1] = cp * sr
    R[:, 2, 2] = cp * cr
    return R


def _smooth(x: np.ndarray, half: int) -> np.ndarray:
    """Moving average with edge padding (keeps the ends fixed)."""
    k = np.ones(2 * half + 1) / (2 * half + 1)
    pad = np.pad(x, ((half, half), (0, 0)), mode="edge")
    return np.column_stack([np.convolve(pad[:, j], k, mode="valid") for j in range(x.shape[1])])


def _rough(t: np.ndarray, rng: np.random.Generator, amp: float) -> np.ndarray:
    """Ground-roughness angle (rad): a few random sinusoids of 0.1-1 Hz with amplitude ``amp``."""
    out = np.zeros_like(t)
    for _ in range(4):
        f = rng.uniform(0.1, 1.0)
        out += amp / 2 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    ramp = np.clip(np.minimum(t, t[-1] - t) / 2.0, 0.0, 1.0)  # still at the ends
    return out * ramp


# --------------------------------------------------------------------------------------------------
# The site in a simulated world
# --------------------------------------------------------------------------------------------------


class MobileBase:
    """The robot's mobile base: its pose is the route's ground truth at the world's simulated time."""

    def __init__(self, route: Route, clock) -> None:
        self.route = route
        self.clock = clock

    def T_world_base(self, t: float | None = None) -> np.ndarray:
        return self.route.pose(self.clock.t if t is None else t)


class Site:
    """The site installed in a :class:`~weldcell.hal.sim.world.SimWorld` (see :func:`install_site`)."""

    def __init__(self, layout: SiteLayout, route: Route, world, weld_workpieces: list[Workpiece]) -> None:
        self.layout = layout
        self.world = world
        self.base = MobileBase(route, world.clock)
        self.weld_workpieces = weld_workpieces
        self.epoch = 1.7e9
        """Host-clock time of simulated t = 0 (sensor stamps are epoch + simulated time)."""

    @property
    def route(self) -> Route:
        return self.base.route

    def set_route(self, settings: RouteSettings) -> Route:
        """Drive a new route (the job chooses its length and speeds)."""
        self.base.route = Route.build(settings, work_points=self.work_points())
        return self.base.route

    def work_points(self) -> np.ndarray:
        pts = [p.center for p in self.layout.plates] + [
            w.T_world_workpiece[:3, 3] for w in self.weld_workpieces
        ]
        return np.asarray(pts, float)

    def under_roof(self, p: np.ndarray) -> np.ndarray:
        """(N,) bool: points below a roof (no sky view)."""
        p = np.atleast_2d(p)
        out = np.zeros(len(p), bool)
        for x0, y0, x1, y1, h in self.layout.roofs:
            out |= (p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1) & (p[:, 2] < h)
        return out

    def distance_to_steel(self, p: np.ndarray) -> np.ndarray:
        p = np.atleast_2d(p)
        return np.min(np.linalg.norm(p[:, None, :] - self.layout.steel_points[None], axis=2), axis=1)

    def weld_truth(self) -> list[dict]:
        """Ground truth of every weld region: name, kind, corners (plates) and world bounding box."""
        out = []
        for p in self.layout.plates:
            wp = p.workpiece()
            V = np.asarray(wp.mesh.vertices)
            out.append(
                {"name": p.name, "kind": "weld-plate", "corners": p.corners, "min": V.min(0), "max": V.max(0)}
            )
        for w in self.weld_workpieces:
            V = np.asarray(w.mesh_in_world().vertices)
            out.append({"name": w.name, "kind": w.kind, "corners": None, "min": V.min(0), "max": V.max(0)})
        return out


def install_site(world, seed: int = 0, route: RouteSettings | None = None) -> Site:
    """Put the default site into ``world``: its parts become workpieces (weld regions keep their
    seams), the profile's workpieces become weld regions, and the live frame ``base`` follows
    the mobile base along its route (simulated clock)."""
    if getattr(world, "site", None) is not None:
        return world.site
    layout = default_layout(seed)
    extra = list(world.workpieces)
    world.workpieces = layout.structures + [p.workpiece() for p in layout.plates] + extra
    world.table_height = -1.0  # the cell's table is buried below the ground of the yard
    site = Site(
        layout,
        Route.build(RouteSettings(seed=seed) if route is None else route, work_points=None),
        world,
        extra,
    )
    site.base.route = Route.build(site.base.route.settings, work_points=site.work_points())
    world.site = site
    world.add_frame(BASE_FRAME, site.base.T_world_base)
    return site
