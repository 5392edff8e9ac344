"""The job ``localize-and-weld`` (paper 002, Fig. 4): template -> guided placement -> inspection ->
edges -> localization -> failure check -> re-plan -> weld, with a report (docs/jobs/localize-and-weld.md).

Every robot motion goes through the safety gate; a localization that cannot be trusted (status failed or
ambiguous, mean error above 2.5 mm) stops the job before any weld with the message to weld by hand.
In the simulated cell a worker places the weldment with a random error per run (±15 mm, ±20 deg by
default, as in §V) and members that differ from CAD (±2 mm), and the weld path is measured against the
true seams.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field
from weldcell.hal.sim import world_of
from weldcell.plugins.localize import acquisition as acq
from weldcell.plugins.localize.acquisition import AcquisitionSettings
from weldcell.plugins.localize.guidance import (
    GuidanceSettings,
    centre_template,
    guide_placement,
    reachable_envelope,
)
from weldcell.plugins.localize.plans import PlanSettings, check_constraints, make_plan, plan_duration
from weldcell.plugins.localize.pose import rot2, wrap
from weldcell.plugins.localize.projector_calibration import move_to
from weldcell.plugins.localize.sim_trial import SimScanSettings
from weldcell.plugins.localize.template import Template, load_template
from weldcell.sdk.errors import DataError, DeviceError, JobError, SafetyError
from weldcell.sdk.geometry import invert
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Length, Speed


class SimWorkerSettings(Settings):
    """The simulated worker who places the weldment (simulated cell only; ignored on hardware)."""

    placement_offset: Length = Field(
        0.015, ge=0, description="placement error, uniform in ± this per axis [m]"
    )
    placement_angle: Angle = Field(0.349, ge=0, description="placement error, uniform in ± this angle [rad]")
    member_variation: Length = Field(0.002, ge=0, description="as-built members differ from CAD by up to [m]")
    placement: tuple[Length, Length, Angle] | None = Field(
        None, description="a fixed placement error (dx, dy, dtheta) instead of a random one (tests)"
    )
    placement_x: Length | None = Field(
        None,
        description="scope 'localize': a fixed placement error in x instead of a random one (studies) [m]",
    )
    placement_y: Length | None = Field(
        None,
        description="scope 'localize': a fixed placement error in y instead of a random one (studies) [m]",
    )
    placement_theta: Angle | None = Field(
        None, description="scope 'localize': a fixed placement error in theta instead of a random one [rad]"
    )


class LocalizeAndWeldSettings(Settings):
    """The job's settings (docs/jobs/localize-and-weld.md)."""

    scope: Literal["full", "localize"] = Field(
        "full",
        description="full: the whole job; localize (simulated cell only): template, the worker's placement, "
        "the plan scanned by the sensor model, edges and localization against the truth, without robot "
        "motion, projector or weld (Monte-Carlo studies: the Table 1 protocol, sim_trial.py)",
    )
    sim_scan: SimScanSettings = Field(
        default_factory=SimScanSettings, description="scope 'localize': the laser sensor model"
    )

    template: str = Field(
        "ladder",
        description="the workpiece: a template file (weldcell/template@1 .json, .dxf, .stl/.ply/.obj; "
        "relative "
        "to the profile) or a built-in flat weldment: ladder, truss, spaceframe",
    )
    template_units: str | None = Field(None, description="units of a DXF/mesh template when not in the file")
    guidance: GuidanceSettings = Field(
        default_factory=GuidanceSettings,
        description="placement guidance: envelope, projector views, fixture marks, worker confirmation",
    )
    calibrate_projector: bool = Field(
        True, description="calibrate the projector from a projected dot pattern first (simulated cell)"
    )
    plan: PlanSettings = Field(
        default_factory=PlanSettings,
        description="inspection plan: zig-zag or spiral, span, line spacing, speed",
    )
    acquisition: AcquisitionSettings = Field(
        default_factory=AcquisitionSettings,
        description="laser acquisition: rate, latency estimation, pose synchronisation",
    )
    worker: SimWorkerSettings = Field(
        default_factory=SimWorkerSettings,
        description="simulated worker only: placement error and member variation drawn per run",
    )
    execute: bool = Field(True, description="weld the re-planned path with the robot (simulated: measured)")
    weld_speed: Speed = Field(0.008, gt=0, description="travel speed along the seam [m/s]")
    allow_unobserved_members: bool = Field(
        False,
        description="weld although members were not seen by the inspection (default: such a fit fails: a "
        "member beyond the inspected envelope leaves the pose along the others unconstrained)",
    )
    approach_distance: Length = Field(0.05, gt=0, description="approach/retract distance along the torch [m]")
    seam_spacing: Length = Field(0.01, gt=0, description="spacing of the seam points handed to the path [m]")


# ------------------------------------------------------------------------------------------ template
def read_template(ctx, s: LocalizeAndWeldSettings) -> Template:
    """The template named by the settings: a file (relative to the profile) or a built-in weldment."""
    from weldcell.plugins.localize.workpieces import WORKPIECES, make_workpiece

    if s.template in WORKPIECES:
        return make_workpiece(s.template)
    path = Path(s.template)
    if not path.is_absolute():
        path = ctx.loaded.source_of(("job", "settings", "template")).parent / path
    if not path.is_file():
        raise DataError(
            f"template '{s.template}' is neither a file ({path}) nor a built-in workpiece",
            f"give a template file or one of {', '.join(WORKPIECES)}",
        )
    return load_template(path, units=s.template_units)


def sensor_mount(ctx) -> np.ndarray:
    """``T_flange_sensor`` of the laser: the profile's calibration file ``laser`` if given, else its mount."""
    from weldcell.sdk.artifacts import read_json
    from weldcell.sdk.geometry import T_from_rpy

    f = ctx.calibration_file("laser")
    if f is not None:
        return np.asarray(read_json(f)["T_flange_sensor"], float)
    m = ctx.profile.devices["laser"].mount
    if not m.parent.endswith(".flange"):
        raise DataError(
            f"the laser is mounted on '{m.parent}'; the inspection needs it on the robot's flange",
            'set [devices.laser] mount = { parent = "robot.flange", ... }',
        )
    return T_from_rpy(m.rpy, m.xyz)


def projector_mount(ctx) -> np.ndarray:
    from weldcell.sdk.geometry import T_from_rpy

    m = ctx.profile.devices["projector"].mount
    return T_from_rpy(m.rpy, m.xyz)


def is_simulated(ctx) -> bool:
    return world_of(ctx) is not None


def confirm_fn(ctx):
    """The worker's confirmation: automatic in simulation, a prompt (Enter) on hardware."""
    if is_simulated(ctx):
        return lambda msg: ctx.reporter.info(f"[dim]worker (simulated): {msg} - done[/dim]")

    def ask(msg: str) -> None:
        input(f"{msg}; press Enter when done ")

    return ask


# --------------------------------------------------------------------------------- the simulated worker
@dataclass
class TruePlacement:
    """Where the simulated worker really put the weldment: the rigid error and the as-built members."""

    pose: np.ndarray
    M: np.ndarray
    outlines: list
    welds: list

    def to_json(self) -> dict:
        return {"x": self.pose[0], "y": self.pose[1], "theta": self.pose[2], "M": self.M.tolist()}


def place_in_sim(ctx, template: Template, w: SimWorkerSettings) -> TruePlacement:
    """The simulated worker places the weldment (seeded by the cell's seed, so a resume places it again
    identically) and the world gets it as a mesh."""
    from shapely import distance, points
    from shapely.geometry import Polygon
    from weldcell.hal.sim.weldment import perturb_members, placement_error, weldment_workpiece
    from weldcell.plugins.localize.pose import pose_matrix
    from weldcell.plugins.localize.refine import fuse_across, member_axis

    rng = np.random.default_rng([ctx.profile.cell.seed, 1002])
    dx, dy, dth = (
        w.placement
        if w.placement is not None
        else placement_error(w.placement_offset, w.placement_angle, rng)
    )
    built, var = perturb_members([m.outline for m in template.members], w.member_variation, rng)
    M = pose_matrix((dx, dy, dth), template.centroid)
    outlines = [P @ M[:2, :2].T + M[:2, 3] for P in built]
    polys = [Polygon(m.outline) for m in template.members]
    welds = []
    for wd in template.welds:
        near = [i for i, p in enumerate(polys) if distance(p, points(wd.points[:, :2])).min() <= 3e-3]
        xy = wd.points[:, :2]
        if near:  # a seam lies against the side faces of the members it joins: it follows each across its
            # axis (refine.fuse_across, as synth.true_welds), not the mean of their displacements
            axes = [member_axis(template.members[i].outline) for i in near]
            disp = [var[i].displace(xy) - xy for i in near]
            xy = xy + fuse_across(disp, [np.array([-u[1], u[0]]) for u in axes])
        welds.append(np.column_stack([xy @ M[:2, :2].T + M[:2, 3], wd.points[:, 2]]))
    world = world_of(ctx)
    T_world_base = world.T_world("robot.base")
    wp = weldment_workpiece(
        outlines,
        [m.top for m in template.members],
        welds,
        [wd.id for wd in template.welds],
        table_z=template.table_z,
    )
    world.workpieces.append(wp.placed(T_world_base))
    return TruePlacement(np.array([dx, dy, dth]), M, outlines, welds)


# ------------------------------------------------------------------------------------------ inspection
def plan_inspection(ctx, template: Template, s: LocalizeAndWeldSettings, T_fs: np.ndarray):
    """The plan, refused before anything moves when it cannot constrain the pose or fails the gate."""
    robot = ctx.device("robot")
    z_sensor = sensor_height(ctx, template, s)
    plan = make_plan(template, s.plan, z_sensor, start_xy=None)
    plan.constraints = check_constraints(plan, template, s.plan)
    plan.duration = plan_duration(plan, robot.gate.model, T_fs, robot.T_flange_tcp)
    return plan


def check_transit(robot, T_tcp: np.ndarray, what: str) -> np.ndarray | None:
    """The gate's check of a transit (:func:`move_to`) from the robot's pose now; returns the joints."""
    gate, T_ft = robot.gate, robot.T_flange_tcp
    st = robot.state()
    if gate.model is None:
        return gate.check_linear(
            st.T_base_tcp, T_tcp, T_ft, robot.motion.speed, robot.motion.accel, st.q, what
        )
    q = gate.solve(T_tcp @ invert(T_ft), st.q, what)
    gate.check_joint_speed(robot.motion.joint_speed, robot.motion.joint_accel)
    for a in np.linspace(0.0, 1.0, 25):  # as Robot.move_joint checks it
        gate.check_point((gate.model.fk((1 - a) * st.q + a * q) @ T_ft)[:3, 3], f"{what} at {100 * a:.0f}%")
    return q


def check_plan_motions(robot, plan, T_fs: np.ndarray, lines: list[int], start: np.ndarray) -> None:
    """Every linear segment of the lines still to scan, through the gate, from the robot's pose now via
    ``start`` (the TCP pose at the first line's start)."""
    gate, T_ft = robot.gate, robot.T_flange_tcp
    q = check_transit(robot, start, "approach to the inspection")
    T_prev = start
    for k in lines:
        for T in plan.line_tcp_poses(k, T_fs, T_ft):
            q = gate.check_linear(T_prev, T, T_ft, plan.line_speed(k), plan.accel, q, f"inspection line {k}")
            T_prev = T


def inspect(ctx, plan, s: LocalizeAndWeldSettings, T_fs: np.ndarray) -> acq.Recording:
    """Scan every line not yet captured (checkpointed: each line saved and recorded at once)."""
    robot, laser = ctx.device("robot"), ctx.device("laser")
    done = {}
    for i, rec in enumerate(ctx.state.captures):
        if rec.get("kind") == "inspection-line" and ctx.state.check_capture(i) is None:
            done[int(rec["line"])] = rec["file"]
    todo = [k for k in range(len(plan.lines)) if k not in done]
    lines = [acq.LineRecord.load(ctx.run_dir / done[k]) for k in sorted(done)]
    world = world_of(ctx)
    if lines and world is not None:  # a resumed simulation: its clock continues after what was recorded
        world.clock.advance(max(ln.t_end for ln in lines) + 1.0 - world.clock.t)
    if todo:
        with ctx.step("check inspection motions (safety gate)"):
            first = plan.tcp_poses(plan.lines[todo[0]][:1], T_fs, robot.T_flange_tcp, plan.yaw(todo[0]))[0]
            check_plan_motions(robot, plan, T_fs, todo, start=first)
        with ctx.step("inspect", total=len(plan.lines), kind="checkpointed") as advance:
            poses = acq.pose_stream_for(robot, s.acquisition.pose_rate)
            move_to(robot, first)  # a joint move (the sensor may turn), through the gate
            poses.start()
            laser.start_stream(capacity=1 << 20)
            t_prev = None
            try:
                for k in todo:
                    spec = acq.LineSpec(
                        k,
                        plan.kinds[k],
                        plan.line_tcp_poses(k, T_fs, robot.T_flange_tcp),
                        s.plan.blend,
                        t_prev,
                        plan.line_speed(k),
                    )
                    line = acq.scan_line(robot, laser, poses, spec, plan, s.acquisition, 0.0)
                    t_prev = line.t_end
                    line.save(ctx.path(acq.line_file(k)))
                    ctx.state.add_capture(
                        {
                            "kind": "inspection-line",
                            "line": k,
                            "file": acq.line_file(k),
                            "readings": len(line.laser_t),
                        }
                    )
                    lines.append(line)
                    advance(len(lines))
            except DeviceError as e:  # keep what the failed line captured (it is scanned again on resume)
                part = getattr(e, "partial_line", None)
                if part is not None:
                    rest = laser.stop_stream()
                    part.laser_t = np.r_[part.laser_t, [r.stamp for r in rest]]
                    part.laser_d = np.r_[
                        part.laser_d, [np.nan if r.distance is None else r.distance for r in rest]
                    ]
                    name = f"inspection/partial_line_{part.index:04d}.npz"
                    part.save(ctx.path(name))
                    ctx.state.data["notes"].setdefault("partial_lines", []).append(name)
                    ctx.state.save()
                raise
            finally:
                rest = laser.stop_stream()
                poses.stop()
            if rest and lines:  # readings that arrived after the last line was saved: keep them
                last = lines[-1]
                last.laser_t = np.r_[last.laser_t, [r.stamp for r in rest]]
                last.laser_d = np.r_[
                    last.laser_d, [np.nan if r.distance is None else r.distance for r in rest]
                ]
                last.save(ctx.path(acq.line_file(last.index)))
    lines.sort(key=lambda ln: ln.index)
    rec = acq.Recording(lines, T_fs, None, {"plan": plan.kind, "levels": None})
    return rec


# ---------------------------------------------------------------------------------------- weld path
@dataclass
class CadSeam:
    """A re-planned CAD weld as a seam polyline for the path stage (approach straight down)."""

    id: str
    joint_class: str
    points: np.ndarray
    normals: np.ndarray
    closed: bool = False

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


def seams_from_welds(welds: list[dict], spacing: float) -> list[CadSeam]:
    out = []
    for w in welds:
        P = np.asarray(w["points"], float)
        L = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]
        if len(P) < 2 or L[-1] <= 0:
            continue
        t = np.linspace(0, L[-1], max(3, int(np.ceil(L[-1] / spacing)) + 1))
        pts = np.column_stack([np.interp(t, L, P[:, i]) for i in range(3)])
        out.append(CadSeam(str(w["id"]), "fillet", pts, np.tile([0.0, 0.0, -1.0], (len(pts), 1))))
    return out


def weld_path(ctx, welds: list[dict], s: LocalizeAndWeldSettings):
    seams = seams_from_welds(welds, s.seam_spacing)
    if not seams:
        raise JobError(
            "the template has no weld seam to re-plan", "add welds to the template (or derive them)"
        )
    path = ctx.stage("path")(seams, frame="base")
    for seam, cad in zip(path.seams, seams, strict=True):
        seam.id = cad.id
    return path


def measure_path(path, truth: TruePlacement | None, template: Template) -> dict:
    """Distance of each re-planned seam (its seam line) from the true seam (simulated cell)."""
    if truth is None:
        return {}
    per = []
    for seam, true in zip(path.seams, truth.welds, strict=False):
        a, b = true[0], true[-1]
        ab = b - a
        t = np.clip((seam.points - a) @ ab / max(ab @ ab, 1e-18), 0, 1)
        d = np.linalg.norm(seam.points - (a + t[:, None] * ab), axis=1)
        per.append({"seam": seam.id, "mean_mm": float(d.mean() * 1e3), "max_mm": float(d.max() * 1e3)})
    allmax = max((p["max_mm"] for p in per), default=float("nan"))
    return {"per_seam": per, "max_mm": allmax, "mean_mm": float(np.mean([p["mean_mm"] for p in per]))}


def plan_weld_motions(robot, path, speed: float, approach: float) -> list[tuple[str, str, object]]:
    """Every motion of the weld, checked through the gate from the robot's pose now before anything moves:
    per seam a joint move above its start (the torch turns there, away from the part), a linear move down,
    the torch poses at weld speed, and back up. Returns (seam id, kind, target) in order."""
    gate, T_ft = robot.gate, robot.T_flange_tcp
    st = robot.state()
    T_prev, q = st.T_base_tcp, st.q
    out: list[tuple[str, str, object]] = []
    for seam in path.seams:
        above = seam.poses[0].copy()
        above[:3, 3] -= approach * above[:3, 2]
        high = above.copy()
        high[2, 3] = max(above[2, 3], T_prev[2, 3])
        end = seam.poses[-1].copy()
        end[:3, 3] -= approach * end[:3, 2]
        try:
            if gate.model is not None:
                q_high = gate.solve(high @ invert(T_ft), q, f"seam {seam.id} approach")
                gate.check_joint_speed(robot.motion.joint_speed, robot.motion.joint_accel)
                for a in np.linspace(0.0, 1.0, 25):  # as Robot.move_joint checks it
                    gate.check_point(
                        (gate.model.fk((1 - a) * q + a * q_high) @ T_ft)[:3, 3], f"seam {seam.id} approach"
                    )
                q, first = q_high, ("joint", q_high)
            else:
                q = gate.check_linear(
                    T_prev, high, T_ft, robot.motion.speed, robot.motion.accel, q, "approach"
                )
                first = ("move", high)
            T_prev = high
            steps = [first, ("move", above), ("weld", seam.poses), ("move", end)]
            for kind, target in steps[1:]:
                v = speed if kind == "weld" else robot.motion.speed
                for T in np.reshape(target, (-1, 4, 4)):
                    q = gate.check_linear(T_prev, T, T_ft, v, robot.motion.accel, q, f"seam {seam.id} {kind}")
                    T_prev = T
        except SafetyError as e:
            raise SafetyError(
                f"seam {seam.id} cannot be welded: {e.message}; nothing was sent to the robot", e.fix
            ) from None
        out += [(seam.id, kind, target) for kind, target in steps]
    return out


def execute_weld(ctx, path, s: LocalizeAndWeldSettings) -> dict:
    robot = ctx.device("robot")
    with ctx.step("check weld motions (safety gate)"):
        motions = plan_weld_motions(robot, path, s.weld_speed, s.approach_distance)
    with ctx.step("weld", total=len(path.seams), kind="motion") as advance:
        done = 0
        for _seam, kind, target in motions:
            if kind == "joint":
                robot.move_joint(target)
            elif kind == "weld":
                robot.follow_path(target, speed=s.weld_speed)
                done += 1
                advance(done)
            else:
                robot.move_linear(target)
    return {"status": "done", "seams": len(path.seams), "dry_run": bool(ctx.profile.cell.dry_run)}


# ---------------------------------------------------------------------------------------------- run
def run(ctx) -> dict:
    """The whole job; returns the figures written into result.json."""
    from weldcell.plugins.localize import report
    from weldcell.plugins.localize.scan_io import write_laser_scan

    s: LocalizeAndWeldSettings = ctx.settings
    if s.scope == "localize":
        from weldcell.plugins.localize import sim_trial

        return sim_trial.run(ctx)
    robot = ctx.device("robot")
    T_fs = sensor_mount(ctx)
    with ctx.step("template"):
        template = read_template(ctx, s)
        template.validate()
        if s.guidance.centre_in_envelope:
            h = s.guidance.working_height or inspection_tcp_height(ctx, template, s, T_fs)
            env = reachable_envelope(robot, template.table_z, s.guidance, h)
            tcp_from_sensor = (invert(T_fs) @ robot.T_flange_tcp)[:2, 3]  # R_DOWN keeps x, flips y
            d = np.array([tcp_from_sensor[0], -tcp_from_sensor[1]])
            turns = np.radians([-90, -45, 0, 45, 90]) if s.plan.align_baseline else [0.0]  # the sensor turns
            offsets = [(0.0, 0.0)] + [tuple(rot2(a) @ d) for a in turns]
            template, clear = centre_template(template, env, s.plan.span, tuple(offsets))
            ctx.figures["planned_position"] = {
                "centroid": np.round(template.centroid, 4).tolist(),
                "envelope_clearance_m": round(clear, 4),
                "tool_height_m": h,
            }
        template.save(ctx.path("template_planned.json"))
    truth = None
    if "projector" in ctx.devices and s.guidance.enabled:
        guidance_step(ctx, template, s)
    if is_simulated(ctx):
        truth = place_in_sim(ctx, template, s.worker)
        ctx.figures["true_placement"] = truth.to_json()
    with ctx.step("inspection plan"):
        plan = plan_inspection(ctx, template, s, T_fs)
        ctx.write_json("inspection/plan.json", plan.to_json())
    ctx.figures["plan"] = {
        "kind": plan.kind,
        "lines": len(plan.lines),
        "length_m": round(plan.length, 3),
        "duration_s": round(plan.duration, 2),
    }
    rec = inspect(ctx, plan, s, T_fs)
    with ctx.step("synchronise (latency + SE(3) interpolation)"):
        if s.acquisition.latency is None:
            rec.latency, info = acq.estimate_latency(rec, template.levels(), s.acquisition.max_pose_gap)
        else:
            rec.latency, info = s.acquisition.latency, {"estimated": False, "reason": "from the settings"}
        rec.notes["latency_estimate"] = info
        acq.save_manifest(ctx.run_dir, rec)
        sync = acq.synchronise(rec, rec.latency, s.acquisition.max_pose_gap)
        scan = acq.to_laser_scan(sync)
        write_laser_scan(ctx.path("scan.csv"), scan)
    ctx.figures["acquisition"] = {
        "readings": len(scan),
        "latency_s": rec.latency,
        "latency": info,
        "dropped_outside_pose_stream": sync.dropped_outside,
        "dropped_in_pose_gaps": sync.dropped_gaps,
        "pose_gaps": sync.gaps,
    }
    with ctx.step("edges"):
        edges = ctx.stage("edges")(scan, template)
    with ctx.step("localize"):
        loc = ctx.stage("localize")(template, edges)
        require_every_member(loc, s)
        doc = loc.to_json()
        ctx.write_json("localization.json", doc)
    ctx.figures["localization"] = {
        k: doc[k] for k in ("status", "message", "x", "y", "theta", "fit_error_mean", "sigma")
    }
    if truth is not None:
        ctx.figures["localization"]["error_vs_truth"] = {
            "x_mm": (loc.pose[0] - truth.pose[0]) * 1e3,
            "y_mm": (loc.pose[1] - truth.pose[1]) * 1e3,
            "theta_deg": float(np.degrees(wrap(loc.pose[2] - truth.pose[2]))),
        }
    path = None
    if loc.ok:
        with ctx.step("re-plan weld path"):
            path = weld_path(ctx, loc.welds, s)
            path.metrics = {
                "localization": loc.status,
                "fit_error_mean": loc.fit_error_mean,
                **measure_path(path, truth, template),
            }
            path.write(ctx.path("weld_path.json"))
            ctx.figures["weld_path"] = path.metrics
        with ctx.step("export programs"):
            ctx.figures["programs"] = export_programs(ctx, path)
        if s.execute:
            ctx.figures["execute"] = execute_weld(ctx, path, s)
    if ctx.profile.output.report:
        with ctx.step("report"):
            report.write_report(ctx, template, plan, scan, edges, loc, path, truth)
    if not loc.ok:
        raise JobError(
            loc.message, "no weld was started: weld this workpiece by hand, or re-place it and run again"
        )
    return {"status": loc.status, "seams": 0 if path is None else len(path.seams)}


def require_every_member(loc, s: LocalizeAndWeldSettings) -> None:
    """The job's failure check beyond the fit's own: a member the inspection did not see makes the pose
    untrustworthy (the part may sit beyond the inspected envelope, or the member is missing)."""
    unseen = [m.id for m in loc.members if m.status == "not_observed"]
    if loc.status == "ok" and unseen and not s.allow_unobserved_members:
        loc.status = "failed"
        loc.message = (
            f"localization failed: members {', '.join(unseen)} were not seen by the inspection (the part "
            "may be placed beyond the inspected envelope, or they are missing), so the pose found "
            f"(x {loc.pose[0] * 1e3:.1f} mm, y {loc.pose[1] * 1e3:.1f} mm) cannot be trusted; check the "
            "part, widen [job.settings.plan] span, or weld this workpiece by hand"
        )


def sensor_height(ctx, template: Template, s: LocalizeAndWeldSettings) -> float:
    """Height of the laser during inspection: the highest top plus the stand-off (default mid-range)."""
    spec = getattr(ctx.device("laser"), "spec", None)
    mid = 0.5 * (spec.min_range + spec.max_range) if spec is not None else 0.15
    return max(m.top for m in template.members) + (s.plan.standoff if s.plan.standoff is not None else mid)


def inspection_tcp_height(ctx, template: Template, s: LocalizeAndWeldSettings, T_fs: np.ndarray) -> float:
    """TCP height above the table while inspecting (the envelope is computed there)."""
    from weldcell.plugins.localize.plans import R_DOWN

    T = np.eye(4)
    T[:3, :3] = R_DOWN
    T[2, 3] = sensor_height(ctx, template, s)
    return float((T @ invert(T_fs) @ ctx.device("robot").T_flange_tcp)[2, 3] - template.table_z)


def guidance_step(ctx, template: Template, s: LocalizeAndWeldSettings) -> None:
    """Projector calibration (simulated cell) and the member-by-member guidance."""
    from weldcell.plugins.localize import projector_calibration as pc

    robot, projector = ctx.device("robot"), ctx.device("projector")
    T_fp = projector_mount(ctx)
    intr = getattr(projector, "intrinsics", None)
    K = intr.K if intr is not None else np.array([[1000.0, 0, 424], [0, 1000.0, 240], [0, 0, 1]])
    size = (intr.width, intr.height) if intr is not None else (848, 480)
    cal_file = ctx.calibration_file("projector")
    if cal_file is not None:
        cal = pc.ProjectorCalibration.load(cal_file)
        K, T_fp = cal.K, cal.T_flange_projector
    elif s.calibrate_projector and hasattr(projector, "project_pixels"):
        name = "calibrate projector (dot pattern)"
        if not ctx.skip(name):
            with ctx.step(name, kind="motion"):
                poses = pc.calibration_poses(template.centroid, template.table_z, 0.6)
                views = pc.collect_views_sim(
                    robot,
                    projector,
                    poses,
                    T_fp,
                    pc.dot_pattern(*size),
                    0.3e-3,
                    np.random.default_rng(ctx.profile.cell.seed),
                )
                cal = pc.calibrate(views, size, template.table_z, K_guess=K, fix_distortion=True)
                cal.save(ctx.path("projector_calibration.json"))
        cal = pc.ProjectorCalibration.load(ctx.run_dir / "projector_calibration.json")
        K, T_fp = cal.K, cal.T_flange_projector
        ctx.figures["projector_calibration"] = {
            "rms_px": cal.rms_px,
            "landing_error_mean_mm": cal.landing_error_mean * 1e3,
            "landing_error_max_mm": cal.landing_error_max * 1e3,
        }
    if hasattr(projector, "calibration"):
        projector.calibration = (K, T_fp)
    name = "guided placement"
    if ctx.skip(name):
        return
    with ctx.step(name, total=len(template.members), kind="motion"):
        T_wb = getattr(robot, "T_world_base", np.eye(4))
        recs = guide_placement(
            robot, projector, template, T_fp, K, size, s.guidance, confirm_fn(ctx), T_world_base=T_wb
        )
        ctx.write_json("guidance.json", {"members": [r.to_json() for r in recs]})
    ctx.figures["guidance"] = [r.to_json() for r in recs]


def export_programs(ctx, path) -> list[str]:
    """The robot programs of the re-planned welds, gate-checked for the cell's robot and tool."""
    return ctx.write_programs(path.to_json(), ctx.device("robot").program_settings())


__all__ = ["LocalizeAndWeldSettings", "run", "invert"]
