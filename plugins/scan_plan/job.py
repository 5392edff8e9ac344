"""The ``scan-and-plan`` job (paper 000): gesture-guided scan → reconstruction → denoising →
seam extraction → 6-DOF weld path → metrics, robot programs and a report.

The scan is :mod:`~weldcell.plugins.scan_plan.gesture_capture`, the execution on the robot
:mod:`~weldcell.plugins.scan_plan.execution`; this module composes the steps (:func:`run`).
"""

from __future__ import annotations

import warnings
from typing import Annotated

import numpy as np
from pydantic import Field
from rich.markup import escape
from weldcell.hal.sim import world_of
from weldcell.plugins.scan_plan.cloud_pipeline import plan_on_cloud
from weldcell.plugins.scan_plan.coverage import expected_coverage, partial_seams, seam_coverage
from weldcell.plugins.scan_plan.execution import EXECUTE, execute
from weldcell.plugins.scan_plan.gesture import GestureScanSettings
from weldcell.plugins.scan_plan.gesture_capture import gesture_scan
from weldcell.sdk.artifacts import read_json
from weldcell.sdk.cloud import write_cloud
from weldcell.sdk.errors import DataError, JobError, JobWarning, SafetyError
from weldcell.sdk.geometry import invert
from weldcell.sdk.scan import PosedScan
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration, Length, Speed


class ScanAndPlanSettings(Settings):
    """Settings of the scan-and-plan job."""

    gesture: GestureScanSettings = Field(
        default_factory=GestureScanSettings, description="the gesture joystick"
    )
    max_scan_time: Duration = Field(180.0, gt=0, description="end the scan after this much sensor time [s]")
    max_captures: int = Field(40, ge=1, description="end the scan after this many captures")
    min_captures: int = Field(1, ge=1, description="fewer captures than this is an error")
    reconnects: int = Field(3, ge=0, description="reconnection attempts when a device drops mid-scan")
    reconnect_delay: Duration = Field(
        0.5, ge=0, description="wait before the 2nd reconnection attempt, doubled for each further one [s]"
    )
    execute: bool = Field(False, description="follow the planned weld path with the robot (dry-run aware)")
    weld_speed: Speed = Field(0.01, gt=0, description="travel speed when executing the path [m/s]")
    min_depth_points: int = Field(500, ge=1, description="a capture with fewer valid points is refused")
    roi_min: tuple[Length, Length, Length] | None = Field(
        None, description="keep only points above this corner of the robot base frame when merging [m]"
    )
    roi_max: tuple[Length, Length, Length] | None = Field(
        None, description="keep only points below this corner of the robot base frame when merging [m]"
    )
    approach_distance: Length = Field(
        0.05, gt=0, description="joint move to this far above the seam start [m]"
    )
    min_seam_coverage: float = Field(
        0.9,
        gt=0,
        le=1,
        description="a true (simulated cell) or expected seam found over less of its length than this "
        "fraction is reported as partial, and the run exits with status 7 (a warning)",
    )
    expected_seam_lengths: list[Annotated[Length, Field(gt=0)]] | None = Field(
        None,
        description="lengths of the seams the part has (from its drawing) [m], e.g. ['493 mm']: without "
        "a simulated ground truth, the found seams (longest first) are compared with them",
    )


def read_hand_eye(path) -> np.ndarray:
    """``T_flange_camera`` from a hand-eye file (``weldcell/hand-eye@1`` or any JSON with a 4x4 ``T``)."""
    from weldcell.sdk.geometry import is_rigid

    doc = read_json(path)
    if not isinstance(doc, dict):
        raise DataError(
            f"{path}: not a hand-eye file (a JSON object with a 4x4 'T')",
            "write it with `weldcell calibrate hand-eye`",
        )
    name = doc.get("transform")
    if isinstance(name, str) and name not in ("T_flange_camera", "T_tool0_camera", "T_ee_camera"):
        raise DataError(
            f"{path}: this hand-eye result is {name}, not T_flange_camera (camera on the flange)",
            "scan-and-plan needs an eye-in-hand calibration; calibrate with config 'eye-in-hand'",
        )
    try:
        T = np.asarray(doc.get("T", doc.get("T_flange_camera")), dtype=float)
    except (TypeError, ValueError):
        T = np.zeros(0)
    if T.shape != (4, 4) or not is_rigid(T, tol=1e-4):
        raise DataError(
            f"{path}: no rigid 4x4 'T' in the hand-eye file", "write it with `weldcell calibrate hand-eye`"
        )
    units = doc.get("units", "m")
    if units != "m":
        from weldcell.sdk.cloud import UNIT_SCALE

        if units not in UNIT_SCALE:
            raise DataError(f"{path}: unknown units {units!r}", "use 'm' or 'mm'")
        T = T.copy()
        T[:3, 3] *= UNIT_SCALE[units]
    return T


def hand_eye(ctx) -> tuple[np.ndarray, str]:
    """``T_flange_camera`` from the profile's calibration file, else from the camera's mount."""
    f = ctx.calibration_file("hand_eye")
    if f is not None:
        return read_hand_eye(f), str(f)
    cam = ctx.profile.devices["camera"]
    robots = [r for r, e in ctx.profile.devices.items() if e.plugin.startswith("robot.")]
    robot_role = robots[0] if robots else "robot"
    if cam.mount.parent != f"{robot_role}.flange":
        raise JobError(
            "the camera is not mounted on the robot flange and no hand-eye calibration is given",
            "set [devices.camera.mount] parent = 'robot.flange' (eye-in-hand) or add "
            "[calibration] hand_eye = ...",
        )
    from weldcell.sdk.geometry import T_from_rpy

    return T_from_rpy(cam.mount.rpy, cam.mount.xyz), "profile mount (nominal)"


def crop_views(scans: list[PosedScan], T_flange_camera, lo, hi) -> list[tuple[int, PosedScan]]:
    """(index, cropped view) of every view with at least 10 points inside the region of interest
    (robot base frame); every view when there is no region."""
    if lo is None and hi is None:
        return list(enumerate(scans))
    out = []
    for i, sc in enumerate(scans):
        P = sc.cloud.transformed(sc.T_base_flange @ T_flange_camera).points
        keep = np.ones(len(P), dtype=bool)
        if lo is not None:
            keep &= np.all(P >= np.asarray(lo), axis=1)
        if hi is not None:
            keep &= np.all(P <= np.asarray(hi), axis=1)
        if keep.sum() >= 10:
            out.append((i, PosedScan(sc.cloud.select(keep), sc.T_base_flange, sc.timestamp)))
    return out


def crop_to_roi(scans: list[PosedScan], T_flange_camera, lo, hi) -> list[PosedScan]:
    """Drop each view's points outside the region of interest (robot base frame)."""
    out = [sc for _, sc in crop_views(scans, T_flange_camera, lo, hi)]
    if not out:
        raise JobError(
            "no capture has points inside the region of interest",
            "check [job.settings] roi_min / roi_max against where the part is",
        )
    return out


def ground_truth(ctx):
    """Ground-truth seams in the robot base frame when the cell is simulated, else None."""
    world = world_of(ctx)
    if world is None:
        return None
    T_base_world = invert(world.T_world("robot.base"))
    return [(name, s.transformed(T_base_world)) for name, s in world.seams_in_world()]


def evaluate(weld_path, gt, standoff: float) -> dict:
    """Eq. 21 (rasterized F1) and eq. 22 (pose RMSE) of every found seam against its nearest true seam.

    The pose error is measured on the seam frames themselves (origin on the seam, z = the estimated
    approach, x = travel), i.e. without the deliberate standoff, work and travel angles of the plan.
    """
    from weldcell.plugins.scan_plan.metrics import pose_rmse, seam_f1
    from weldcell.plugins.scan_plan.torch_path import torch_frames, travel_directions

    if not gt or not weld_path.seams:
        return {"seams_found": len(weld_path.seams), "seams_true": len(gt or [])}
    gt_pts = np.vstack([s.points for _, s in gt])
    pred_pts = np.vstack([s.points for s in weld_path.seams])
    out = {
        "seams_found": len(weld_path.seams),
        "seams_true": len(gt),
        "f1": seam_f1(pred_pts, gt_pts, cell=0.002, tolerance_cells=1),
    }
    per = []
    for seam in weld_path.seams:
        name, truth = min(
            gt,
            key=lambda g: float(
                np.mean(
                    np.min(
                        np.linalg.norm(seam.points[::5, None, :] - g[1].points[None, ::5, :], axis=2), axis=1
                    )
                )
            ),
        )
        approach = np.asarray(seam.extra["approach"], dtype=float)
        travel = travel_directions(seam.points, 5, seam.closed)
        frames = torch_frames(seam.points, approach, travel, standoff=0.0, work_angle=0.0, travel_angle=0.0)
        r = pose_rmse(frames, truth.points, truth.approach, truth.travel)
        per.append({"seam": seam.id, "truth": f"{name}/{truth.id}", **r})
    out["per_seam"] = per
    out["translation_rmse_mm"] = float(np.sqrt(np.mean([p["translation_m"] ** 2 for p in per])) * 1000)
    out["rotation_rmse_deg"] = float(np.degrees(np.sqrt(np.mean([p["rotation_rad"] ** 2 for p in per]))))
    return out


class PartialSeamsWarning(JobWarning):
    """The weld path was written, but a seam was found over only part of its length (exit status 7)."""


def run(ctx) -> dict:
    """The whole job; returns the figures written into result.json."""
    from weldcell.plugins.scan_plan.report import write_report

    s: ScanAndPlanSettings = ctx.settings
    T_flange_camera, he_source = hand_eye(ctx)
    ctx.figures["hand_eye_source"] = he_source
    ctx.state.data["notes"]["hand_eye"] = {"T_flange_camera": T_flange_camera.tolist(), "source": he_source}
    ctx.state.save()
    scans = crop_to_roi(gesture_scan(ctx, T_flange_camera), T_flange_camera, s.roi_min, s.roi_max)
    rec = _reconstruct(ctx, scans, T_flange_camera)
    he_fit = getattr(rec, "hand_eye", None)
    if he_fit is not None:  # anchor "hand-eye": the hand-eye error the reconstruction found
        ctx.figures["reconstruction"]["hand_eye_correction"] = he_fit.summary()
        ctx.reporter.info(f"hand-eye: {escape(he_fit.describe())}")
    planned = plan_on_cloud(
        rec.cloud,
        ctx.stage,
        step=ctx.step,
        on_denoised=lambda c: write_cloud(ctx.path("model_denoised.ply"), c),
    )
    clean, extraction, path = planned.cloud, planned.extraction, planned.path
    if path is None:
        raise JobError(
            "no weld seam was found on the scanned part",
            "check the scan covers the joint; lower [stages.seam.settings] t or min_seam_length",
        )
    gt = ground_truth(ctx)
    partial = _metrics(ctx, path, rec, gt)
    with ctx.step("export programs"):
        written = ctx.write_programs(path.to_json(), ctx.device("robot").program_settings())
    ctx.figures["programs"] = written
    refused = _execute_if_asked(ctx, path) if s.execute else None
    if ctx.profile.output.report:
        notes = []
        if he_fit is not None:
            notes.append(f"hand-eye (found by the reconstruction): {he_fit.describe()}")
        if refused is not None:
            notes.append(f"EXECUTION REFUSED by the safety gate: {refused.message}")
        notes += [f"PARTIAL {line}" for line in partial]
        with ctx.step("report"):
            write_report(ctx, scans, rec, clean, extraction, path, gt, notes=notes)
    if refused is not None:
        raise refused
    if partial:  # everything is written; the exit status says the path covers only part of a seam
        ctx.figures["seams_partial"] = partial
        raise PartialSeamsWarning(
            f"{len(partial)} seam(s) found over less than {100 * s.min_seam_coverage:.0f} % of their "
            f"length: " + "; ".join(partial),
            "the weld path was written for the parts found; check the scan shows the whole joint (more "
            "views along it), or lower [settings] min_seam_coverage to accept partial seams",
        )
    return {"seams": len(path.seams), "captures": len(scans)}


def _reconstruct(ctx, scans: list[PosedScan], T_flange_camera: np.ndarray):
    """The reconstruct stage on the cropped views; its warnings become report lines; writes model.ply."""
    with ctx.step("reconstruct (merge + linear ICP)", total=len(scans)) as advance:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rec = ctx.stage("reconstruct")(
                scans, T_flange_camera, progress=lambda i, n, msg="": advance(i, n, msg)
            )
        for w in caught:  # e.g. an ICP correction refused: the operator sees it as a line, not a traceback
            ctx.reporter.info(f"[yellow]{escape(str(w.message))}[/yellow]")
        ctx.figures["reconstruction_notes"] = [str(w.message) for w in caught]
        if rec.cloud.viewpoints is None:  # a reconstruct stage that does not say where the cameras were
            eyes = [(sc.T_base_flange @ T_flange_camera)[:3, 3] for sc in scans]
            rec.cloud = rec.cloud.with_viewpoints(eyes)
        write_cloud(ctx.path("model.ply"), rec.cloud)
    ctx.figures["reconstruction"] = {
        "points": len(rec.cloud),
        "fitness_before": rec.fitness_before,
        "fitness": rec.fitness,
        "accepted": rec.accepted,
    }
    return rec


def _metrics(ctx, path, rec, gt) -> list[str]:
    """Eqs. 20-22 and the seam coverage into the weld path's metrics; writes weld_path.json. Returns one
    line per seam found over less than ``min_seam_coverage`` of its length."""
    s: ScanAndPlanSettings = ctx.settings
    standoff = ctx.stage_settings("path").standoff
    with ctx.step("metrics"):
        path.metrics = {"fitness": rec.fitness, **evaluate(path, gt, standoff)}
        if gt:
            coverage = seam_coverage(path, gt)
        elif s.expected_seam_lengths:
            coverage = expected_coverage(path, list(s.expected_seam_lengths))
        else:
            coverage = []
        partial = partial_seams(coverage, s.min_seam_coverage)
        if coverage:
            path.metrics["coverage"] = coverage
            path.metrics["seams_partial"] = len(partial)
        path.write(ctx.path("weld_path.json"))
    ctx.figures["metrics"] = path.metrics
    for line in partial:
        ctx.reporter.info(f"[yellow]PARTIAL {escape(line)}[/yellow]")
    return partial


def _execute_if_asked(ctx, path) -> SafetyError | None:
    """Weld the path (:func:`~weldcell.plugins.scan_plan.execution.execute`); the gate's refusal is
    returned, to be raised after the report is written (nothing was sent)."""
    s: ScanAndPlanSettings = ctx.settings
    try:
        execute(ctx, path, s.weld_speed, s.approach_distance)
        ctx.figures["execute"] = {
            "status": "done",
            "dry_run": bool(ctx.profile.cell.dry_run),
            "attempt": ctx.state.steps[EXECUTE].get("attempts", 1),
        }
    except SafetyError as e:  # reported after the report is written: nothing was sent
        ctx.figures["execute"] = {"status": "refused", "reason": e.message}
        return e
    return None
