"""Seeded seam-extraction cases: any joint, any placement, any scanner -- and how to score a result.

A *case* is one simulated scan of one workpiece of the simulated cell (hal/sim/workpieces.py, plus an
X-groove butt built here), with its ground-truth seams and the part of each seam the scan shows:

* joints: V-groove butt, X-groove (double-V) butt, fillet T (also thin-plate and unequal web/base
  thickness), lap (also thin), outside corner (also thin), cylinder-on-plate saddle, Y-pipe junction;
  sizes drawn at random around the builders' defaults;
* placement: either the part *rests* on a table on one of its faces (turned about the table normal), or
  it is *held* in a fixture at a rotation drawn uniformly over SO(3) (vertical and overhead joints),
  with a fixture plate behind it (0-10 mm away, on the side away from the scanner); a quarter of the
  cases also express the whole scene in a base frame turned at random (nothing is "z up");
* scanners (:data:`SCANNERS`): an area-scan RGB-D camera (RealSense D415 model, stereo noise), a
  structured-light scanner (PhoXi S model, 0.05 mm noise) and a laser line profiler swept by the robot
  (about 1 mm between points along a line, 5-7 mm between lines, 0.3 mm noise growing with incidence,
  no viewpoint recorded); each with its own view set around the joint;
* visibility: a true seam point counts as *shown* when some view on the torch's side of it (its ray
  runs along the approach) reaches it (1 mm in front of it, along its approach) unobstructed, inside
  that view's image and range, and the scan holds a point near it; shown runs shorter than
  :data:`MIN_SHOWN` are dropped.

:func:`score_case` scores found seams (points + approach directions): precision (found points within
:data:`TOLERANCE` of any true seam), recall (shown true points within it of a found seam), F1,
translation RMSE and RMS approach-angle error over the matched found points (each against the nearest
shown true point within :data:`TOLERANCE`, else the nearest true point).

``make_case(index, seed)`` is deterministic; ``cases(n, seed)`` yields the first ``n``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from weldcell.hal.sim.camera_model import CameraPreset, RaycastCamera, get_preset
from weldcell.hal.sim.workpieces import SeamTruth, Workpiece, make_workpiece
from weldcell.sdk.geometry import frame_from_axes, transform_points, transform_vectors

#: matching distance of precision and recall (m)
TOLERANCE = 0.0015
#: shown runs of a true seam shorter than this are not counted (m): the seam stage's shortest seam
MIN_SHOWN = 0.02
#: density of the scored polylines (m)
STEP = 0.0005

JOINT_KINDS = (
    "v-groove",
    "x-groove",
    "fillet-t",
    "fillet-t-thin",
    "fillet-t-unequal",
    "lap",
    "lap-thin",
    "corner",
    "corner-thin",
    "saddle",
    "y-pipe",
)


@dataclass(frozen=True)
class Scanner:
    """A scanner model: ``kind`` 'area' (one image per view) or 'line' (a profiler swept by the robot)."""

    name: str
    kind: str
    preset: CameraPreset
    distance: tuple[float, float]
    views: tuple[int, int]
    cone_deg: float
    records_viewpoints: bool
    line_gap: tuple[float, float] = (0.0, 0.0)


def _line_profiler() -> CameraPreset:
    # a 320-point profile over a 55 deg fan: seen from 0.3 m a point every ~1 mm along the line, as in
    # the real scans; 0.3 mm noise at normal incidence, growing as 1/cos (grazing faces)
    w = 320
    f = (w / 2) / math.tan(math.radians(55.0) / 2)
    return CameraPreset(
        "line-profiler",
        w,
        1,
        f,
        f,
        (w - 1) / 2,
        0.0,
        0.15,
        0.6,
        sigma0=3e-4,
        principle="laser",
        grazing_dropout_deg=80.0,
        edge_dropout=0.3,
        random_dropout=0.002,
        min_cos=0.1,
        source="generic laser line profiler (Gocator 2350 / Keyence LJ-X class), seam_cases",
    )


SCANNERS: dict[str, Scanner] = {
    "rgbd": Scanner(
        "rgbd",
        "area",
        get_preset("realsense-d415").decimated(3),
        (0.45, 0.55),
        (4, 8),
        40.0,
        True,
    ),
    "structured-light": Scanner(
        "structured-light",
        "area",
        get_preset("phoxi-s").decimated(4),
        (0.42, 0.47),
        (2, 4),
        35.0,
        False,
    ),
    "line-laser": Scanner(
        "line-laser",
        "line",
        _line_profiler(),
        (0.25, 0.35),
        (1, 2),
        30.0,
        False,
        line_gap=(0.005, 0.007),
    ),
}


@dataclass
class SeamCase:
    """One scan: ``points`` (N, 3) in the base frame, the true seams (base frame), per true seam a mask
    of its points the scan shows, the camera positions (``None`` when the scanner records none)."""

    index: int
    joint: str
    scanner: str
    placement: str
    points: np.ndarray
    truth: list[SeamTruth]
    shown: list[np.ndarray]
    viewpoints: np.ndarray | None
    params: dict = field(default_factory=dict)

    @property
    def shown_length(self) -> float:
        """Total length of the shown parts of the true seams (m)."""
        return float(sum(m.sum() for m in self.shown) * STEP)

    @property
    def name(self) -> str:
        return f"{self.index:03d}-{self.joint}-{self.scanner}-{self.placement}"


# ----------------------------------------------------------------------------- workpieces


def _x_groove(rng: np.random.Generator) -> Workpiece:
    """Double-V butt of two plates along x: grooves on both faces, roots at the two ends of the land."""
    import trimesh
    from shapely.geometry import Polygon

    length, t = rng.uniform(0.15, 0.4), rng.uniform(0.012, 0.02)
    bevel, gap, land = math.radians(rng.uniform(25, 35)), rng.uniform(0.0, 0.0015), rng.uniform(0.001, 0.002)
    width = rng.uniform(0.12, 0.2)
    g2, h = gap / 2, (t - land) / 2
    top = g2 + h * math.tan(bevel)
    left = [(-width / 2, 0), (-top, 0), (-g2, h), (-g2, h + land), (-top, t), (-width / 2, t)]
    meshes = []
    for sign in (1.0, -1.0):
        poly = Polygon([(sign * y, z) for y, z in left])
        m = trimesh.creation.extrude_polygon(poly.buffer(0) if sign < 0 else poly, length)
        meshes.append(m)
    tm = trimesh.util.concatenate(meshes)
    # extrude_polygon: polygon in (x, y), height along z -> map (x, y, z) to (y, z, x - length / 2)
    V = np.asarray(tm.vertices)[:, [2, 0, 1]] - np.array([length / 2, 0, 0])
    F = np.asarray(tm.faces)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F))
    mesh.compute_triangle_normals()
    seams = []
    for sid, z, a in (("groove-top", h + land, -1.0), ("groove-bottom", h, 1.0)):
        k = int(math.ceil(length / STEP)) + 1
        x = np.linspace(-length / 2, length / 2, k)
        pts = np.column_stack([x, np.zeros(k), np.full(k, z)])
        seams.append(SeamTruth(sid, "butt", pts, np.tile([0, 0, a], (k, 1)), np.tile([1.0, 0, 0], (k, 1))))
    params = dict(length=length, thickness=t, bevel_angle=bevel, root_gap=gap, land=land, width=width)
    return Workpiece("x-groove-butt", "x-groove-butt", mesh, seams, params)


def make_joint(joint: str, rng: np.random.Generator) -> Workpiece:
    """A workpiece of ``joint`` (a name in :data:`JOINT_KINDS`) with sizes drawn from ``rng``."""
    u = rng.uniform
    L = u(0.15, 0.4)
    if joint == "v-groove":
        return make_workpiece(
            "v-groove-butt",
            length=L,
            width=u(0.12, 0.2),
            thickness=u(0.006, 0.014),
            bevel_angle=math.radians(u(25, 35)),
            root_gap=u(0, 0.0015),
            root_face=u(0.0005, 0.0015),
        )
    if joint == "x-groove":
        return _x_groove(rng)
    if joint.startswith("fillet-t"):
        t = u(0.002, 0.003) if joint.endswith("thin") else u(0.006, 0.012)
        web_t = u(0.003, 0.006) if joint.endswith("unequal") else t
        if joint.endswith("unequal"):
            t = u(0.012, 0.02)
        return make_workpiece(
            "fillet-t",
            length=L,
            base_width=u(0.12, 0.2),
            web_height=u(0.06, 0.12),
            thickness=t,
            web_thickness=web_t,
        )
    if joint.startswith("lap"):
        t = u(0.002, 0.003) if joint.endswith("thin") else u(0.005, 0.01)
        return make_workpiece("lap", length=L, width=u(0.1, 0.15), thickness=t, overlap=u(0.03, 0.06))
    if joint.startswith("corner"):
        t = u(0.002, 0.003) if joint.endswith("thin") else u(0.006, 0.012)
        return make_workpiece("corner", length=L, width=u(0.08, 0.15), thickness=t)
    if joint == "saddle":
        return make_workpiece(
            "cylinder-on-plate",
            radius=u(0.03, 0.06),
            height=u(0.08, 0.14),
            plate=u(0.2, 0.3),
            thickness=u(0.006, 0.012),
        )
    if joint == "y-pipe":
        r = u(0.035, 0.05)
        return make_workpiece(
            "y-pipe",
            radius=r,
            branch_radius=r * u(0.6, 0.8),
            branch_angle=math.radians(u(40, 65)),
            length=u(0.3, 0.4),
        )
    raise ValueError(f"unknown joint {joint!r}; use one of {JOINT_KINDS}")


# ----------------------------------------------------------------------------- placement


def _rest_rotation(wp: Workpiece, rng: np.random.Generator) -> np.ndarray:
    """A rotation that sets the part on one of its larger convex-hull faces (face down), random yaw."""
    import trimesh

    V = np.asarray(wp.mesh.vertices)
    hull = trimesh.Trimesh(V, np.asarray(wp.mesh.triangles)).convex_hull
    areas, normals = hull.facets_area, hull.facets_normal
    if len(areas) == 0:
        areas, normals = hull.area_faces, hull.face_normals
    ok = np.flatnonzero(areas >= 0.2 * areas.max())
    n = normals[rng.choice(ok)]
    R = Rotation.align_vectors([[0, 0, -1.0]], [n])[0]
    return (Rotation.from_euler("z", rng.uniform(0, 2 * np.pi)) * R).as_matrix()


def _box(lo: np.ndarray, hi: np.ndarray, T: np.ndarray) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_box(*(hi - lo))
    m.translate(lo)
    m.transform(T)
    return m


def _place(wp: Workpiece, rng: np.random.Generator, mode: str):
    """(part mesh in the scene, table mesh, true seams, the target seam's mean approach, its index, the
    table's normal towards the part); gravity is -z of the scene."""
    target = int(rng.integers(len(wp.seams)))
    for _ in range(50):
        R = _rest_rotation(wp, rng) if mode == "rests" else Rotation.random(random_state=rng).as_matrix()
        T = np.eye(4)
        T[:3, :3] = R
        mesh = o3d.geometry.TriangleMesh(wp.mesh).transform(T)
        seams = [s.transformed(T) for s in wp.seams]
        a = seams[target].approach.mean(axis=0)
        a /= max(np.linalg.norm(a), 1e-12)
        V = np.asarray(mesh.vertices)
        if mode == "rests":
            if a[2] > 0.3:  # the joint faces the table: no scanner above the table sees it
                continue
            support = np.array([0.0, 0.0, -1.0])
            gap = 0.0
        else:
            support = a + 0.8 * _random_unit(rng)  # behind the part as seen from the torch
            support /= np.linalg.norm(support)
            if support @ a < 0.5:
                continue
            gap = rng.uniform(0.0, 0.01)
        Tt = frame_from_axes(_perp(support), -support)  # table frame: z = table normal (towards part)
        ext = float((V @ support).max())
        Tt[:3, 3] = support * (ext + gap) + V.mean(axis=0) - support * (V.mean(axis=0) @ support)
        # the table reaches 60 mm beyond the part on every side (a bigger one only adds points)
        uv = (V - Tt[:3, 3]) @ Tt[:3, :2]
        lo, hi = uv.min(axis=0) - 0.06, uv.max(axis=0) + 0.06
        table = _box(np.array([lo[0], lo[1], -0.02]), np.array([hi[0], hi[1], 0.0]), Tt)
        return mesh, table, seams, a, target, -support
    raise RuntimeError("no placement shows the joint")


def _random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def _perp(v: np.ndarray) -> np.ndarray:
    return np.cross(v, [1.0, 0, 0] if abs(v[0]) < 0.9 else [0, 1.0, 0])


def _view_dirs(a: np.ndarray, n: int, cone_deg: float, table_n: np.ndarray, rng) -> list[np.ndarray]:
    """``n`` unit directions from the target towards the cameras, within ``cone_deg`` of ``-a`` and at
    least 10 deg above the table plane."""
    out = []
    while len(out) < n:
        tilt = math.radians(cone_deg) * math.sqrt(rng.uniform(0, 1))
        axis = _perp(-a) if len(out) == 0 else _random_unit(rng)
        d = Rotation.from_rotvec(tilt * _unit(np.cross(-a, axis))).apply(-a)
        if d @ table_n < math.sin(math.radians(10)):
            d = d + (math.sin(math.radians(15)) - d @ table_n) * table_n
            d = _unit(d)
        out.append(d)
    return out


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


# ----------------------------------------------------------------------------- scanning


def _area_scan(cam, sc: Scanner, center, dirs, rng):
    poses, parts = [], []
    for d in dirs:
        eye = center + d * rng.uniform(*sc.distance)
        T = frame_from_axes(_perp(-d), -d, eye)
        T[:3, :3] = T[:3, :3] @ Rotation.from_euler("z", rng.uniform(0, 2 * np.pi)).as_matrix()
        pts = cam.render(T, rng=rng).to_points()
        parts.append(transform_points(T, pts))
        poses.append(T)
    return np.vstack(parts), poses


def _line_scan(cam, sc: Scanner, center, dirs, travel, half, rng):
    """Sweep the profiler along ``travel`` (across the seam's lines) over ``±half``, one sweep per dir."""
    poses, parts = [], []
    for d in dirs:
        sweep = _unit(travel - (travel @ d) * d)
        sweep = Rotation.from_rotvec(d * math.radians(rng.uniform(-30, 30))).apply(sweep)
        gap = rng.uniform(*sc.line_gap)
        dist = rng.uniform(*sc.distance)
        for s in np.arange(-half, half + gap, gap) + rng.uniform(0, gap):
            eye = center + d * dist + sweep * s
            T = frame_from_axes(np.cross(sweep, -d), -d, eye)  # image row (x) across the sweep
            pts = cam.render(T, rng=rng).to_points()
            parts.append(transform_points(T, pts))
            poses.append(T)
    return np.vstack(parts), poses


def _shown(scene, sc: Scanner, poses, seams, cloud_tree, near: float) -> list[np.ndarray]:
    p = sc.preset
    out = []
    for s in seams:
        P, A = _dense(s)
        Q = P - 0.001 * A
        seen = np.zeros(len(P), dtype=bool)
        for T in poses:
            o = T[:3, 3]
            local = (Q - o) @ T[:3, :3]
            z = local[:, 2]
            u = p.fx * local[:, 0] / np.maximum(z, 1e-9) + p.cx
            inside = (z > p.min_range) & (z < p.max_range) & (u >= 0) & (u <= p.width - 1)
            if sc.kind == "area":
                v = p.fy * local[:, 1] / np.maximum(z, 1e-9) + p.cy
                inside &= (v >= 0) & (v <= p.height - 1)
            else:  # within half a line gap of the profile's plane
                inside &= np.abs(local[:, 1]) <= 0.5 * sc.line_gap[1]
                o = o[None, :] + np.outer(local[:, 1], T[:3, 1])
            # a view shows a seam point only from the torch's side of it: its ray runs along the approach
            # (a ray through an X-groove's root gap reaches the far root from the wrong side)
            facing = np.einsum("ij,ij->i", P - o, A) > 0.0
            idx = np.flatnonzero(inside & facing & ~seen)
            if not len(idx):
                continue
            oo = o if o.ndim == 1 else o[idx]
            D = Q[idx] - oo
            dist = np.linalg.norm(D, axis=1)
            rays = np.column_stack([np.broadcast_to(oo, D.shape), D / dist[:, None]]).astype(np.float32)
            hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
            seen[idx[hit >= dist - 2e-4]] = True
        d, _ = cloud_tree.query(P, k=1, distance_upper_bound=near)
        seen &= np.isfinite(d)
        out.append(_drop_short(seen, s.closed))
    return out


def _drop_short(mask: np.ndarray, closed: bool) -> np.ndarray:
    """``mask`` without runs of True shorter than :data:`MIN_SHOWN`."""
    m = mask.copy()
    if m.all() or not m.any():
        return m
    shift = int(np.argmin(m)) if closed else 0  # start a loop at a hidden point
    r = np.roll(m, -shift)
    edges = np.flatnonzero(np.diff(np.r_[0, r.astype(int), 0]))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        if (b - a) * STEP < MIN_SHOWN:
            r[a:b] = False
    return np.roll(r, shift)


def _dense(s: SeamTruth) -> tuple[np.ndarray, np.ndarray]:
    """Points and approach of ``s`` every :data:`STEP`."""
    return resample(s.points, s.approach, s.closed)


def resample(P: np.ndarray, A: np.ndarray, closed: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Polyline ``P`` (K, 3) with directions ``A`` resampled every :data:`STEP` (linear)."""
    P, A = np.asarray(P, float), np.asarray(A, float)
    if closed:
        P, A = np.vstack([P, P[:1]]), np.vstack([A, A[:1]])
    if len(P) < 2:
        return P, A
    s = np.r_[0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]
    q = np.arange(0, s[-1], STEP) if closed else np.linspace(0, s[-1], max(2, int(s[-1] / STEP) + 1))
    Pq = np.column_stack([np.interp(q, s, P[:, k]) for k in range(3)])
    Aq = np.column_stack([np.interp(q, s, A[:, k]) for k in range(3)])
    return Pq, Aq / np.maximum(np.linalg.norm(Aq, axis=1, keepdims=True), 1e-12)


def make_case(index: int, seed: int = 0) -> SeamCase:
    """Case ``index`` of the set drawn with ``seed`` (joint and scanner cycle, the rest is random)."""
    rng = np.random.default_rng([seed, index])
    joint = JOINT_KINDS[index % len(JOINT_KINDS)]
    sc = list(SCANNERS.values())[(index // len(JOINT_KINDS)) % len(SCANNERS)]
    mode = "rests" if rng.uniform() < 0.5 else "held"
    wp = make_joint(joint, rng)
    mesh, table, seams, a, target, table_n = _place(wp, rng, mode)
    center = seams[target].points.mean(axis=0)
    cam = RaycastCamera(sc.preset, [mesh, table])
    dirs = _view_dirs(a, int(rng.integers(sc.views[0], sc.views[1] + 1)), sc.cone_deg, table_n, rng)
    if sc.kind == "area":
        pts, poses = _area_scan(cam, sc, center, dirs, rng)
        near = 0.002
    else:
        tr = seams[target].travel.mean(axis=0)
        tr = tr if np.linalg.norm(tr) > 0.3 else seams[target].points[0] - center  # closed seams
        span = np.ptp(seams[target].points, axis=0)
        half = 0.5 * float(np.linalg.norm(span)) + 0.02
        pts, poses = _line_scan(cam, sc, center, dirs, _unit(tr), half, rng)
        near = max(0.002, 0.6 * sc.line_gap[1])
    scene = o3d.t.geometry.RaycastingScene()
    for m in (mesh, table):
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
    shown = _shown(scene, sc, poses, seams, cKDTree(pts), near)
    placement = _placement_name(a, mode)
    T_base = np.eye(4)
    if rng.uniform() < 0.25:  # the scene in a base frame turned at random
        T_base[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T_base[:3, 3] = rng.uniform(-0.5, 0.5, 3)
        placement += "-turned"
    seams = [s.transformed(T_base) for s in seams]
    eyes = np.array([T[:3, 3] for T in poses]) if sc.records_viewpoints else None
    return SeamCase(
        index,
        joint,
        sc.name,
        placement,
        transform_points(T_base, pts),
        seams,
        shown,
        None if eyes is None else transform_points(T_base, eyes),
        dict(wp.params, table_normal=transform_vectors(T_base, table_n).tolist()),
    )


def _placement_name(a: np.ndarray, mode: str) -> str:
    """'flat' (torch above the joint: approach down, gravity -z), 'overhead' (approach up) or 'vertical'."""
    return f"{mode}-" + ("flat" if a[2] < -0.7 else "overhead" if a[2] > 0.7 else "vertical")


def cases(n: int, seed: int = 0):
    """The first ``n`` cases of the set drawn with ``seed``."""
    for i in range(n):
        yield make_case(i, seed)


# ----------------------------------------------------------------------------- scoring


@dataclass
class CaseScore:
    """Precision / recall / F1 at :data:`TOLERANCE`, translation RMSE (m), RMS approach error (rad)."""

    precision: float
    recall: float
    f1: float
    rmse: float
    approach: float
    found_length: float
    shown_length: float
    per_seam_recall: list[float]


def score_case(case: SeamCase, found: list[tuple[np.ndarray, np.ndarray, bool]]) -> CaseScore:
    """Score ``found`` seams, each ``(points (K, 3), approach (K, 3), closed)``, against ``case``."""
    TP, TA = zip(*(_dense(s) for s in case.truth), strict=True)
    allP, allA = np.vstack(TP), np.vstack(TA)
    dense = [resample(p, a, c) for p, a, c in found if len(p) >= 2]
    shown_len = case.shown_length
    if not dense:
        return CaseScore(0.0, 0.0, 0.0, math.nan, math.nan, 0.0, shown_len, [0.0] * len(case.truth))
    FP, FA = np.vstack([d[0] for d in dense]), np.vstack([d[1] for d in dense])
    d, j = cKDTree(allP).query(FP, k=1)
    match = d <= TOLERANCE
    # a found point within reach of a shown seam point is scored against the seam the scan shows, not a
    # nearer hidden one (an X-groove's two roots are 1-2 mm apart, their approaches opposite)
    shown_idx = np.flatnonzero(np.concatenate(case.shown))
    if len(shown_idx):
        ds, js = cKDTree(allP[shown_idx]).query(FP, k=1)
        near_shown = ds <= TOLERANCE
        j = np.where(near_shown, shown_idx[np.minimum(js, len(shown_idx) - 1)], j)
    precision = float(match.mean())
    ftree = cKDTree(FP)
    hits, total, per = 0, 0, []
    for P, m in zip(TP, case.shown, strict=True):
        if m.any():
            dd, _ = ftree.query(P[m], k=1)
            h = int((dd <= TOLERANCE).sum())
            hits, total = hits + h, total + int(m.sum())
            per.append(h / int(m.sum()))
        else:
            per.append(math.nan)
    recall = hits / total if total else (1.0 if precision > 0 else 0.0)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    perp = _off_line(FP[match], allP, j[match])
    rmse = float(np.sqrt(np.mean(perp**2))) if match.any() else math.nan
    cos = np.clip(np.einsum("ij,ij->i", FA[match], allA[j[match]]), -1, 1)
    appr = float(np.sqrt(np.mean(np.arccos(cos) ** 2))) if match.any() else math.nan
    return CaseScore(precision, recall, f1, rmse, appr, len(FP) * STEP, shown_len, per)


def _off_line(F: np.ndarray, T: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Distances of ``F`` from the true polyline ``T`` near its nearest points ``T[j]`` (perpendicular to
    the local tangent, so the sampling step of ``T`` does not count as error)."""
    if not len(F):
        return np.zeros(0)
    lo, hi = np.clip(j - 1, 0, len(T) - 1), np.clip(j + 1, 0, len(T) - 1)
    t = T[hi] - T[lo]
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    D = F - T[j]
    return np.linalg.norm(D - np.einsum("ij,ij->i", D, t)[:, None] * t, axis=1)
