"""Guided placement with the laser projector (paper 002, §III-B).

1. The planned position: the workpiece is centred in the robot's reachable envelope, computed from the
   robot model's joint limits (inverse kinematics with the tool pointing down at the working height on
   a grid of the table; the centre is the reachable cell farthest from the envelope's border).
2. For each member in turn the robot carries the projector (a pinhole "inverse camera" on the flange)
   above the member, high enough for the member to fit in its field of view; the projector shows the
   cylindrical-magnet fixture positions on the member's outer boundary, then the member's outline; the
   worker confirms each step (a prompt on hardware; automatic in simulation). Every move passes the
   safety gate.

In simulation the projector's light is ray-cast onto the scene, and how far the lit outline lands from
the CAD outline is measured per member (it shows the projector calibration's error).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pydantic import Field
from weldcell.plugins.localize.plans import R_DOWN, member_axes
from weldcell.plugins.localize.projector_calibration import move_to
from weldcell.plugins.localize.template import Template
from weldcell.sdk.errors import DataError, SafetyError
from weldcell.sdk.geometry import invert
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length


class GuidanceSettings(Settings):
    """Planned position and projector guidance (§III-B)."""

    enabled: bool = Field(True, description="guide the worker with the projector (needs a projector device)")
    centre_in_envelope: bool = Field(
        True, description="move the template so it is centred in the robot's reachable envelope"
    )
    working_height: Length | None = Field(
        None, gt=0, description="tool height above the table for the envelope [m]; default: the inspection's"
    )
    envelope_step: Length = Field(0.08, gt=0, description="grid step of the envelope computation [m]")
    magnet_diameter: Length = Field(0.03, gt=0, description="diameter of the cylindrical fixture magnets [m]")
    magnets_per_member: int = Field(2, ge=1, le=6, description="magnets along each member's outer boundary")
    max_projector_height: Length = Field(
        0.7, gt=0, description="highest the projector is carried above the table [m]"
    )
    min_projector_height: Length = Field(0.3, gt=0, description="lowest projector height above the table [m]")


# ----------------------------------------------------------------------------------- reachable envelope
@dataclass
class Envelope:
    """The reachable cells of the table at the working height (tool down): grid XY (N, 2) and mask."""

    xy: np.ndarray
    reachable: np.ndarray
    step: float
    centre: np.ndarray

    def contains(self, pts: np.ndarray) -> np.ndarray:
        """Is each point (M, 2) within half a cell of a reachable cell?"""
        ok = self.xy[self.reachable]
        if len(ok) == 0:
            return np.zeros(len(pts), bool)
        from scipy.spatial import cKDTree

        d, _ = cKDTree(ok).query(np.asarray(pts, float))
        return d <= self.step * 0.75


def reachable_envelope(robot, table_z: float, s: GuidanceSettings, height: float) -> Envelope:
    """The table cells where the tool can point straight down at ``height`` above the table, within the
    joint limits (IK) and the safety gate's workspace box and reach."""
    gate = robot.gate
    model = gate.model
    if model is None:
        raise DataError(
            f"robot '{robot.name}' has no kinematic model: the reachable envelope cannot be computed",
            "set the robot model in its settings, or [job.settings.guidance] centre_in_envelope = false",
        )
    reach = float(getattr(model, "max_reach_bound", model.reach))
    lo = np.maximum(gate.lo[:2], -reach)
    hi = np.minimum(gate.hi[:2], reach)
    step = s.envelope_step
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 1e-9, step), np.arange(lo[1], hi[1] + 1e-9, step))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    z = table_z + height
    ny, nx = gx.shape
    ok = np.zeros(len(xy), bool)
    T_ft_inv = invert(robot.T_flange_tcp)
    st = robot.state()

    def solve(i: int, seed: np.ndarray) -> np.ndarray | None:
        T = np.eye(4)
        T[:3, :3] = R_DOWN
        T[:3, 3] = [xy[i, 0], xy[i, 1], z]
        try:
            gate.check_point(T[:3, 3])
            q = gate.solve(T @ T_ft_inv, seed)
        except SafetyError:
            return None
        # the same arm configuration as the neighbour it was reached from (as the gate tracks a path)
        return q if q is not None and np.max(np.abs(q - seed)) < 0.35 + 0.35 * step / 0.05 else None

    # flood fill from the cell under the tool: a cell is reachable when IK seeded by a reachable neighbour
    # gives a solution of the same arm configuration (no branch flip), like a path the gate would accept
    start = int(np.argmin(np.linalg.norm(xy - st.T_base_tcp[:2, 3], axis=1)))
    q0 = solve(start, st.q)
    if q0 is None:
        seeds = [
            model.ik(np.r_[np.c_[R_DOWN, [xy[start, 0], xy[start, 1], z]], [[0, 0, 0, 1]]] @ T_ft_inv, st.q)
        ]
        q0 = solve(start, seeds[0]) if seeds else None
    qs: dict[int, np.ndarray] = {}
    if q0 is not None:
        ok[start], qs[start] = True, q0
    todo = [start] if q0 is not None else []
    while todo:
        i = todo.pop()
        r, c = divmod(i, nx)
        for rr, cc in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
            j = rr * nx + cc
            if 0 <= rr < ny and 0 <= cc < nx and not ok[j] and j not in qs:
                q = solve(j, qs[i])
                qs[j] = q
                if q is not None:
                    ok[j] = True
                    todo.append(j)
    if not ok.any():
        raise DataError(
            f"no table cell is reachable with the tool down at {z:.3f} m",
            "check [cell.safety] workspace_min/max, the robot model and working_height",
        )
    from scipy.ndimage import distance_transform_edt

    mask = ok.reshape(gx.shape)
    dist = distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1]
    k = int(np.argmax(dist.ravel()))
    return Envelope(xy, ok, step, xy[k])


def centre_template(
    template: Template, env: Envelope, margin: float, offsets: tuple = ((0.0, 0.0),), rotations: float = 30.0
) -> tuple[Template, float]:
    """The template translated to where it sits deepest inside the envelope: the reachable cell that
    maximises the smallest distance from the template's outline (densified) to the envelope's border.
    The paper centres the workpiece's centroid on the envelope's centre; for a part that is large
    against the envelope this keeps every member reachable. Returns (template, clearance in m); a
    clearance under ``margin`` (the inspection's reach beyond the outline) is refused. ``offsets`` (2,)
    are where the tool is relative to the point worked on (e.g. the laser's offset from the TCP): the
    outline is checked at each. The part is also turned in steps of ``rotations`` degrees (0: never)
    about its centroid: the planned orientation is ours to choose."""
    from scipy.interpolate import RegularGridInterpolator
    from weldcell.plugins.localize.plans import _densify
    from weldcell.plugins.localize.pose import transform_template

    xs, ys = np.unique(env.xy[:, 0]), np.unique(env.xy[:, 1])
    mask = env.reachable.reshape(len(ys), len(xs))
    from scipy.ndimage import distance_transform_edt

    dist = distance_transform_edt(np.pad(mask, 1))[1:-1, 1:-1] * env.step - env.step  # conservative
    f = RegularGridInterpolator((ys, xs), dist, bounds_error=False, fill_value=-1.0)
    pts = np.vstack([_densify(np.vstack([m.outline, m.outline[:1]]), env.step / 2) for m in template.members])
    cand = env.xy[env.reachable]
    best, clear, best_angle = cand[0], -np.inf, 0.0
    for ang in np.radians(np.arange(0.0, 180.0, float(rotations))) if rotations else [0.0]:
        R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        rel = np.vstack([(pts - template.centroid) @ R.T + np.asarray(o, float) for o in offsets])
        Q = cand[:, None, :] + rel[None]  # (C, P, 2)
        v = f(Q.reshape(-1, 2)[:, ::-1]).reshape(len(cand), len(rel)).min(axis=1)
        k = int(np.argmax(v))
        if v[k] > clear + 1e-9:
            best, clear, best_angle = cand[k], float(v[k]), float(ang)
    if clear < margin:
        raise DataError(
            f"the workpiece does not fit in the robot's reachable envelope with {margin * 1e3:.0f} mm spare "
            f"(best clearance {clear * 1e3:.0f} mm)",
            "use a robot with more reach, a smaller inspection span, or split the workpiece",
        )
    d = best - template.centroid
    turned = transform_template(template, (0.0, 0.0, best_angle))
    return transform_template(turned, (d[0], d[1], 0.0)), clear


# --------------------------------------------------------------------------------------- what to show
def fixture_positions(template: Template, index: int, diameter: float, n: int) -> np.ndarray:
    """Centres (n, 2) of the fixture magnets of member ``index``: along its outer long edge (the one
    farther from the workpiece's centroid), just outside it, so the member rests against them."""
    from weldcell.plugins.localize.plans import major_edges

    m = template.members[index]
    P = m.outline
    edges = major_edges(P)
    if len(edges) == 0:
        edges = np.arange(len(P))
    mids = 0.5 * (P[edges] + np.roll(P, -1, axis=0)[edges])
    e = int(edges[int(np.argmax(np.linalg.norm(mids - template.centroid, axis=1)))])
    a, b = P[e], P[(e + 1) % len(P)]
    d = (b - a) / np.linalg.norm(b - a)
    normal = np.array([d[1], -d[0]])
    if np.dot(normal, 0.5 * (a + b) - P.mean(axis=0)) < 0:
        normal = -normal
    f = (np.arange(n) + 0.5) / n if n > 1 else np.array([0.5])
    return a + f[:, None] * (b - a) + 0.5 * diameter * normal


def circle_segments(centre: np.ndarray, radius: float, z: float, n: int = 24) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n + 1)
    p = np.column_stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), np.full(n + 1, z)])
    return np.stack([p[:-1], p[1:]], axis=1)


def outline_segments(outline: np.ndarray, z: float) -> np.ndarray:
    P = np.column_stack([outline, np.full(len(outline), z)])
    return np.stack([P, np.roll(P, -1, axis=0)], axis=1)


def projector_pose(
    points_xy: np.ndarray, table_z: float, K: np.ndarray, size: tuple[int, int], s: GuidanceSettings
) -> np.ndarray:
    """``T_base_projector`` looking straight down over the points, high enough to hold them in view
    (clamped to [min, max]_projector_height; the outline is cut at the image border if it is larger)."""
    c = points_xy.mean(axis=0)
    half_w = size[0] / 2 / K[0, 0]
    half_h = size[1] / 2 / K[1, 1]
    ext = np.abs(points_xy - c).max(axis=0)
    h = max(ext[0] / half_w, ext[1] / half_h) * 1.15
    h = float(np.clip(h, s.min_projector_height, s.max_projector_height))
    T = np.eye(4)
    T[:3, :3] = R_DOWN
    T[:3, 3] = [c[0], c[1], table_z + h]
    return T


# --------------------------------------------------------------------------------------------- guide
@dataclass
class MemberGuidance:
    """What was shown for one member and how well the light landed (sim: measured by ray casting)."""

    id: str
    magnets: np.ndarray
    projector_height: float
    lit_error_mean: float | None = None
    lit_error_max: float | None = None
    confirmed: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        return {
            "id": self.id,
            "magnets": np.round(self.magnets, 5).tolist(),
            "projector_height": round(self.projector_height, 4),
            "lit_error_mean_mm": None if self.lit_error_mean is None else round(self.lit_error_mean * 1e3, 3),
            "lit_error_max_mm": None if self.lit_error_max is None else round(self.lit_error_max * 1e3, 3),
            "confirmed": self.confirmed,
        }


def _lit_error(projector, outline: np.ndarray, T_world_base: np.ndarray) -> tuple[float, float] | None:
    """Distance (mean, max) of the lit points from the CAD outline (simulated projectors only)."""
    lit = getattr(projector, "lit", None)
    if lit is None or len(lit) == 0:
        return None
    pts = (np.c_[lit, np.ones(len(lit))] @ invert(T_world_base).T)[:, :2]
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        return None
    segs = np.stack([outline, np.roll(outline, -1, axis=0)], axis=1)
    a, b = segs[:, 0], segs[:, 1]
    ab = b - a
    t = np.clip(np.einsum("nsk,sk->ns", pts[:, None] - a[None], ab) / np.einsum("sk,sk->s", ab, ab), 0, 1)
    d = np.linalg.norm(pts[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1)
    return float(d.mean()), float(d.max())


def guide_placement(
    robot,
    projector,
    template: Template,
    T_flange_projector: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    s: GuidanceSettings,
    confirm: Callable[[str], None],
    T_world_base: np.ndarray | None = None,
) -> list[MemberGuidance]:
    """Member by member: move the projector over it, show the magnets, then the outline; confirm each."""
    T_wb = np.eye(4) if T_world_base is None else T_world_base
    out = []
    for i, m in enumerate(template.members):
        magnets = fixture_positions(template, i, s.magnet_diameter, s.magnets_per_member)
        view = np.vstack([m.outline, magnets])
        T_bp = projector_pose(view, template.table_z, K, size, s)
        T_tcp = T_bp @ invert(T_flange_projector) @ robot.T_flange_tcp
        move_to(robot, T_tcp)  # a joint move through the safety gate
        rec = MemberGuidance(m.id, magnets, float(T_bp[2, 3] - template.table_z))
        segs = np.concatenate([circle_segments(c, s.magnet_diameter / 2, template.table_z) for c in magnets])
        projector.project(_to_world(segs, T_wb), label=f"{m.id}: fixtures")
        confirm(f"place the {len(magnets)} fixture magnets of member '{m.id}' on the marked circles")
        rec.confirmed.append("fixtures")
        projector.project(
            _to_world(outline_segments(m.outline, template.table_z), T_wb), label=f"{m.id}: outline"
        )
        err = _lit_error(projector, m.outline, T_wb)
        if err is not None:
            rec.lit_error_mean, rec.lit_error_max = err
        confirm(f"place member '{m.id}' on its projected outline, against the magnets")
        rec.confirmed.append("outline")
        out.append(rec)
    projector.clear()
    return out


def _to_world(segs: np.ndarray, T_world_base: np.ndarray) -> np.ndarray:
    P = segs.reshape(-1, 3) @ T_world_base[:3, :3].T + T_world_base[:3, 3]
    return P.reshape(-1, 2, 3)


__all__ = [
    "GuidanceSettings",
    "Envelope",
    "reachable_envelope",
    "centre_template",
    "fixture_positions",
    "guide_placement",
    "MemberGuidance",
    "member_axes",
]
