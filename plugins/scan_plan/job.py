"""The ``scan-and-plan`` job (paper 000): gesture-guided scan → reconstruction → denoising →
seam extraction → 6-DOF weld path → metrics, robot programs and a report."""

from __future__ import annotations

import re
import time
import warnings
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import Field
from rich.markup import escape
from weldcell.hal.sim import world_of
from weldcell.plugins.scan_plan.coverage import expected_coverage, partial_seams, seam_coverage
from weldcell.plugins.scan_plan.gesture import GestureScanController, GestureScanSettings
from weldcell.sdk.artifacts import read_json, sha256_file
from weldcell.sdk.cloud import drop_invalid, read_cloud, write_cloud
from weldcell.sdk.errors import DataError, DeviceError, JobError, JobWarning, SafetyError
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


def _plain(e: DeviceError) -> str:
    """A device error's message for the operator: without an embedded API hint ('fix: call recover()')."""
    return re.split(r"\s+fix:\s", e.message)[0]


def _retry(ctx, device, what: str, fn, attempts: int, delay: float = 0.0):
    """Call ``fn``; on a DeviceError recover the device and retry (captures are already saved).

    A recovery that itself fails (the device is still gone) counts as an attempt; attempts after the
    first wait ``delay`` seconds, doubled each time. When every attempt fails, a JobError tells how to
    resume the run.
    """
    last: DeviceError | None = None
    for k in range(attempts + 1):
        if k > 0:
            line = f"{what}: {_plain(last)}; reconnecting ({k}/{attempts})"
            ctx.reporter.info(f"[yellow]{escape(line)}[/yellow]")
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
        f"{what}: {_plain(last)} (after {attempts} reconnection attempt{'s' if attempts != 1 else ''})",
        f"captures so far are saved in {ctx.run_dir}; fix the device and run again with "
        f"`weldcell run {ctx.loaded.path} --resume {ctx.run_dir}`",
    ) from last


SCAN = "scan (gesture-guided)"
EXECUTE = "execute weld path"
CHECK = "check weld path motions"


def _to_json(v):
    if isinstance(v, np.ndarray):
        return {"array": v.tolist()}
    if isinstance(v, tuple):
        return {"tuple": [_to_json(x) for x in v]}
    if isinstance(v, np.generic):
        return v.item()
    return v


def _from_json(v):
    if isinstance(v, dict) and "array" in v:
        return np.asarray(v["array"], dtype=float)
    if isinstance(v, dict) and "tuple" in v:
        return tuple(_from_json(x) for x in v["tuple"])
    return v


def controller_state(ctl: GestureScanController) -> dict:
    """The controller's running state (smoothed palm, hold timers, clutch, ...), exactly, as JSON."""
    return {k: _to_json(v) for k, v in vars(ctl).items() if k.startswith("_")}


def restore_controller(ctl: GestureScanController, state: dict) -> None:
    """Put a :func:`controller_state` snapshot back."""
    for k, v in state.items():
        if k.startswith("_") and hasattr(ctl, k):
            setattr(ctl, k, _from_json(v))


def _replays_script(sensor) -> bool:
    """A gesture sensor that replays a script (the simulated hand) starts it again when reopened; a
    live tracker simply continues with the operator's hand."""
    return getattr(sensor, "player", None) is not None


def _generator_state(device) -> dict | None:
    """The random generator state of a simulated device (its noise), so a resumed scan continues it."""
    rng = getattr(device, "rng", None)
    return rng.bit_generator.state if isinstance(rng, np.random.Generator) else None


def load_captures(ctx) -> list[PosedScan]:
    """Scans recorded in state.json (after a resume), each verified against its recorded size and
    SHA-256 and read back from the run folder.

    A damaged capture while the scan is still open is taken out (with the ones after it; their files
    are kept, renamed) and the scan continues from the capture before it. When the scan had finished, a
    damaged capture stops the run with an error: re-scanning moves the robot, so it needs ``--redo scan``.
    """
    st = ctx.state
    bad = st.first_damaged_capture()
    if bad is not None:
        i, problem = bad
        if st.step_done(SCAN) and not ctx.redoing(SCAN):
            raise DataError(
                f"{problem}; the scan had finished, so it is not taken again automatically",
                f"restore the file, or re-scan from capture {i} on (the {i} before it are kept) with "
                f"`{ctx.resume_command} --redo scan`",
            )
        n = len(st.captures) - i
        ctx.reporter.info(
            f"[yellow]{escape(problem)}: it is captured again ({n} capture(s) taken out)[/yellow]"
        )
        st.discard_captures(i, problem)
    elif ctx.redoing(SCAN) and st.captures:
        ctx.reporter.info(f"--redo scan: {len(st.captures)} earlier capture(s) set aside, scanning again")
        st.discard_captures(0, "--redo scan")
    scans = []
    for rec in st.captures:
        f = ctx.run_dir / rec["file"]
        cloud = read_cloud(f, units="m", frame="camera", check_scale=False)
        if "points" in rec and len(cloud) != rec["points"]:
            raise DataError(
                f"capture {rec['file']} holds {len(cloud)} points, {rec['points']} were recorded",
                f"restore the file, or re-scan with `{ctx.resume_command} --redo scan`",
            )
        scans.append(PosedScan(cloud, np.asarray(rec["T_base_flange"], dtype=float), float(rec["stamp"])))
    return scans


class _ScanClock:
    """Scan time: sensor time since the scan began, continued across resumes (stamps restart)."""

    def __init__(self, base: float = 0.0, gap: float = 0.0) -> None:
        self.base, self.gap, self.first = base, gap, None

    def __call__(self, stamp: float) -> float:
        if self.first is None:
            self.first = stamp
        return self.base + self.gap + (stamp - self.first)


def _continue_scan(ctx, ctl, robot, sensor, camera, read) -> _ScanClock:
    """Put the scan back where its last capture left it: controller state, the simulated hand's script
    position and noise generators, and the robot at that capture's joints (one gated joint move)."""
    if not ctx.state.captures:
        return _ScanClock()
    last = ctx.state.captures[-1]
    if "controller" not in last:  # a run folder from before checkpoints: continue from here
        return _ScanClock(float(last.get("scan_time", 0.0)), 1.0 / ctl.rate_hint)
    restore_controller(ctl, last["controller"])
    if _replays_script(sensor):
        # the hand script replays from its start: skip the frames the scan already used, timing them
        # as the first attempt did (scan time counts from the script's first frame)
        clock = _ScanClock()
        for _ in range(int(last["frames"])):
            clock(read().stamp)
    else:  # a live tracker: the operator's hand continues now
        clock = _ScanClock(float(last["scan_time"]), 1.0 / ctl.rate_hint)
    replay = last.get("replay") or {}
    if replay.get("camera_rng") is not None and _generator_state(camera) is not None:
        camera.rng.bit_generator.state = replay["camera_rng"]
    q = np.asarray(last.get("q", []), dtype=float)
    now = robot.state().q
    if q.shape == now.shape and np.max(np.abs(q - now)) > 1e-6:
        ctx.reporter.info(f"returning the robot to where capture {len(ctx.state.captures) - 1} was taken")
        robot.move_joint(q)
    return clock


def gesture_scan(ctx, T_flange_camera: np.ndarray) -> list[PosedScan]:
    """Algorithm 1 in a loop: move the camera by hand gestures, capture on 'ok', stop on a fist.

    Every capture is a checkpoint (file + size + SHA-256, pose, joints, scan time, gesture frames used,
    controller state): a resumed scan continues after the last one, never capturing a view twice.
    """
    s: ScanAndPlanSettings = ctx.settings
    robot, camera, sensor = ctx.device("robot"), ctx.device("camera"), ctx.device("gesture")
    scans = load_captures(ctx)
    resumed = len(scans)
    if ctx.state.step_done(SCAN) and not ctx.redoing(SCAN):
        ctx.reporter.info(f"scan: done in an earlier attempt ({len(scans)} captures), not repeated")
        ctx.figures["scan"] = {"captures": len(scans), "resumed_captures": resumed, "refused_targets": 0}
        return scans
    if scans:
        ctx.reporter.info(f"resuming with {len(scans)} capture(s) already taken")

    def retry(device, what, fn):
        return _retry(ctx, device, what, fn, s.reconnects, s.reconnect_delay)

    # gesture frames read since the scan began (a scripted sensor's resume re-reads them from 0)
    frames = int(ctx.state.captures[-1].get("frames", 0)) if scans and not _replays_script(sensor) else 0

    def read():
        nonlocal frames
        frame = retry(sensor, "gesture sensor", sensor.read)
        frames += 1
        return frame

    ctl = GestureScanController(s.gesture)
    refused = 0
    with ctx.step(SCAN, total=s.max_captures, kind="checkpointed") as advance:
        clock = _continue_scan(ctx, ctl, robot, sensor, camera, read)
        advance(len(scans), s.max_captures, "captures")
        while len(scans) < s.max_captures:
            frame = read()
            t = clock(frame.stamp)
            if t > s.max_scan_time or getattr(sensor, "finished", False):
                break
            state = retry(robot, "robot", robot.state)
            cmd = ctl.update(frame, state.T_base_flange @ T_flange_camera, stamp=t)
            if cmd.capture:
                depth = retry(camera, "camera", camera.capture)
                state = retry(robot, "robot", robot.state)
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
                    {
                        "file": name,
                        "T_base_flange": state.T_base_flange.tolist(),
                        "q": state.q.tolist(),
                        "stamp": depth.stamp,
                        "points": len(cloud),
                        "scan_time": t,
                        "frames": frames,
                        "controller": controller_state(ctl),
                        "replay": {"camera_rng": _generator_state(camera)},
                    }
                )
                scans.append(PosedScan(cloud, state.T_base_flange, depth.stamp))
                advance(len(scans), s.max_captures, f"{len(cloud)} pts")
            if cmd.stop:
                break
            if cmd.target is not None:
                T_tcp = cmd.target @ invert(T_flange_camera) @ robot.T_flange_tcp
                try:
                    retry(robot, "robot", lambda T=T_tcp: robot.move_linear(T))
                except SafetyError as e:
                    refused += 1
                    if refused == 1 or refused % 50 == 0:
                        ctx.reporter.info(  # expected while following a hand: the gate keeps the arm safe
                            "gesture target refused by the safety gate (expected now and then: the camera "
                            f"stays where it is and follows the next target): {e.message}"
                        )
        if len(scans) < s.min_captures:
            raise JobError(
                f"the scan ended with {len(scans)} capture(s); at least {s.min_captures} are needed",
                "make the 'ok' sign with the right hand while the part is in view",
            )
    ctx.figures["scan"] = {"captures": len(scans), "resumed_captures": resumed, "refused_targets": refused}
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
                gate.check_joint_move(  # exactly what Robot.move_joint checks
                    q,
                    q_high,
                    T_ft,
                    robot.motion.joint_speed,
                    robot.motion.joint_accel,
                    f"joint move to the approach of {seam.id}",
                )
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
    start, down, and follow its torch poses (each command again through the safety gate).

    A ``motion`` step: done in an earlier attempt it is not repeated (nor checked again); interrupted part
    way it stops the resume (the part may be welded in part) until the operator asks ``--redo execute``.
    """
    robot = ctx.device("robot")
    if ctx.skip(EXECUTE):
        before = ctx.state.steps[EXECUTE].get("weld_path_sha256")
        if before and before != sha256_file(ctx.run_dir / "weld_path.json"):
            ctx.reporter.info(
                "[yellow]the weld path computed now differs from the one executed earlier; the earlier "
                "execution stands (--redo execute to weld this one)[/yellow]"
            )
        return
    with ctx.step(CHECK):
        plans = plan_execution(robot, path, speed, approach)
    with ctx.step(EXECUTE, total=len(plans), kind="motion") as advance:
        ctx.state.set_step(
            EXECUTE,
            weld_path_sha256=sha256_file(ctx.run_dir / "weld_path.json"),
            progress=f"0 of {len(plans)} seams welded",
        )
        for i, m in enumerate(plans):
            ctx.state.set_step(EXECUTE, progress=f"{i} of {len(plans)} seams welded, {m.seam_id} started")
            if m.q_high is not None:
                robot.move_joint(m.q_high)
            else:
                robot.move_linear(m.high)
            robot.move_linear(m.above)
            robot.follow_path(m.path, speed=speed)
            ctx.state.set_step(EXECUTE, progress=f"{i + 1} of {len(plans)} seams welded")
            advance(i + 1)


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
    doc = path.to_json()
    with ctx.step("export programs"):
        written = ctx.write_programs(doc, ctx.device("robot").program_settings())
    ctx.figures["programs"] = written
    refused: SafetyError | None = None
    if s.execute:
        try:
            execute(ctx, path, s.weld_speed, s.approach_distance)
            ctx.figures["execute"] = {
                "status": "done",
                "dry_run": bool(ctx.profile.cell.dry_run),
                "attempt": ctx.state.steps[EXECUTE].get("attempts", 1),
            }
        except SafetyError as e:  # reported after the report is written: nothing was sent
            ctx.figures["execute"] = {"status": "refused", "reason": e.message}
            refused = e
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
