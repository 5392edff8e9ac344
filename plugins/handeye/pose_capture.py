"""Visiting one calibration pose: a gated move, a depth capture (recovering a dropped camera), the
flange measured in it, and the record ``state.json`` keeps; the verification scan of eq. 13; and, on
resume, the check of every recorded capture.
"""

from __future__ import annotations

import numpy as np
from weldcell.sdk.calibration import CalibrateSettings
from weldcell.sdk.cloud import PointCloud, read_cloud, write_cloud
from weldcell.sdk.errors import DataError, DeviceError, JobError, SafetyError

POSES = "calibration poses (scan + flange + fit)"


def move_to_pose(robot, T_base_flange: np.ndarray) -> None:
    """Joint move (IK through the gate) when the model is known, else a linear move; both gated."""
    T_tcp = T_base_flange @ robot.T_flange_tcp
    if robot.gate.model is not None:
        robot.gate.check_point(T_tcp[:3, 3], "calibration pose")
        q = robot.gate.solve(T_base_flange, robot.state().q, "calibration pose")
        robot.move_joint(q)
    else:
        robot.move_linear(T_tcp)


def capture_frame(ctx, camera, attempts: int):
    """A depth frame; a camera error is recovered and retried ``attempts`` times, then a JobError."""
    for k in range(attempts + 1):
        try:
            return camera.capture()
        except DeviceError as e:
            if k == attempts:
                raise JobError(
                    f"camera: {e.message} (after {attempts} reconnection attempts)",
                    f"captures so far are saved in {ctx.run_dir}; fix the camera and continue with "
                    f"`weldcell run {ctx.loaded.path} --resume {ctx.run_dir}`",
                ) from e
            ctx.reporter.info(f"[yellow]camera: {e.message}; reconnecting ({k + 1}/{attempts})[/yellow]")
            camera.recover()
            camera.configure()
            camera.activate()
    raise AssertionError("unreachable")


def scan_pose(ctx, stage, T_goal: np.ndarray, name: str, predicted, seed: int) -> dict:
    """Move, capture, save and measure one pose; the returned record is what state.json keeps."""
    s: CalibrateSettings = ctx.settings
    robot, camera = ctx.device("robot"), ctx.device("camera")
    try:
        move_to_pose(robot, T_goal)
    except SafetyError as e:
        return {"status": "refused", "reason": e.message}
    frame = capture_frame(ctx, camera, s.reconnects)
    T = robot.state().T_base_flange
    cloud = frame.to_cloud()
    P = stage.flange.crop(cloud.points) if hasattr(stage, "flange") else stage.crop(cloud.points)
    rec: dict = {"T_base_flange": T.tolist(), "stamp": frame.stamp, "points": int(len(P))}
    if s.save_clouds and len(P):
        rec["file"] = f"captures/{name}.ply"
        write_cloud(ctx.path(rec["file"]), PointCloud(P.astype(np.float32).astype(float), frame="camera"))
    if len(P) < s.min_points:
        return {**rec, "status": "no-flange", "reason": f"only {len(P)} valid points in the scan"}
    try:
        m = stage.measure(P, predicted, seed=seed)
    except DataError as e:
        return {**rec, "status": "no-flange", "reason": e.message}
    rec.update(
        status="ok",
        p_cam=m.p_cam.tolist(),
        normal=m.normal.tolist(),
        radius=float(m.report["radius"]),
        support=int(m.report["support"]),
    )
    if "T_cam_flange" in m.report:
        rec["T_cam_target"] = np.asarray(m.report["T_cam_flange"]).tolist()
    rec["_face"] = m.face
    return rec


def public_record(rec: dict) -> dict:
    """What ``state.json`` keeps of a pose record (its private ``_`` keys left out)."""
    return {k: v for k, v in rec.items() if not k.startswith("_")}


def verification_scan(ctx, stage, T_v: np.ndarray, seed: int):
    """The verification scan (face cloud, T_base_flange) for eq. 13: from state.json after a resume."""
    for rec in ctx.state.captures:
        if rec.get("kind") == "verification" and rec.get("status") == "ok" and "file" in rec:
            P = read_cloud(ctx.run_dir / rec["file"], units="m", frame="camera", check_scale=False).points
            m = stage.measure(P, seed=seed)
            return m.face, np.asarray(rec["T_base_flange"], float)
    with ctx.step("verification scan (eq. 13)", kind="checkpointed"):
        rec = scan_pose(ctx, stage, T_v, "verification", None, seed)
        ctx.state.add_capture({"kind": "verification", **public_record(rec)})
    if rec["status"] != "ok":
        raise JobError(
            f"verification scan at the box centre failed: {rec['reason']}",
            "make sure the flange at the centre of [job.settings] box_min/box_max faces the camera "
            "in range, or set verifier = 'consensus' in [stages.handeye.settings]",
        )
    return rec["_face"], np.asarray(rec["T_base_flange"], float)


def check_captures(ctx) -> None:
    """On resume: every recorded capture against its size and SHA-256. While the pose loop is open a
    damaged one is set aside and its pose visited again (a gated free-space move, no contact); once the
    loop had finished, a damaged capture stops the run (``--redo 'calibration poses'`` visits all again)."""
    st = ctx.state
    if ctx.redoing(POSES) and st.captures:
        ctx.reporter.info(f"--redo: {len(st.captures)} earlier capture(s) set aside; all poses visited again")
        st.discard_captures(0, "--redo calibration poses")
        return
    for i in reversed(range(len(st.captures))):
        problem = st.check_capture(i)
        if not problem:
            continue
        if st.step_done(POSES):
            raise DataError(
                f"{problem}; the calibration poses were finished, so they are not visited again "
                "automatically",
                f"restore the file, or visit every pose again with `{ctx.resume_command} --redo "
                "'calibration poses'`",
            )
        ctx.reporter.info(f"[yellow]{problem}: that pose is visited and captured again[/yellow]")
        st.discard_captures(i, problem, count=1)
