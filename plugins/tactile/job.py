"""The ``tactile-track`` job (paper 003 §2.2, Algorithm 2): track a seam's side wall with the SRM tool.

At camera rate: capture the in-finger image →
:class:`~weldcell.plugins.tactile.marker.MarkerDisplacementEstimator` (tag displacement → tip deflection δ
through the SRM's tag gains) → :meth:`TactileSeamServo.step` → the twist
``[vx, vy, vz, 0, 0, ω]`` of the TCP (the SRM tip's undeformed centre) → ``robot.speed_linear`` through the
HAL safety gate. A command the gate refuses (e.g. the seam runs out of the ``[cell.safety]`` box), a lost
marker or an overload is a **safe stop**: the robot stops, everything recorded so far is written, and the
run fails with a message that says why and where.

The planned path comes from a ``weldcell/weld-path@1`` file (``plan_file``) or from the run's own vision
step: one scan of the fixed depth camera, mapped to the robot base with the hand-eye (``[calibration]
hand_eye``, an eye-on-base ``T_base_camera``), denoised and searched for seams by the profile's stages.

Writes ``tactile_track.json`` (``weldcell/tactile-track@1``), ``refined_path.json``
(``weldcell/weld-path@1``: the seam found by touch, with torch poses), ``fig13_paths.png``,
``deformation_over_time.png``, ``error_along_seam.png`` (simulated cell), ``summary.txt`` and
``report/report.html`` (plugins/tactile/report.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field
from weldcell.hal.sim import world_of
from weldcell.sdk.cloud import PointCloud, write_cloud
from weldcell.sdk.errors import DataError, DeviceError, JobError, SafetyError
from weldcell.sdk.geometry import frame_from_axes, invert, transform_points
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Duration, Frequency, Length, Speed
from weldcell.sdk.weldpath import SeamPath, WeldPath

from . import report as tactile_report
from .paths import Polyline, left_normal
from .servo import ServoSettings, TactileSeamServo, seam_from_tip_path
from .srm_model import SRMParams, tip_deflection_from_tag

SCHEMA = "weldcell/tactile-track@1"
Vec3 = tuple[Length, Length, Length]
NORMAL_ENDS = ("contact lost", "end of planned path")


# -- settings ------------------------------------------------------------------------------------


class SRMToolSettings(Settings):
    """The SRM finger's calibration as the job uses it: tag, camera-in-tool and tag-to-tip gains."""

    marker_size: Length = Field(0.010, gt=0, description="side of the tag's black square [m]")
    marker_id: int = Field(0, ge=0, description="ArUco id of the tag")
    dictionary: str = Field("DICT_4X4_50", description="ArUco dictionary of the tag")
    tag_gain: float = Field(
        0.85, gt=0, description="calibrated tag translation per metre of lateral tip deflection"
    )
    tag_axial_gain: float = Field(
        0.6, gt=0, description="calibrated tag translation per metre of axial deflection"
    )
    camera_rpy: tuple[Angle, Angle, Angle] = Field(
        (0.0, 0.0, 0.0), description="in-finger camera orientation in the tool frame [rad] (default: aligned)"
    )
    filter: Literal["one-euro", "none"] = Field("one-euro", description="smoothing of the tag displacement")
    min_cutoff: float = Field(3.0, gt=0, description="One-Euro cut-off at rest [Hz]")
    beta: float = Field(200.0, ge=0, description="One-Euro speed coefficient [s/m]")
    max_reprojection_error: float = Field(
        1.5, gt=0, description="tag poses re-projecting worse are lost [px]"
    )
    rest_frames: int = Field(5, ge=1, description="contact-free frames averaged for the tag's rest pose")


class ScanSettings(Settings):
    """The vision step: one scan of the fixed depth camera, seams in the robot base frame."""

    roi_min: Vec3 = Field(
        (-1.0, -1.0, -0.05), description="keep scan points above this corner, base frame [m]"
    )
    roi_max: Vec3 = Field((1.0, 1.0, 1.0), description="keep scan points below this corner, base frame [m]")
    park_xyz: Vec3 | None = Field(
        None,
        description="flange position to park at before scanning (out of the "
        "camera's view), base frame [m]; default: stay",
    )
    park_rpy: tuple[Angle, Angle, Angle] = Field(
        (3.14159265, 0.0, 0.0), description="flange orientation when parked [rad]"
    )
    min_points: int = Field(2000, ge=10, description="fewer valid points in the ROI is an error")
    wall_band: Length = Field(0.02, gt=0, description="how far beside a seam to look for its wall [m]")
    wall_rise: Length = Field(0.004, gt=0, description="points this far above the seam count as its wall [m]")
    min_wall_points: int = Field(30, ge=1, description="a seam with fewer wall points is not trackable")


class TrackSettings(Settings):
    """How the SRM tool is brought to the seam and driven along it."""

    plan_file: str | None = Field(
        None,
        description="weld-path@1 file with the planned seam (relative to the "
        "profile); default: the run's own vision step",
    )
    seam_id: str | None = Field(None, description="seam of the plan file to track; default: the first")
    rate: Frequency = Field(50.0, gt=0, description="in-finger camera rate = control rate [Hz]")
    command_duration: Duration | None = Field(
        None, gt=0, description="duration of each velocity command [s]; default 1/rate"
    )
    max_time: Duration | None = Field(
        None,
        gt=0,
        description="longest tracking time [s]; default from the plan's length and the servo speed",
    )
    tip_height: Length = Field(
        0.0035, gt=0, description="height of the tip centre (TCP) above the seam line [m]"
    )
    start_inset: Length = Field(
        0.005, ge=0, description="start this far along the plan from its first point [m]"
    )
    approach_clearance: Length = Field(
        0.004,
        ge=0,
        description="start this far from the planned seam, on the "
        "free side (the servo then seeks the wall) [m]",
    )
    approach_height: Length = Field(
        0.03,
        gt=0,
        description="come down to the start from this high [m]; the tag's rest pose is captured there",
    )
    approach_speed: Speed = Field(0.05, gt=0, description="speed of the approach and retract moves [m/s]")
    retract: Length = Field(0.03, ge=0, description="lift the tool this much after the stop [m]")
    srm: SRMToolSettings = Field(default_factory=SRMToolSettings, description="the SRM finger's calibration")
    fail_on_safe_stop: bool = Field(
        True,
        description="a safe stop (safety gate, lost marker, overload) fails "
        "the run after writing what was recorded",
    )
    plots: bool = Field(True, description="write the figures")


class TactileTrackSettings(TrackSettings):
    """Settings of the ``tactile-track`` job."""

    scan: ScanSettings = Field(
        default_factory=ScanSettings, description="the vision step (without plan_file)"
    )


# -- the servo stage -----------------------------------------------------------------------------


class SRMServoStage:
    """The ``tactile.srm-servo`` stage: builds Algorithm 2's controller for a planned path."""

    def __init__(self, settings: ServoSettings) -> None:
        self.settings = settings

    def __call__(self, planned_points: np.ndarray, gate=None) -> TactileSeamServo:
        return TactileSeamServo(planned_points, self.settings, gate)


# -- plan ----------------------------------------------------------------------------------------


@dataclass
class Plan:
    """A planned seam line (K, 3) in the base frame, ordered so that the wall is on the servo's side."""

    points: np.ndarray
    source: str
    info: dict[str, Any] = field(default_factory=dict)


def wall_evidence(cloud_pts: np.ndarray, seam_pts: np.ndarray, band: float, rise: float) -> tuple[int, int]:
    """Points of a wall standing beside the seam: (count on the left of travel, count on the right)."""
    line = Polyline(seam_pts, "seam")
    P = np.asarray(cloud_pts, dtype=float)
    near = line.distances(P) < band
    left = right = 0
    for p in P[near][:: max(1, int(near.sum()) // 4000)]:
        pr = line.project(p)
        if pr.before_start or pr.past_end or p[2] < pr.point[2] + rise:
            continue
        side = float((p[:2] - pr.point[:2]) @ left_normal(pr.tangent))
        left += side > 0
        right += side < 0
    return left, right


def orient_plan(points: np.ndarray, wall_side: str, wall_left: bool) -> np.ndarray:
    """Reverse the seam if needed so that its wall is on ``wall_side`` of travel."""
    return points if (wall_left == (wall_side == "left")) else points[::-1].copy()


def plan_from_file(path: Path, seam_id: str | None) -> np.ndarray:
    wp = WeldPath.from_json(path)
    if wp.frame not in ("base", "robot.base"):
        raise DataError(
            f"{path}: the plan is in frame '{wp.frame}'", "give a weld path in the robot base frame"
        )
    seams = [s for s in wp.seams if seam_id is None or s.id == seam_id]
    if not seams:
        raise DataError(
            f"{path}: no seam {seam_id!r} (seams: {[s.id for s in wp.seams]})",
            "set [job.settings] seam_id to one of them",
        )
    return np.asarray(seams[0].points, dtype=float)


def _goto(robot, T_tcp: np.ndarray, speed: float | None = None) -> None:
    """Joint move through the gate when the kinematics are known (no straight-line singularity issues)."""
    if robot.gate.model is not None:
        T_flange = T_tcp @ invert(robot.T_flange_tcp)
        robot.gate.check_point(T_tcp[:3, 3], "tactile approach")
        robot.move_joint(robot.gate.solve(T_flange, robot.state().q, "tactile approach"))
    else:
        robot.move_linear(T_tcp, speed=speed)


def scan_for_seam(
    ctx,
    camera,
    T_base_camera: np.ndarray,
    s: ScanSettings,
    wall_side: str,
    truth_seams: list[np.ndarray] | None = None,
    prefix: str = "",
) -> Plan:
    """One scan → base frame (with the GIVEN hand-eye) → ROI → denoise → seams → the seam with a wall."""
    robot = ctx.device("robot")
    P = _recorded_scan(ctx, prefix)
    if P is None and s.park_xyz is not None:
        from weldcell.sdk.geometry import T_from_rpy

        with ctx.step(f"{prefix}park the robot out of the camera's view", kind="checkpointed"):
            _goto(robot, T_from_rpy(s.park_rpy, s.park_xyz) @ robot.T_flange_tcp)
    if P is None:
        with ctx.step(f"{prefix}scan the part", kind="checkpointed"):
            frame = camera.capture()
            cam_pts = frame.to_cloud().points
            P = transform_points(T_base_camera, cam_pts)
            keep = np.all((P >= np.asarray(s.roi_min)) & (P <= np.asarray(s.roi_max)), axis=1)
            P = P[keep]
            write_cloud(ctx.path("scan_base.ply"), PointCloud(P, frame="base"))
            if len(P) < s.min_points:
                raise JobError(
                    f"the scan has only {len(P)} points inside the part's ROI (need {s.min_points})",
                    "check [job.settings.scan] roi_min/roi_max (robot base frame) and that the part is "
                    "in the camera's view",
                )
            # a checkpoint: a resumed run reuses this scan instead of parking and scanning again
            rec = {"kind": "scan", "prefix": prefix, "file": "scan_base.ply", "points": len(P)}
            ctx.state.add_capture(rec)
    with ctx.step(f"{prefix}seams (denoise + edge intensity)"):
        view = transform_points(T_base_camera, np.zeros((1, 3)))
        clean = ctx.stage("denoise")(PointCloud(P, frame="base", meta={"viewpoints": view}))
        extraction = ctx.stage("seam")(clean)
    candidates = []
    for seam in extraction.seams:
        left, right = wall_evidence(clean.points, seam.points, s.wall_band, s.wall_rise)
        candidates.append((max(left, right), left > right, seam))
    info = {
        "seams_found": len(candidates),
        "candidates": [
            {
                "id": int(c[2].id),
                "joint": c[2].joint_class,
                "length_mm": 1e3 * c[2].length,
                "wall_points": c[0],
            }
            for c in candidates
        ],
    }
    good = [c for c in candidates if c[0] >= s.min_wall_points]
    if not good:
        raise JobError(
            f"no seam with a side wall found in the scan ({len(candidates)} seam(s), wall points "
            f"{[c[0] for c in candidates]})",
            "check the ROI and the seam stage's settings; the SRM tool tracks fillet and lap joints",
        )
    n_wall, wall_left, seam = max(good, key=lambda c: (c[0], c[2].length))
    pts = orient_plan(np.asarray(seam.points, dtype=float), ctx.stage_settings("servo").wall_side, wall_left)
    info.update(chosen=int(seam.id), joint=seam.joint_class, length_mm=1e3 * seam.length, wall_points=n_wall)
    if truth_seams:
        info.update(plan_error_vs_truth(pts, truth_seams))
    return Plan(pts, "vision", info)


def plan_error_vs_truth(plan: np.ndarray, truth_seams: list[np.ndarray]) -> dict[str, float]:
    """RMS / max distance (mm) of a planned seam to the nearest true seam, in the plane and in 3-D."""
    best = None
    for true in truth_seams:
        line = Polyline(true, "true seam")
        inside = np.array([not (p.before_start or p.past_end) for p in map(line.project, plan)])
        if not inside.any():
            continue
        Q = plan[inside]
        d_xy = line.distances(Q)
        dense = line.resample(0.0002)
        from scipy.spatial import cKDTree

        d3 = cKDTree(dense).query(Q)[0]
        row = {
            "vision_plan_rms_mm": 1e3 * float(np.sqrt(np.mean(d_xy**2))),
            "vision_plan_max_mm": 1e3 * float(d_xy.max()),
            "vision_plan_rms_3d_mm": 1e3 * float(np.sqrt(np.mean(d3**2))),
        }
        if best is None or row["vision_plan_rms_mm"] < best["vision_plan_rms_mm"]:
            best = row
    return best or {}


# -- tracking ------------------------------------------------------------------------------------


@dataclass
class TrackRecord:
    """What one tracking run recorded (base frame, SI)."""

    t: list[float] = field(default_factory=list)
    tcp: list[np.ndarray] = field(default_factory=list)
    torch: list[np.ndarray] = field(default_factory=list)
    twist: list[np.ndarray] = field(default_factory=list)
    delta_n: list[float] = field(default_factory=list)
    delta_t: list[float] = field(default_factory=list)
    delta_d: list[float] = field(default_factory=list)
    in_contact: list[bool] = field(default_factory=list)
    lost: list[bool] = field(default_factory=list)
    state: list[str] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) for k, v in self.__dict__.items()}


def _estimator(img, s: SRMToolSettings):
    from weldcell.sdk.geometry import T_from_rpy

    from .marker import CameraIntrinsics, MarkerDisplacementEstimator

    k = img.intrinsics
    if k is None:
        raise JobError(
            "the tactile camera delivers no intrinsics: the tag's pose cannot be measured",
            "give the in-finger camera's intrinsics (intrinsics_file or [intrinsics]) in its settings",
        )
    intr = CameraIntrinsics(k.K, np.asarray(k.dist, dtype=float), k.width, k.height)
    return MarkerDisplacementEstimator(
        intr,
        s.marker_size,
        s.marker_id,
        s.dictionary,
        T_tool_cam=T_from_rpy(s.camera_rpy, (0.0, 0.0, 0.0)),
        filter=s.filter,
        min_cutoff=s.min_cutoff,
        beta=s.beta,
        max_reprojection_error=s.max_reprojection_error,
    )


def check_tool_offset(ctx, robot) -> None:
    """The robot's TCP must be the SRM tip (the tactile device's mount on the flange)."""
    entry = ctx.profile.devices.get("tactile")
    if entry is None or not entry.mount.parent.endswith(".flange"):
        return
    mount = np.asarray(entry.mount.xyz, dtype=float)
    tcp = np.asarray(robot.T_flange_tcp[:3, 3])
    if np.linalg.norm(mount - tcp) > 1e-3:
        raise JobError(
            f"the robot's TCP {np.round(tcp * 1e3, 1).tolist()} mm is not the SRM tip "
            f"{np.round(mount * 1e3, 1).tolist()} mm (the tactile device's mount on the flange)",
            "set [devices.robot.settings] tcp_xyz to the tactile device's mount xyz (the servo moves it)",
        )


def _recorded_scan(ctx, prefix: str) -> np.ndarray | None:
    """The part scan of an earlier attempt of this run (verified against its size and SHA-256), or None
    when there is none or it is damaged (then the robot parks and scans again: no contact, no weld)."""
    from weldcell.sdk.cloud import read_cloud

    for i, rec in enumerate(ctx.state.captures):
        if rec.get("kind") == "scan" and rec.get("prefix", "") == prefix:
            problem = ctx.state.check_capture(i)
            if problem:
                ctx.reporter.info(f"[yellow]{problem}: the part is scanned again[/yellow]")
                return None
            ctx.reporter.info(f"[dim]{prefix}scan of the part: taken in an earlier attempt, reused[/dim]")
            return read_cloud(ctx.run_dir / rec["file"], units="m", frame="base", check_scale=False).points
    return None


def _track_guard(ctx, s: TrackSettings, prefix: str) -> dict[str, Any] | None:
    """Resume rules of the contact phase (approach + Algorithm 2 + retract): done before -> its stored
    figures (nothing moves); started and not finished -> the run stops until ``--redo track``."""
    approach, tracking = f"{prefix}approach the seam start", f"{prefix}track the seam (Algorithm 2)"
    stored = ctx.state.data["notes"].get(f"{prefix}tactile figures")
    if ctx.redoing(tracking) or ctx.redoing(approach):
        ctx.redo.update({approach, tracking})  # the approach belongs to the tracking it prepares
        return None
    if ctx.state.step_done(tracking) and stored is not None:
        ctx.reporter.info(f"[dim]{tracking}: done in an earlier attempt, not repeated[/dim]")
        if stored.get("safe_stop") and s.fail_on_safe_stop:
            raise JobError(
                f"tactile tracking made a safe stop in an earlier attempt: {stored['safe_stop']}",
                f"{_fix_for(stored['safe_stop'])}; to track again: `{ctx.resume_command} --redo track`",
            )
        return stored
    if ctx.state.step_done(tracking):  # killed after the tracking, before its results were saved
        ctx.state.set_step(tracking, status="failed", error="stopped before its results were saved")
    for name in (tracking, approach):
        if ctx.state.status(name) is not None:
            ctx._guard_motion(name)
    return None


def track(ctx, plan_points: np.ndarray, s: TrackSettings, prefix: str = "") -> dict[str, Any]:
    """Approach, capture the rest pose, run Algorithm 2 until it stops, retract; write the artifacts.

    Returns the figures; raises :class:`JobError` after writing them when the stop was a safe stop and
    ``fail_on_safe_stop`` is set.
    """
    stored = _track_guard(ctx, s, prefix)
    if stored is not None:
        return stored
    robot, tactile = ctx.device("robot"), ctx.device("tactile")
    S: ServoSettings = ctx.stage_settings("servo")
    check_tool_offset(ctx, robot)
    plan = np.asarray(plan_points, dtype=float) + np.array([0.0, 0.0, s.tip_height])
    line = Polyline(plan, "planned path")
    p0, t0 = line.at(min(s.start_inset, 0.5 * line.length))
    t0 = line.smooth_tangent(min(s.start_inset, 0.5 * line.length), 0.005)
    into_wall = (1.0 if S.wall_side == "left" else -1.0) * left_normal(t0)
    start = p0.copy()
    start[:2] -= s.approach_clearance * into_wall
    T_start = frame_from_axes([t0[0], t0[1], 0.0], [0.0, 0.0, -1.0], start)
    T_above = T_start.copy()
    T_above[2, 3] += s.approach_height
    srm = s.srm
    assumed = SRMParams(
        tip_radius=max(S.tip_radius, 1e-6), tag_gain=srm.tag_gain, tag_axial_gain=srm.tag_axial_gain
    )

    with ctx.step(f"{prefix}approach the seam start", kind="motion"):
        _goto(robot, T_above, s.approach_speed)
        frames = [tactile.capture() for _ in range(srm.rest_frames)]
        est = _estimator(frames[0], srm)
        est.capture_rest([f.image for f in frames])
        robot.move_linear(T_start, speed=s.approach_speed)

    duration = s.command_duration or 1.0 / s.rate
    horizon = max(duration, 0.05)

    def gate(twist: np.ndarray, T: np.ndarray) -> None:
        robot.gate.check_twist(twist, robot.motion.accel, T, horizon)

    servo: TactileSeamServo = ctx.stage("servo")(plan, gate)
    max_time = s.max_time or 3.0 * (line.length + 0.05) / S.speed + 5.0
    rec = TrackRecord()
    stop_reason, final_state, safe_stop = "", "", ""
    t_first = None
    n_frames = int(max_time * s.rate) + 1
    with ctx.step(f"{prefix}track the seam (Algorithm 2)", total=n_frames, kind="motion") as advance:
        while True:
            try:
                img = tactile.capture()
            except DeviceError as e:
                safe_stop = f"tactile camera: {e.message}"
                break
            t = float(img.stamp)
            t_first = t if t_first is None else t_first
            reading = est.update(img.image, t)
            delta = None
            if not hasattr(reading, "frames_lost"):
                delta = -tip_deflection_from_tag(reading.displacement, assumed)
            T = robot.state().T_base_tcp
            cmd = servo.step(t, T, delta)
            rec.t.append(t - t_first)
            rec.tcp.append(T[:3, 3].copy())
            rec.torch.append(cmd.P_t)
            rec.twist.append(cmd.twist)
            rec.delta_n.append(cmd.delta_n if delta is not None else np.nan)
            rec.delta_t.append(cmd.delta_t if delta is not None else np.nan)
            rec.delta_d.append(cmd.delta_d)
            rec.in_contact.append(bool(cmd.in_contact))
            rec.lost.append(delta is None)
            rec.state.append(cmd.state)
            if len(rec.t) % 25 == 0:
                advance(len(rec.t), n_frames, f"{1e3 * servo.refined.length:.0f} mm refined, {cmd.state}")
            stop_reason, final_state = cmd.reason, cmd.state
            if cmd.done:
                break
            if t - t_first > max_time:
                stop_reason, final_state = f"time limit {max_time:.1f} s", "stopped"
                break
            try:
                robot.speed_linear(cmd.twist, duration=duration)
            except SafetyError as e:
                stop_reason, final_state = f"safety: {e.message}", "fault"
                break
        robot.stop()
    if final_state == "fault" or (
        stop_reason and stop_reason not in NORMAL_ENDS and not stop_reason.startswith("time limit")
    ):
        safe_stop = safe_stop or stop_reason
    notes: list[str] = []
    if s.retract > 0:
        up = robot.state().T_base_tcp.copy()
        up[2, 3] += s.retract
        try:
            robot.move_linear(up, speed=s.approach_speed)
        except SafetyError as e:
            notes.append(f"retract refused by the safety gate: {e.message}")
    return _finish(ctx, servo, rec, plan, s, S, stop_reason, final_state, safe_stop, notes, prefix)


# -- results -------------------------------------------------------------------------------------


def _truth(ctx, plan: np.ndarray, S: ServoSettings) -> dict | None:
    dev = ctx.devices.get("tactile")
    if not hasattr(dev, "truth"):
        return None
    tr = dev.truth()
    if tr.get("seam") is None:
        return None
    seam = np.asarray(tr["seam"], dtype=float)
    seam_line = Polyline(seam, "true seam")
    # same travel direction as the plan
    if float(seam_line.at(seam_line.length)[0][:2] @ (plan[-1, :2] - plan[0, :2])) < float(
        seam_line.at(0.0)[0][:2] @ (plan[-1, :2] - plan[0, :2])
    ):
        seam = seam[::-1].copy()
    tr["seam"] = seam
    return tr


def _metrics(
    rec: dict[str, np.ndarray],
    refined: np.ndarray,
    refined_t: np.ndarray,
    seam_est: np.ndarray,
    plan: np.ndarray,
    truth: dict | None,
    S: ServoSettings,
    tip_height: float,
) -> dict[str, float]:
    m: dict[str, float] = {}
    contact = rec["in_contact"] & ~np.isnan(rec["delta_n"]) if len(rec["t"]) else np.zeros(0, bool)
    if contact.any():
        m["delta_n_mean_mm"] = 1e3 * float(np.nanmean(rec["delta_n"][contact]))
        m["delta_n_std_mm"] = 1e3 * float(np.nanstd(rec["delta_n"][contact]))
    m["delta_d_mm"] = 1e3 * S.delta_d
    m["frames"] = float(len(rec["t"]))
    m["duration_s"] = float(rec["t"][-1]) if len(rec["t"]) else 0.0
    m["marker_lost_frames"] = float(np.sum(rec["lost"])) if len(rec["t"]) else 0.0
    m["refined_points"] = float(len(refined))
    m["refined_length_mm"] = 1e3 * (Polyline(refined).length if len(refined) >= 2 else 0.0)
    if truth is None or len(seam_est) < 2:
        return m
    seam_line = Polyline(truth["seam"], "true seam")
    inside = np.array([not (p.before_start or p.past_end) for p in map(seam_line.project, seam_est)])
    if inside.any():
        d = seam_line.distances(seam_est[inside])
        m["refined_seam_rms_mm"] = 1e3 * float(np.sqrt(np.mean(d**2)))
        m["refined_seam_max_mm"] = 1e3 * float(d.max())
        dz = (
            seam_est[inside, 2]
            - tip_height
            - np.array([seam_line.project(p).point[2] for p in seam_est[inside]])
        )
        m["refined_seam_height_rms_mm"] = 1e3 * float(np.sqrt(np.mean(dz**2)))
    m["refined_coverage"] = float(Polyline(refined).length / seam_line.length)
    inside_p = np.array([not (p.before_start or p.past_end) for p in map(seam_line.project, plan)])
    if inside_p.any():
        dp = seam_line.distances(plan[inside_p])
        m["plan_rms_mm"] = 1e3 * float(np.sqrt(np.mean(dp**2)))
    return m


def refined_weld_path(seam_line_pts: np.ndarray, wall_side: str) -> WeldPath:
    """The seam found by touch as a weld path: torch z bisects the wall and the floor, x along travel."""
    P = np.asarray(seam_line_pts, dtype=float)
    line = Polyline(P, "refined seam")
    sign = 1.0 if wall_side == "left" else -1.0
    poses = []
    for s_ in line.s:
        t = line.smooth_tangent(float(s_), 0.003)
        n_in = sign * left_normal(t)
        approach = np.array([n_in[0], n_in[1], -1.0]) / np.sqrt(2.0)
        poses.append(frame_from_axes([t[0], t[1], 0.0], approach, line.points[len(poses)]))
    return WeldPath([SeamPath("tactile", "fillet", line.points, np.stack(poses))], frame="base")


def _finish(
    ctx,
    servo: TactileSeamServo,
    record: TrackRecord,
    plan: np.ndarray,
    s: TrackSettings,
    S: ServoSettings,
    stop_reason: str,
    final_state: str,
    safe_stop: str,
    notes: list[str],
    prefix: str,
) -> dict[str, Any]:
    rec = record.arrays()
    refined, refined_t = servo.refined.points, servo.refined.times  # refined_t: absolute camera stamps
    seam_est = (
        seam_from_tip_path(refined, S.tip_radius, S.wall_side, S.tangent_window) if len(refined) else refined
    )
    truth = _truth(ctx, plan, S)
    metrics = _metrics(rec, refined, refined_t, seam_est, plan - [0, 0, s.tip_height], truth, S, s.tip_height)
    if truth is not None and "t" in truth and len(refined_t):
        # recorded tip P_s against the true tip at the capture it was recorded from (same simulated clock)
        idx = np.clip(np.searchsorted(truth["t"], refined_t - 1e-9), 0, len(truth["t"]) - 1)
        e = np.linalg.norm(refined[:, :2] - truth["tip"][idx, :2], axis=1)
        metrics["refined_tip_rms_mm"] = 1e3 * float(np.sqrt(np.mean(e**2)))
    seam_line = seam_est - np.array([0.0, 0.0, s.tip_height]) if len(seam_est) else seam_est
    files = {"track": f"{prefix}tactile_track.json"}
    doc = {
        "schema": SCHEMA,
        "frame": "base",
        "units": "m",
        "stop_reason": stop_reason,
        "final_state": final_state,
        "safe_stop": safe_stop or None,
        "settings": {"servo": S.model_dump(mode="json"), "track": s.model_dump(mode="json")},
        "planned_path": np.round(plan, 7).tolist(),
        "refined_path": np.round(refined, 7).tolist(),
        "refined_times": np.round(refined_t, 5).tolist(),
        "seam_estimate": np.round(seam_line, 7).tolist(),
        "frames": {
            "t": np.round(rec["t"], 5).tolist(),
            "tcp": np.round(rec["tcp"], 7).tolist(),
            "torch": np.round(rec["torch"], 7).tolist(),
            "twist": np.round(rec["twist"], 7).tolist(),
            "delta_n": [None if np.isnan(v) else round(float(v), 8) for v in rec["delta_n"]],
            "delta_t": [None if np.isnan(v) else round(float(v), 8) for v in rec["delta_t"]],
            "delta_d": np.round(rec["delta_d"], 8).tolist(),
            "in_contact": rec["in_contact"].tolist(),
            "marker_lost": rec["lost"].tolist(),
            "state": rec["state"].tolist(),
        },
        "metrics": metrics,
        "notes": notes,
    }
    ctx.write_json(files["track"], doc)
    if len(seam_line) >= 2:
        wp = refined_weld_path(seam_line, S.wall_side)
        wp.metrics = {k: v for k, v in metrics.items() if k.startswith("refined")}
        files["refined_path"] = f"{prefix}refined_path.json"
        wp.write(ctx.path(files["refined_path"]))
    report_data = tactile_report.TrackData.from_record(rec, plan, refined, seam_est, truth)
    if s.plots and len(rec["t"]):
        files.update(tactile_report.pictures(ctx, report_data, prefix))
    figures = {
        "stop_reason": stop_reason,
        "final_state": final_state,
        "safe_stop": safe_stop or None,
        **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in metrics.items()},
        "files": files,
    }
    if len(rec["t"]):
        files["report"] = f"{prefix}report/report.html"
        tactile_report.write_html(ctx, report_data, figures, prefix)
    ctx.write_text(f"{prefix}summary.txt", summary_text(figures, "tactile tracking"))
    ctx.state.data["notes"][f"{prefix}tactile figures"] = figures  # a resume returns these, moving nothing
    ctx.state.save()
    if safe_stop and s.fail_on_safe_stop:
        ctx.figures.update({"tactile": figures})
        where = (
            f"after {metrics.get('refined_length_mm', 0.0):.0f} mm of seam, t = {metrics['duration_s']:.2f} s"
        )
        raise JobError(
            f"tactile tracking made a safe stop {where}: {safe_stop}",
            _fix_for(safe_stop) + f"; what was recorded is in {ctx.run_dir}",
        )
    return figures


def _fix_for(reason: str) -> str:
    if reason.startswith("safety"):
        return (
            "check the planned path against [cell.safety] workspace_min/max (the seam leaves the box) or "
            "shorten the plan"
        )
    if "marker" in reason:
        return "check the in-finger camera: lighting, focus, a torn or occluded tag, marker id and dictionary"
    if "overload" in reason:
        return "the finger was pressed beyond its range: lower delta_d / k_p or check the plan's height"
    return "see tactile_track.json for the recorded frames"


def summary_text(fig: dict[str, Any], title: str) -> str:
    lines = [f"weldcell {title}", ""]
    for k, v in fig.items():
        if k == "files":
            continue
        if isinstance(v, dict):
            lines.append(f"{k}:")
            lines += [f"  {k2:<28} {v2}" for k2, v2 in v.items() if not isinstance(v2, dict | list)]
        else:
            lines.append(f"{k:<30} {v}")
    if "files" in fig:
        lines += ["", "files: " + ", ".join(str(v) for v in fig["files"].values())]
    return "\n".join(lines) + "\n"


# -- the tactile-track job -----------------------------------------------------------------------


def read_T_base_camera(path: Path) -> np.ndarray:
    """``T_base_camera`` from a ``weldcell/hand-eye@1`` file (eye-on-base)."""
    from weldcell.sdk.handeye_files import read_result

    res = read_result(path)
    if res.name != "T_base_camera":
        raise DataError(
            f"{path}: the hand-eye is {res.name}, not T_base_camera (a camera fixed in the cell)",
            "calibrate the fixed camera with the 'calibrate' job (eye-on-base)",
        )
    return np.asarray(res.T, dtype=float)


def run(ctx) -> dict[str, Any]:
    """The ``tactile-track`` job."""
    s: TactileTrackSettings = ctx.settings
    S: ServoSettings = ctx.stage_settings("servo")
    if s.plan_file is not None:
        path = (ctx.loaded.source_of(("job", "settings", "plan_file")).parent / s.plan_file).resolve()
        plan = Plan(plan_from_file(path, s.seam_id), f"file {path}")
        pts = plan.points
        # the file's travel direction is kept; only the servo's wall side must match it
    else:
        camera = ctx.devices.get("camera")
        hand_eye = ctx.calibration_file("hand_eye")
        if camera is None or hand_eye is None:
            raise JobError(
                "tactile-track has no planned path: no plan_file, and no camera + hand-eye for the "
                "vision step",
                "set [job.settings] plan_file, or add [devices.camera] and "
                "[calibration] hand_eye = 'handeye.json'",
            )
        truth = _true_seams(ctx)
        plan = scan_for_seam(ctx, camera, read_T_base_camera(hand_eye), s.scan, S.wall_side, truth)
        pts = plan.points
    figures = {"plan": {"source": plan.source, **plan.info}}
    ctx.figures.update(figures)
    figures["tactile"] = track(ctx, pts, s)
    return figures


def _true_seams(ctx) -> list[np.ndarray] | None:
    """Ground-truth seams in the robot base frame (simulated cell), else None."""
    world = world_of(ctx)
    if world is None:
        return None
    T_base_world = invert(world.T_world("robot.base"))
    return [transform_points(T_base_world, s.points) for _, s in world.seams_in_world()]
