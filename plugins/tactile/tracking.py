"""Algorithm 2 on the robot: approach the seam, run the deformation servo at camera rate, retract.

At camera rate: capture the in-finger image → tag displacement → tip deflection δ →
:meth:`TactileSeamServo.step` → the TCP twist → ``robot.speed_linear`` through the HAL safety gate. A
refused command, a lost marker or an overload is a safe stop; :func:`track` then writes what was recorded
(:mod:`~weldcell.plugins.tactile.track_results`) before it fails.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from weldcell.sdk.errors import DeviceError, JobError, SafetyError
from weldcell.sdk.geometry import frame_from_axes, invert

from .paths import Polyline, left_normal
from .servo import ServoSettings, TactileSeamServo
from .srm_model import SRMParams, tip_deflection_from_tag
from .track_results import TrackOutcome, TrackRecord, finish, fix_for
from .track_settings import SRMToolSettings, TrackSettings

NORMAL_ENDS = ("contact lost", "end of planned path")


def goto(robot, T_tcp: np.ndarray, speed: float | None = None) -> None:
    """Joint move through the gate when the kinematics are known (no straight-line singularity issues)."""
    if robot.gate.model is not None:
        T_flange = T_tcp @ invert(robot.T_flange_tcp)
        robot.gate.check_point(T_tcp[:3, 3], "tactile approach")
        robot.move_joint(robot.gate.solve(T_flange, robot.state().q, "tactile approach"))
    else:
        robot.move_linear(T_tcp, speed=speed)


def _estimator(img, s: SRMToolSettings):
    """The tag displacement estimator of the SRM finger, from the in-finger camera's intrinsics."""
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
                f"{fix_for(stored['safe_stop'])}; to track again: `{ctx.resume_command} --redo track`",
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

    with ctx.step(f"{prefix}approach the seam start", kind="motion"):
        goto(robot, T_above, s.approach_speed)
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
    out = _servo_loop(ctx, servo, est, s, S, max_time, prefix)
    if s.retract > 0:
        up = robot.state().T_base_tcp.copy()
        up[2, 3] += s.retract
        try:
            robot.move_linear(up, speed=s.approach_speed)
        except SafetyError as e:
            out.notes.append(f"retract refused by the safety gate: {e.message}")
    return finish(ctx, out, plan, s, S, prefix)


def _servo_loop(
    ctx, servo: TactileSeamServo, est, s: TrackSettings, S: ServoSettings, max_time: float, prefix: str
) -> TrackOutcome:
    """Algorithm 2 at camera rate until the servo is done, the time runs out or a safe stop; then stop."""
    robot, tactile = ctx.device("robot"), ctx.device("tactile")
    assumed = SRMParams(
        tip_radius=max(S.tip_radius, 1e-6), tag_gain=s.srm.tag_gain, tag_axial_gain=s.srm.tag_axial_gain
    )
    duration = s.command_duration or 1.0 / s.rate
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
            rec.add(t - t_first, T, cmd, delta is not None)
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
    return TrackOutcome(servo, rec, stop_reason, final_state, safe_stop)
