"""Inspection plans (paper 002, §III-C) and the check that a plan constrains the pose (§IV, Fig. 10).

* **local**: a zig-zag across the major axis of each member (Fig. 7): legs from one side of the
  member's envelope to the other while advancing ``spacing`` along the axis, so every leg crosses both
  of the member's long edges; the envelope reaches ``span`` beyond the member on each side (the
  placement error it tolerates).
* **global**: a rectangular spiral along the principal axes of the whole workpiece (Fig. 8; the
  eigenvectors of its outline, sampled evenly along the outline so long edges weigh by their length),
  from ``span`` outside the workpiece inwards, rings ``spacing`` apart.

Both blend their corners with a rounded turn of radius ``blend`` (the zig-zag's extremes excite
vibration when taken sharply, §III-C). Both start with a *latency pass*: one line across the first
member, forward and straight back, from which acquisition estimates the sensor-robot latency.

:func:`check_constraints` runs before anything moves: at the planned position (and, when asked, at the
corners of the placement window) the plan must cross each member's major-axis edges at least
``min_crossings`` times, and the crossings of all members together must fix x, y and theta (members
whose edges are all parallel leave the workpiece free to slide; Fig. 10). A plan that does not is
refused with the member and edge named.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import Field
from weldcell.plugins.localize.template import Template
from weldcell.sdk.errors import DataError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Acceleration, Angle, Length, Speed

#: sensor orientation during inspection: beam (z) straight down, x along base x
R_DOWN = np.diag([1.0, -1.0, -1.0])


class PlanSettings(Settings):
    """The inspection plan (§III-C): which pattern, its span and line spacing, its speed."""

    plan: Literal["local", "global"] = Field(
        "local",
        description="local: zig-zag across each member (butt-jointed frames); global: a spiral along the "
        "workpiece's principal axes (members inside the hull, mitre joints)",
    )
    span: Length = Field(
        0.04, gt=0, description="how far the pattern reaches beyond the planned outline (placement error) [m]"
    )
    spacing: Length = Field(0.015, gt=0, description="distance between zig-zag legs / spiral rings [m]")
    end_margin: Length = Field(0.02, ge=0, description="zig-zag legs keep this far from a member's ends [m]")
    standoff: Length | None = Field(
        None, gt=0, description="sensor height above the highest member top [m]; default: mid of its range"
    )
    speed: Speed = Field(0.1, gt=0, description="TCP speed while inspecting [m/s]")
    accel: Acceleration = Field(1.0, gt=0, description="TCP acceleration while inspecting [m/s^2]")
    blend: Length = Field(0.005, ge=0, description="corner radius of the blended turns [m]")
    spiral_angle: Angle = Field(
        0.0,
        description="turn the global spiral by this from the principal axes [rad]: 0 is the paper's; members "
        "parallel to an axis are crossed only near the spiral's ends, 45 deg crosses them on every ring",
    )
    spiral_core: Literal["none", "serpentine"] = Field(
        "serpentine",
        description="global plan: 'none' is the paper's spiral alone (it crosses members along the major "
        "axis only near its ends); 'serpentine' adds legs across the minor axis over the whole workpiece "
        "after the spiral, so long members are crossed along their whole length",
    )
    core_spacing: Length | None = Field(
        None, gt=0, description="distance between the serpentine's legs [m]; default: 2 x spacing"
    )
    align_baseline: bool = Field(
        True,
        description="local plan: turn the sensor so its triangulation baseline runs along each member (no "
        "shadow behind the member's long edges: both edges of every crossing are readable)",
    )
    latency_pass: bool = Field(True, description="start with a forward/backward pass (latency estimate)")
    min_crossings: int = Field(2, ge=1, description="crossings needed on each major-axis edge (§IV)")
    check_angle: Angle = Field(
        0.349, ge=0, description="also check the plan at ±this rotation of the part (placement window) [rad]"
    )
    check_offset: Length = Field(
        0.015, ge=0, description="also check the plan at ±this offset of the part (placement window) [m]"
    )


@dataclass
class InspectionPlan:
    """The sensor's path over the table: ``lines`` polylines (K_i, 2) of beam-foot XY in the base frame
    (scanned one after another, each ending where the next starts), ``kinds`` per line ('latency-fwd',
    'latency-back', 'leg', 'transit', 'ring'), the sensor height ``z_sensor`` and the speed."""

    kind: str
    lines: list[np.ndarray]
    kinds: list[str]
    z_sensor: float
    speed: float
    accel: float
    duration: float = 0.0
    axes: np.ndarray = field(default_factory=lambda: np.eye(2))
    constraints: dict = field(default_factory=dict)
    yaws: list[float] = field(default_factory=list)
    """Per line: the sensor's turn about the vertical (its triangulation baseline's direction) [rad]."""

    def yaw(self, k: int) -> float:
        return float(self.yaws[k]) if self.yaws else 0.0

    def line_speed(self, k: int, turn_rate: float = 0.5) -> float:
        """TCP speed of line ``k``: the plan's, slower on a line that turns the sensor (a transit between
        members) so the turn stays under ``turn_rate`` rad/s."""
        turn = abs(self.yaw(k) - self.yaw(k - 1)) if k > 0 else 0.0
        if turn < 1e-9:
            return self.speed
        length = float(np.linalg.norm(np.diff(self.lines[k], axis=0), axis=1).sum())
        return float(min(self.speed, max(0.005, length * turn_rate / turn)))

    @property
    def xy(self) -> np.ndarray:
        """All waypoints in order (M, 2)."""
        return np.vstack([self.lines[0][:1]] + [ln[1:] for ln in self.lines])

    @property
    def length(self) -> float:
        return float(sum(np.linalg.norm(np.diff(ln, axis=0), axis=1).sum() for ln in self.lines))

    def sensor_poses(self, xy: np.ndarray, yaw: float = 0.0) -> np.ndarray:
        """Sensor poses (K, 4, 4) in the base frame above ``xy`` (K, 2): beam down, at ``z_sensor``, its x
        axis (the triangulation baseline) turned ``yaw`` from base x."""
        T = np.tile(np.eye(4), (len(xy), 1, 1))
        c, s = np.cos(yaw), np.sin(yaw)
        T[:, :3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R_DOWN
        T[:, :2, 3] = xy
        T[:, 2, 3] = self.z_sensor
        return T

    def tcp_poses(
        self, xy: np.ndarray, T_flange_sensor: np.ndarray, T_flange_tcp: np.ndarray, yaw: float = 0.0
    ) -> np.ndarray:
        """Robot TCP poses (K, 4, 4) that put the sensor above ``xy`` (turned ``yaw``)."""
        return self.sensor_poses(xy, yaw) @ np.linalg.inv(T_flange_sensor) @ T_flange_tcp

    def line_tcp_poses(self, k: int, T_flange_sensor: np.ndarray, T_flange_tcp: np.ndarray) -> np.ndarray:
        """TCP poses of line ``k`` after its first point (which is where the previous line ended)."""
        return self.tcp_poses(self.lines[k][1:], T_flange_sensor, T_flange_tcp, self.yaw(k))

    def to_json(self) -> dict:
        return {
            "kind": self.kind,
            "z_sensor": self.z_sensor,
            "speed": self.speed,
            "duration_s": round(self.duration, 3),
            "length_m": round(self.length, 4),
            "lines": [np.round(ln, 6).tolist() for ln in self.lines],
            "line_kinds": self.kinds,
            "constraints": self.constraints,
        }


# ------------------------------------------------------------------------------------------ geometry
def member_axes(outline: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre (2,), unit major axis u (2,) and the extents [[umin, umax], [vmin, vmax]] of an outline."""
    P = np.asarray(outline, dtype=float)
    pts = _densify(np.vstack([P, P[:1]]), 0.002)
    c = pts.mean(axis=0)
    w, V = np.linalg.eigh(np.cov((pts - c).T))
    u = V[:, int(np.argmax(w))]
    v = np.array([-u[1], u[0]])
    uv = (P - c) @ np.column_stack([u, v])
    return c, u, np.array([[uv[:, 0].min(), uv[:, 0].max()], [uv[:, 1].min(), uv[:, 1].max()]])


def _densify(poly: np.ndarray, step: float) -> np.ndarray:
    out = [poly[:1]]
    for a, b in zip(poly[:-1], poly[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + np.linspace(0, 1, n + 1)[1:, None] * (b - a))
    return np.vstack(out)


def _blend(corners: np.ndarray, r: float) -> list[np.ndarray]:
    """Split a corner polyline into straight runs joined by rounded turns of radius ~``r``.

    Returns polylines: each a straight run followed by the turn into the next run (a quadratic Bezier
    sampled at thirds; the robot's corner zone ``blend`` rounds it further), the last run ending at the
    last corner.
    """
    n = len(corners)
    if n < 3 or r <= 0:
        return [corners[i : i + 2] for i in range(n - 1)]
    runs, start = [], corners[0]
    for i in range(1, n - 1):
        a, p, b = corners[i - 1], corners[i], corners[i + 1]
        rr = min(r, 0.45 * np.linalg.norm(p - a), 0.45 * np.linalg.norm(b - p))
        d_in = (p - a) / max(np.linalg.norm(p - a), 1e-12)
        d_out = (b - p) / max(np.linalg.norm(b - p), 1e-12)
        p0, p2 = p - rr * d_in, p + rr * d_out
        s = np.linspace(0, 1, 4)[1:, None]
        turn = (1 - s) ** 2 * p0 + 2 * (1 - s) * s * p + s**2 * p2
        runs.append(np.vstack([start, p0, turn]))
        start = p2
    runs.append(np.vstack([start, corners[-1]]))
    return runs


def _latency_pass(template: Template, span: float) -> list[np.ndarray]:
    c, u, ext = member_axes(template.members[0].outline)
    v = np.array([-u[1], u[0]])
    mid = c + 0.5 * (ext[0, 0] + ext[0, 1]) * u
    a, b = mid + (ext[1, 0] - span) * v, mid + (ext[1, 1] + span) * v
    return [np.vstack([a, b]), np.vstack([b, a])]


def zigzag_corners(outline: np.ndarray, span: float, spacing: float, end_margin: float) -> np.ndarray:
    """Corner points (n, 2) of the zig-zag over one member: alternating sides, ``spacing`` apart along
    the major axis, ``span`` beyond the outline on each side."""
    c, u, ext = member_axes(outline)
    v = np.array([-u[1], u[0]])
    u0, u1 = ext[0, 0] + end_margin, ext[0, 1] - end_margin
    if u1 <= u0:
        u0 = u1 = 0.5 * (ext[0, 0] + ext[0, 1])
    n = max(2, int(np.floor((u1 - u0) / spacing)) + 1)
    us = np.linspace(u0, u1, n)
    vs = np.where(np.arange(n) % 2 == 0, ext[1, 0] - span, ext[1, 1] + span)
    return c + us[:, None] * u + vs[:, None] * v


def principal_axes(template: Template) -> tuple[np.ndarray, np.ndarray]:
    """Centre (2,) and axes (2, 2) (columns: major, minor) of the whole workpiece's outline."""
    pts = np.vstack([_densify(np.vstack([m.outline, m.outline[:1]]), 0.005) for m in template.members])
    c = pts.mean(axis=0)
    w, V = np.linalg.eigh(np.cov((pts - c).T))
    order = np.argsort(w)[::-1]
    return c, V[:, order]


def spiral_corners(
    template: Template,
    span: float,
    spacing: float,
    angle: float = 0.0,
    core: str = "none",
    core_spacing: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Corners (n, 2) of a rectangular spiral inwards along the principal axes (turned by ``angle``), and
    the axes (2, 2).

    The paper's spiral (``core="none"``) closes when its short side does: members along the major axis
    are crossed only by the rings' short legs near the workpiece's ends. ``core="serpentine"`` continues
    from the spiral's centre with legs across the minor axis (from ``span`` outside the workpiece on one
    side to ``span`` outside on the other), ``core_spacing`` apart over the workpiece's length, so those
    members are crossed along their whole length as well."""
    c, A = principal_axes(template)
    if angle:
        A = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]) @ A
    pts = np.vstack([m.outline for m in template.members])
    uv = (pts - c) @ A
    lo, hi = uv.min(axis=0) - span, uv.max(axis=0) + span
    x0, y0, x1, y1 = lo[0], lo[1], hi[0], hi[1]
    # with the core, the rings shrink along the major axis in proportion to the extents (they close on
    # both axes together), so their long legs keep crossing the members near the ends on every ring
    du = spacing * (hi[1] - lo[1]) / (hi[0] - lo[0]) if core == "serpentine" else spacing
    corners = [[x0, y0]]
    while x1 - x0 > spacing and y1 - y0 > spacing:  # one ring: along u, v, back u, back v, then inset
        corners += [[x1, y0], [x1, y1], [x0, y1], [x0, y0 + spacing]]
        x0, y0, x1, y1 = x0 + du, y0 + spacing, x1 - du, y1 - spacing
    if core == "serpentine":
        step = core_spacing or 2 * spacing
        u0, u1 = lo[0] + span, hi[0] - span  # the workpiece's own extent along the major axis
        n = max(2, int(np.floor((u1 - u0) / step)) + 1)
        us = u0 + (u1 - u0 - (n - 1) * step) / 2 + step * np.arange(n)
        if abs(us[0] - corners[-1][0]) > abs(us[-1] - corners[-1][0]):
            us = us[::-1]  # start at the nearer end
        for i, u in enumerate(us):
            a, b = (lo[1], hi[1]) if i % 2 == 0 else (hi[1], lo[1])
            corners += [[u, a], [u, b]]
    C = np.asarray(corners)
    return c + C @ A.T, A


def make_plan(
    template: Template, s: PlanSettings, z_sensor: float, start_xy: np.ndarray | None = None
) -> InspectionPlan:
    """The local or global plan over ``template`` at its planned position (no motion, no check)."""
    lines: list[np.ndarray] = []
    kinds: list[str] = []
    yaws: list[float] = []

    def member_yaw(i: int) -> float:
        if not (s.align_baseline and s.plan == "local"):
            return 0.0
        u = member_axes(template.members[i].outline)[1]
        a = float(np.arctan2(u[1], u[0]))
        return float((a + np.pi / 2) % np.pi - np.pi / 2)  # in [-90, 90) deg: the smaller wrist turn

    if s.latency_pass:
        lines += _latency_pass(template, s.span)
        kinds += ["latency-fwd", "latency-back"]
        yaws += [member_yaw(0)] * 2
    blend = min(s.blend, 0.5 * s.span)  # a turn must not cut the corner back inside the outline
    here = lines[-1][-1] if lines else (start_xy if start_xy is not None else template.centroid)
    axes = np.eye(2)
    if s.plan == "local":
        todo = list(range(len(template.members)))
        while todo:  # nearest member next, entered at its nearer end
            cand = []
            for i in todo:
                z = zigzag_corners(template.members[i].outline, s.span, s.spacing, s.end_margin)
                for zz in (z, z[::-1]):
                    cand.append((float(np.linalg.norm(zz[0] - here)), i, zz))
            _, i, z = min(cand, key=lambda x: x[0])
            todo.remove(i)
            lines.append(np.vstack([here, z[0]]))
            kinds.append("transit")
            runs = _blend(z, blend)
            lines += runs
            kinds += ["leg"] * len(runs)
            yaws += [member_yaw(i)] * (len(runs) + 1)  # the transit turns the sensor for the member
            here = z[-1]
    else:
        C, axes = spiral_corners(template, s.span, s.spacing, s.spiral_angle, s.spiral_core, s.core_spacing)
        lines.append(np.vstack([here, C[0]]))
        kinds.append("transit")
        runs = _blend(C, blend)
        lines += runs
        kinds += ["ring"] * len(runs)
        yaws += [0.0] * (len(runs) + 1)
    keep = [i for i, ln in enumerate(lines) if np.linalg.norm(ln[-1] - ln[0]) > 1e-9 or len(ln) > 2]
    return InspectionPlan(
        s.plan,
        [lines[i] for i in keep],
        [kinds[i] for i in keep],
        float(z_sensor),
        s.speed,
        s.accel,
        axes=axes,
        yaws=[yaws[i] for i in keep],
    )


# ------------------------------------------------------------------------------------ the constraint check
def _crossings(path: np.ndarray, segs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intersections of a polyline (M, 2) with segments (S, 2, 2): (hits (K, 2), segment index (K,))."""
    a, b = path[:-1], path[1:]
    c, d = segs[:, 0], segs[:, 1]
    r = b - a
    q = d - c
    den = r[:, None, 0] * q[None, :, 1] - r[:, None, 1] * q[None, :, 0]
    ac = c[None] - a[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ac[..., 0] * q[None, :, 1] - ac[..., 1] * q[None, :, 0]) / den
        u = (ac[..., 0] * r[:, None, 1] - ac[..., 1] * r[:, None, 0]) / den
    ok = (np.abs(den) > 1e-15) & (t >= 0) & (t < 1) & (u >= 0) & (u <= 1)
    i, j = np.nonzero(ok)
    return a[i] + t[i, j, None] * r[i], j


def major_edges(outline: np.ndarray, max_angle_deg: float = 20.0, min_fraction: float = 0.3) -> np.ndarray:
    """Indices of the outline segments along the member's major axis (its long edges)."""
    P = np.asarray(outline, dtype=float)
    _, u, ext = member_axes(P)
    d = np.roll(P, -1, axis=0) - P
    L = np.linalg.norm(d, axis=1)
    cos = np.abs(d @ u) / np.maximum(L, 1e-12)
    length = ext[0, 1] - ext[0, 0]
    return np.flatnonzero((cos >= np.cos(np.radians(max_angle_deg))) & (L >= min_fraction * length))


def _window_poses(template: Template, offset: float, angle: float) -> list[tuple[str, np.ndarray]]:
    out = [("planned position", np.eye(4))]
    if offset <= 0 and angle <= 0:
        return out
    for dx, dy, dth in [
        (offset, offset, angle),
        (-offset, -offset, -angle),
        (offset, -offset, -angle),
        (-offset, offset, angle),
    ]:
        name = f"part displaced ({dx * 1e3:+.0f} mm, {dy * 1e3:+.0f} mm, {np.degrees(dth):+.0f} deg)"
        out.append((name, rigid_2d(dx, dy, dth, template.centroid)))
    return out


def rigid_2d(dx: float, dy: float, dtheta: float, centre: np.ndarray) -> np.ndarray:
    """``M`` (4, 4): rotation by ``dtheta`` about the vertical through ``centre`` (2,), then (dx, dy)."""
    c, s = np.cos(dtheta), np.sin(dtheta)
    M = np.eye(4)
    M[:2, :2] = [[c, -s], [s, c]]
    M[:2, 3] = np.asarray(centre, float)[:2] - M[:2, :2] @ np.asarray(centre, float)[:2] + [dx, dy]
    return M


def check_constraints(plan: InspectionPlan, template: Template, s: PlanSettings) -> dict:
    """Refuse (DataError naming the member and edge) a plan that cannot constrain the pose; returns the
    crossing counts per member and major edge at the planned position."""
    path = plan.xy
    report: dict = {}
    for where, M in _window_poses(template, s.check_offset, s.check_angle):
        rows, counts = [], {}
        for m in template.members:
            P = m.outline @ M[:2, :2].T + M[:2, 3]
            segs = np.stack([P, np.roll(P, -1, axis=0)], axis=1)
            hits, j = _crossings(path, segs)
            d = segs[j, 1] - segs[j, 0]
            n = np.column_stack([-d[:, 1], d[:, 0]]) / np.linalg.norm(d, axis=1, keepdims=True)
            c = template.centroid
            R = template.radius
            rows.append(np.column_stack([n, ((hits - c)[:, 0] * n[:, 1] - (hits - c)[:, 1] * n[:, 0]) / R]))
            per = {}
            for e in major_edges(P):
                k = int(np.sum(j == e))
                per[int(e)] = k
                if k < s.min_crossings:
                    a, b = segs[e] * 1e3
                    raise DataError(
                        f"the {plan.kind} inspection plan crosses member '{m.id}' edge {e} (from "
                        f"({a[0]:.0f}, {a[1]:.0f}) to ({b[0]:.0f}, {b[1]:.0f}) mm) {k} times at the {where}; "
                        f"at least {s.min_crossings} are needed to constrain the pose (§IV, Fig. 10)",
                        "widen [job.settings.plan] span, reduce its spacing or end_margin, "
                        "or use the other plan",
                    )
            counts[m.id] = per
        J = np.vstack(rows)
        w, V = np.linalg.eigh(J.T @ J)
        if w[0] < 1e-3 * w[-1]:
            weak = V[:, 0]
            what = "rotation" if abs(weak[2]) > 0.9 else f"sliding along ({weak[0]:+.2f}, {weak[1]:+.2f})"
            raise DataError(
                f"the {plan.kind} inspection plan leaves the pose free ({what}) at the {where}: the edges it "
                "crosses are (nearly) parallel: no neighbouring member fixes the sliding direction (Fig. 10)",
                "scan members that run across that direction too (widen span, or use the global plan)",
            )
        if where == "planned position":
            report = {"crossings": counts, "conditioning": float(w[0] / w[-1])}
    return report


def plan_duration(
    plan: InspectionPlan, model, T_flange_sensor: np.ndarray, T_flange_tcp: np.ndarray
) -> float:
    """Duration (s) with the robot's motion-time model (each waypoint a linear move), or length/speed."""
    if model is None:
        return plan.length / plan.speed
    T_prev = plan.tcp_poses(plan.lines[0][:1], T_flange_sensor, T_flange_tcp, plan.yaw(0))[0]
    total = 0.0
    for k in range(len(plan.lines)):
        v = plan.line_speed(k)
        for T in plan.line_tcp_poses(k, T_flange_sensor, T_flange_tcp):
            total += model.linear_move_time(T_prev, T, v, plan.accel)
            T_prev = T
    return float(total)
