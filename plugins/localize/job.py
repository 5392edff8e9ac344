"""The job ``localize-and-weld`` (paper 002, Fig. 4): template -> guided placement -> inspection ->
edges -> localization -> failure check -> re-plan -> weld, with a report (docs/jobs/localize-and-weld.md).

Every robot motion goes through the safety gate; a localization that cannot be trusted (status failed or
ambiguous, mean error above 2.5 mm) stops the job before any weld with the message to weld by hand.
In the simulated cell a worker places the weldment with a random error per run (±15 mm, ±20 deg by
default, as in §V) and members that differ from CAD (±2 mm), and the weld path is measured against the
true seams.

This module runs the steps in order; they live in ``job_settings.py`` (settings), ``sim_worker.py`` (the
simulated placement), ``inspection.py`` (plan, gate checks, scan) and ``welding.py`` (re-plan, weld).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from weldcell.hal.sim import world_of
from weldcell.plugins.localize import acquisition as acq
from weldcell.plugins.localize.guidance import (
    centre_template,
    guide_placement,
    reachable_envelope,
)
from weldcell.plugins.localize.inspection import (  # noqa: F401  (re-exported: the job's old public names)
    check_plan_motions,
    check_transit,
    inspect,
    inspection_tcp_height,
    plan_inspection,
    sensor_height,
)
from weldcell.plugins.localize.job_settings import LocalizeAndWeldSettings, SimWorkerSettings  # noqa: F401
from weldcell.plugins.localize.pose import rot2, wrap
from weldcell.plugins.localize.sim_worker import TruePlacement, place_in_sim  # noqa: F401
from weldcell.plugins.localize.template import Template, load_template
from weldcell.plugins.localize.welding import (  # noqa: F401  (re-exported: the job's old public names)
    CadSeam,
    execute_weld,
    export_programs,
    measure_path,
    plan_weld_motions,
    seams_from_welds,
    weld_path,
)
from weldcell.sdk.errors import DataError, JobError
from weldcell.sdk.geometry import invert


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


# ---------------------------------------------------------------------------------------------- run
def run(ctx) -> dict:
    """The whole job; returns the figures written into result.json."""
    from weldcell.plugins.localize import report

    s: LocalizeAndWeldSettings = ctx.settings
    if s.scope == "localize":
        from weldcell.plugins.localize import sim_trial

        return sim_trial.run(ctx)
    T_fs = sensor_mount(ctx)
    with ctx.step("template"):
        template = planned_template(ctx, s, T_fs)
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
        scan, acquisition = synchronised_scan(ctx, rec, template, s)
    ctx.figures["acquisition"] = acquisition
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


def planned_template(ctx, s: LocalizeAndWeldSettings, T_fs: np.ndarray) -> Template:
    """The template, validated and (``centre_in_envelope``) moved to the middle of the robot's reachable
    envelope at the inspection height; saved as ``template_planned.json``."""
    robot = ctx.device("robot")
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
    return template


def synchronised_scan(ctx, rec: acq.Recording, template: Template, s: LocalizeAndWeldSettings):
    """The laser scan in the base frame: the latency (estimated unless given), then every reading at its
    SE(3)-interpolated pose (written as ``scan.csv``), and the acquisition's figures."""
    from weldcell.plugins.localize.scan_io import write_laser_scan

    if s.acquisition.latency is None:
        rec.latency, info = acq.estimate_latency(rec, template.levels(), s.acquisition.max_pose_gap)
    else:
        rec.latency, info = s.acquisition.latency, {"estimated": False, "reason": "from the settings"}
    rec.notes["latency_estimate"] = info
    acq.save_manifest(ctx.run_dir, rec)
    sync = acq.synchronise(rec, rec.latency, s.acquisition.max_pose_gap)
    scan = acq.to_laser_scan(sync)
    write_laser_scan(ctx.path("scan.csv"), scan)
    figures = {
        "readings": len(scan),
        "latency_s": rec.latency,
        "latency": info,
        "dropped_outside_pose_stream": sync.dropped_outside,
        "dropped_in_pose_gaps": sync.dropped_gaps,
        "pose_gaps": sync.gaps,
    }
    return scan, figures


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


__all__ = ["LocalizeAndWeldSettings", "run", "invert"]
