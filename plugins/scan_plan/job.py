"""The ``scan-and-plan`` job (paper 000): gesture-guided scan → reconstruction → denoising →
seam extraction → 6-DOF weld path → metrics, robot programs and a report."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
from pydantic import Field
from rich.markup import escape
from weldcell.plugins.scan_plan.gesture import GestureScanController, GestureScanSettings
from weldcell.sdk.artifacts import read_json
from weldcell.sdk.cloud import drop_invalid, read_cloud, write_cloud
from weldcell.sdk.errors import DataError, DeviceError, JobError, SafetyError
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


def _retry(ctx, device, what: str, fn, attempts: int, delay: float = 0.0):
    """Call ``fn``; on a DeviceError recover the device and retry (captures are already saved).

    A recovery that itself fails (the device is still gone) counts as an attempt; attempts after the
    first wait ``delay`` seconds, doubled each time. When every attempt fails, a JobError tells how to
    resume the run.
    """
    last: DeviceError | None = None
    for k in range(attempts + 1):
        if k > 0:
            ctx.reporter.info(f"[yellow]{what}: {last.message}; reconnecting ({k}/{attempts})[/yellow]")
            if delay > 0 and k > 1:
                time.sleep(delay * 2 ** (k - 2))
            try:
                device.recover()
                device.configure()
                device.activate()
            except DeviceError as e:
                last = e
                continue
        try:
            return fn()
        except DeviceError as e:
            last = e
    raise JobError(
        f"{what}: {last.message} (after {attempts} reconnection attempt{'s' if attempts != 1 else ''})",
        f"captures so far are saved in {ctx.run_dir}; fix the device and run again with "
        f"`weldcell run {ctx.loaded.path} --resume {ctx.run_dir}`",
    ) from last


def load_captures(ctx) -> list[PosedScan]:
    """Scans recorded in state.json (after a resume), read back from the run folder."""
    scans = []
    for i, rec in enumerate(ctx.state.captures):
        f = ctx.run_dir / rec["file"]
        if not f.is_file():
            raise JobError(
                f"capture {i} of the resumed run ({rec['file']}) is missing from {ctx.run_dir}",
                "restore the file, or start a new run without --resume",
            )
        cloud = read_cloud(f, units="m", frame="camera", check_scale=False)
        scans.append(PosedScan(cloud, np.asarray(rec["T_base_flange"], dtype=float), float(rec["stamp"])))
    return scans


def gesture_scan(ctx, T_flange_camera: np.ndarray) -> list[PosedScan]:
    """Algorithm 1 in a loop: move the camera by hand gestures, capture on 'ok', stop on a fist."""
    s: ScanAndPlanSettings = ctx.settings
    robot, camera, sensor = ctx.device("robot"), ctx.device("camera"), ctx.device("gesture")
    scans = load_captures(ctx)
    resumed = len(scans)
    if scans:
        ctx.reporter.info(f"resuming with {len(scans)} capture(s) already taken")
    ctl = GestureScanController(s.gesture)
    refused = 0
    t0 = None
    with ctx.step("scan (gesture-guided)", total=s.max_captures) as advance:
        advance(len(scans), s.max_captures, "captures")
        while len(scans) < s.max_captures:
            frame = _retry(ctx, sensor, "gesture sensor", sensor.read, s.reconnects, s.reconnect_delay)
            stamp = frame.stamp
            t0 = stamp if t0 is None else t0
            if stamp - t0 > s.max_scan_time or getattr(sensor, "finished", False):
                break
            state = robot.state()
            T_base_camera = state.T_base_flange @ T_flange_camera
            cmd = ctl.update(frame, T_base_camera, stamp=stamp)
            if cmd.capture:
                depth = _retry(ctx, camera, "camera", camera.capture, s.reconnects, s.reconnect_delay)
                pose = robot.state().T_base_flange
                cloud = drop_invalid(depth.to_cloud())
                if len(cloud) < s.min_depth_points:
                    ctx.reporter.info(
                        f"[yellow]capture refused: only {len(cloud)} valid points (is the part "
                        "in view and in range?)[/yellow]"
                    )
                    continue
                name = f"scans/{len(scans):03d}.ply"
                write_cloud(ctx.path(name), cloud)
                ctx.state.add_capture(
                    {"file": name, "T_base_flange": pose.tolist(), "stamp": depth.stamp, "points": len(cloud)}
                )
                scans.append(PosedScan(cloud, pose, depth.stamp))
                advance(len(scans), s.max_captures, f"{len(cloud)} pts")
            if cmd.stop:
                break
            if cmd.target is not None:
                T_tcp = cmd.target @ invert(T_flange_camera) @ robot.T_flange_tcp
                try:
                    robot.move_linear(T_tcp)
                except SafetyError as e:
                    refused += 1
                    if refused == 1 or refused % 50 == 0:
                        ctx.reporter.info(
                            f"[yellow]gesture target refused by the safety gate: {e.message}[/yellow]"
                        )
    ctx.figures["scan"] = {"captures": len(scans), "resumed_captures": resumed, "refused_targets": refused}
    if len(scans) < s.min_captures:
        raise JobError(
            f"the scan ended with {len(scans)} capture(s); at least {s.min_captures} are needed",
            "make the 'ok' sign with the right hand while the part is in view",
        )
    return scans


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


@dataclass
class SeamMotion:
    """The motions that weld one seam: a joint move (``q_high``; a linear move to ``high`` when the robot
    has no kinematic model) to a pose above the seam start, a linear move down to ``above``, then the
    torch poses and back out through ``above`` and ``high`` at weld speed."""

    seam_id: str
    q_high: np.ndarray | None
    high: np.ndarray
    above: np.ndarray
    path: np.ndarray


def plan_execution(robot, path, speed: float, approach: float) -> list[SeamMotion]:
    """Check every motion of executing ``path`` through the robot's safety gate, from the robot's current
    state, before anything is sent: one unreachable pose anywhere refuses the whole execution.

    Raises SafetyError naming the seam and the motion; the robot has not moved.
    """
    gate, T_ft = robot.gate, robot.T_flange_tcp
    st = robot.state()
    T_prev, q = st.T_base_tcp, st.q
    lin_speed, lin_accel = robot.motion.speed, robot.motion.accel
    plans = []
    for seam in path.seams:
        try:
            above = seam.poses[0].copy()
            above[:3, 3] -= approach * above[:3, 2]
            high = above.copy()  # the approach pose at the current height: joint moves stay clear of the part
            high[2, 3] = max(above[2, 3], min(T_prev[2, 3], above[2, 3] + 0.15))
            q_high = None
            if gate.model is not None:
                q_high = gate.solve(high @ invert(T_ft), q, f"approach of {seam.id}")
                gate.check_joint_speed(robot.motion.joint_speed, robot.motion.joint_accel)
                for a in np.linspace(0.0, 1.0, 25):  # as Robot.move_joint checks it
                    T = gate.model.fk((1 - a) * q + a * q_high) @ T_ft
                    gate.check_point(T[:3, 3], f"joint move to the approach of {seam.id}")
                q = q_high
            else:
                q = gate.check_linear(T_prev, high, T_ft, lin_speed, lin_accel, q, f"approach of {seam.id}")
            q = gate.check_linear(high, above, T_ft, lin_speed, lin_accel, q, f"descent to {seam.id}")
            poses = np.concatenate([seam.poses, above[None], high[None]])
            T_seg = above
            for i, T in enumerate(poses):
                q = gate.check_linear(T_seg, T, T_ft, speed, robot.motion.accel, q, f"path segment {i}")
                T_seg = T
        except SafetyError as e:
            raise SafetyError(
                f"seam {seam.id} cannot be welded: {e.message}; nothing was sent to the robot", e.fix
            ) from None
        plans.append(SeamMotion(seam.id, q_high, high, above, poses))
        T_prev = high
    return plans


def execute(ctx, path, speed: float, approach: float) -> None:
    """Check the whole execution first (:func:`plan_execution`), then per seam: joint move above its
    start, down, and follow its torch poses (each command again through the safety gate)."""
    robot = ctx.device("robot")
    with ctx.step("check weld path motions"):
        plans = plan_execution(robot, path, speed, approach)
    with ctx.step("execute weld path", total=len(plans)) as advance:
        for i, m in enumerate(plans):
            if m.q_high is not None:
                robot.move_joint(m.q_high)
            else:
                robot.move_linear(m.high)
            robot.move_linear(m.above)
            robot.follow_path(m.path, speed=speed)
            advance(i + 1)


def ground_truth(ctx):
    """Ground-truth seams in the robot base frame when the cell is simulated, else None."""
    world = ctx.shared.get("sim.world")
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


def run(ctx) -> dict:
    """The whole job; returns the figures written into result.json."""
    from weldcell.plugins.scan_plan.report import write_report

    s: ScanAndPlanSettings = ctx.settings
    T_flange_camera, he_source = hand_eye(ctx)
    ctx.figures["hand_eye_source"] = he_source
    ctx.state.data["notes"]["hand_eye"] = {"T_flange_camera": T_flange_camera.tolist(), "source": he_source}
    ctx.state.save()
    scans = crop_to_roi(gesture_scan(ctx, T_flange_camera), T_flange_camera, s.roi_min, s.roi_max)

    with ctx.step("reconstruct (merge + linear ICP)", total=len(scans)) as advance:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rec = ctx.stage("reconstruct")(
                scans, T_flange_camera, progress=lambda i, n, msg="": advance(i, n, msg)
            )
        for w in caught:  # e.g. an ICP correction refused: the operator sees it as a line, not a traceback
            ctx.reporter.info(f"[yellow]{escape(str(w.message))}[/yellow]")
        ctx.figures["reconstruction_notes"] = [str(w.message) for w in caught]
        write_cloud(ctx.path("model.ply"), rec.cloud)
        rec.cloud.meta["viewpoints"] = [(sc.T_base_flange @ T_flange_camera)[:3, 3].tolist() for sc in scans]
    ctx.figures["reconstruction"] = {
        "points": len(rec.cloud),
        "fitness_before": rec.fitness_before,
        "fitness": rec.fitness,
        "accepted": rec.accepted,
    }
    he_fit = getattr(rec, "hand_eye", None)
    if he_fit is not None:  # anchor "hand-eye": the hand-eye error the reconstruction found
        ctx.figures["reconstruction"]["hand_eye_correction"] = he_fit.summary()
        ctx.reporter.info(f"hand-eye: {escape(he_fit.describe())}")
    with ctx.step("denoise (bilateral filter)"):
        clean = ctx.stage("denoise")(rec.cloud)
        write_cloud(ctx.path("model_denoised.ply"), clean)
    with ctx.step("seams (edge intensity)"):
        extraction = ctx.stage("seam")(clean)
    if not extraction.seams:
        raise JobError(
            "no weld seam was found on the scanned part",
            "check the scan covers the joint; lower [stages.seam.settings] t or min_seam_length",
        )
    with ctx.step("weld path (torch frames + slerp)"):
        path = ctx.stage("path")(extraction.seams, frame="base")
    gt = ground_truth(ctx)
    standoff = ctx.stage_settings("path").standoff
    with ctx.step("metrics"):
        path.metrics = {"fitness": rec.fitness, **evaluate(path, gt, standoff)}
        path.write(ctx.path("weld_path.json"))
    ctx.figures["metrics"] = path.metrics
    doc = path.to_json()
    with ctx.step("export programs"):
        written = []
        for spec in ctx.resolved["exporters"]:
            text = spec.export(doc, ctx.resolved["exporter_settings"].get(spec.name) or spec.settings())
            name = f"programs/weld_path{spec.suffix}"
            ctx.write_text(name, text)
            written.append(name)
    ctx.figures["programs"] = written
    refused: SafetyError | None = None
    if s.execute:
        try:
            execute(ctx, path, s.weld_speed, s.approach_distance)
            ctx.figures["execute"] = {"status": "done", "dry_run": bool(ctx.profile.cell.dry_run)}
        except SafetyError as e:  # reported after the report is written: nothing was sent
            ctx.figures["execute"] = {"status": "refused", "reason": e.message}
            refused = e
    if ctx.profile.output.report:
        with ctx.step("report"):
            write_report(ctx, scans, rec, clean, extraction, path, gt)
            if he_fit is not None:
                with ctx.path("summary.txt").open("a") as f:
                    f.write(f"\nhand-eye (found by the reconstruction): {he_fit.describe()}\n")
            if refused is not None:
                with ctx.path("summary.txt").open("a") as f:
                    f.write(f"\nEXECUTION REFUSED by the safety gate: {refused.message}\n")
    if refused is not None:
        raise refused
    return {"seams": len(path.seams), "captures": len(scans)}
