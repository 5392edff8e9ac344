"""The ``calibrate`` job (paper 003): online flange-based hand-eye calibration of a camera fixed in the
cell (eye-on-base).

Plan calibration poses (a grid in a box of the robot base frame, flange facing the camera with bounded
random tilts), drive them one at a time through the safety gate (a refused pose is skipped with a
note), scan the flange at each, segment it and fit its centre, and feed the pair to Algorithm 1 until
its cost reaches ``e_required`` or the poses run out. Every capture (cloud + pose + centre) is saved
at once, so an interrupted run resumes where it stopped. Writes ``handeye.json``
(``weldcell/hand-eye@1``), ``samples.json`` (``weldcell/handeye-samples@1``, usable offline by
``weldcell calibrate hand-eye RUN_DIR``), the report and, in the simulated cell, the error against the
camera's true mount.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator
from scipy.spatial.transform import Rotation
from weldcell.plugins.handeye.pointfit import scaled_svd_fit
from weldcell.plugins.handeye.result import HandEyeSample
from weldcell.plugins.handeye.samples_io import write_result, write_samples
from weldcell.plugins.handeye.stages import predicted_p_cam
from weldcell.sdk.cloud import PointCloud, read_cloud, write_cloud
from weldcell.sdk.errors import DataError, DeviceError, JobError, SafetyError
from weldcell.sdk.geometry import T_from_rpy, frame_from_axes, invert, pose_error
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Length

Vec3 = tuple[Length, Length, Length]


class CalibrateSettings(Settings):
    """Settings of the online hand-eye calibration job."""

    box_min: Vec3 = Field(description="lower corner of the box the flange visits, robot base frame [m]")
    box_max: Vec3 = Field(description="upper corner of that box, robot base frame [m]")
    n_poses: int = Field(30, ge=4, le=500, description="calibration poses planned")
    max_tilt: Angle = Field(
        0.3,
        ge=0,
        le=1.2,
        description="largest random tilt of the flange away from "
        "facing the camera, about each of its x and y axes [rad] (§3.1: 0.3)",
    )
    max_spin: Angle = Field(
        0.3, ge=0, le=3.1416, description="largest random turn about the flange axis [rad]"
    )
    face_toward: Vec3 | None = Field(
        None,
        description="point the flange faces, robot base frame [m]; default: "
        "the camera's nominal mount in the profile",
    )
    seed: int | None = Field(None, description="seed of the pose plan; default: the cell's seed")
    min_poses: int = Field(8, ge=4, description="Algorithm 1 may stop only after this many flange centres")
    stop_at_target: bool = Field(True, description="stop once Algorithm 1's cost reaches e_required")
    verification_scan: bool = Field(
        True,
        description="scan the flange at the box centre first (the "
        "verification cloud of the ICP metric, eq. 13)",
    )
    min_points: int = Field(200, ge=10, description="a scan with fewer valid points has no flange")
    reconnects: int = Field(2, ge=0, description="reconnection attempts when the camera drops")
    save_clouds: bool = Field(True, description="keep every scan (cropped to the stage's box) in captures/")

    @model_validator(mode="after")
    def _box(self) -> CalibrateSettings:
        for axis, lo, hi in zip("xyz", self.box_min, self.box_max, strict=True):
            if lo > hi:
                raise ValueError(f"box_min.{axis} ({lo}) must not exceed box_max.{axis} ({hi})")
        return self


# -- planning ------------------------------------------------------------------------------------


def _grid_order(n: int, rng: np.random.Generator) -> np.ndarray:
    """Unit-box grid nodes (n, 3) in [-0.5, 0.5]^3: the first four are non-coplanar corners (a good
    starting pool S_0 for Algorithm 1), the rest of a ~n-node grid follow in random order."""
    nz = 3 if n >= 12 else 2
    nx = max(2, int(np.ceil(np.sqrt(n / nz))))
    g = np.linspace(-0.5, 0.5, nx)
    G = np.stack(np.meshgrid(g, g, np.linspace(-0.5, 0.5, nz), indexing="ij"), -1).reshape(-1, 3)
    corners = np.array([[-0.5, -0.5, -0.5], [0.5, 0.5, -0.5], [0.5, -0.5, 0.5], [-0.5, 0.5, 0.5]])
    first = [int(np.argmin(np.linalg.norm(G - c, axis=1))) for c in corners]
    rest = [i for i in rng.permutation(len(G)) if i not in first]
    return G[first + rest][:n]


def plan_poses(
    box_min, box_max, n: int, face_toward, max_tilt: float, max_spin: float, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Calibration flange poses (n, 4, 4) in the base frame and the verification pose (box centre,
    facing ``face_toward``). Each pose: a grid node, the flange z axis toward ``face_toward``, then
    random rotations about the flange x and y (|angle| <= max_tilt) and z (|angle| <= max_spin)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(box_min, float), np.asarray(box_max, float)
    pos = (lo + hi) / 2 + _grid_order(n, rng) * (hi - lo)
    if len(pos) < n:
        pos = np.vstack([pos, lo + rng.random((n - len(pos), 3)) * (hi - lo)])
    target = np.asarray(face_toward, float)

    def facing(p: np.ndarray) -> np.ndarray:
        z = target - p
        if np.linalg.norm(z) < 1e-6:
            raise DataError(
                "face_toward lies inside the pose box", "give the camera's position in the base frame"
            )
        z /= np.linalg.norm(z)
        up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        return frame_from_axes(up - z * (up @ z), z, p)

    tilt = rng.uniform(-1, 1, (n, 3)) * np.array([max_tilt, max_tilt, max_spin])
    jitter = Rotation.from_euler("xyz", tilt).as_matrix()
    poses = np.empty((n, 4, 4))
    for i, p in enumerate(pos):
        T = facing(p)
        T[:3, :3] = T[:3, :3] @ jitter[i]
        poses[i] = T
    return poses, facing((lo + hi) / 2)


def nominal_T_base_camera(ctx) -> np.ndarray:
    """The camera's mount as the profile states it, in the robot base frame (a rough prior only)."""
    p = ctx.profile.devices
    cam, rob = p["camera"].mount, p["robot"].mount
    T_parent_cam = T_from_rpy(cam.rpy, cam.xyz)
    if cam.parent == "base":
        return T_parent_cam
    return invert(T_from_rpy(rob.rpy, rob.xyz)) @ T_parent_cam


def ground_truth(ctx) -> np.ndarray | None:
    """The true ``T_base_camera`` in the simulated cell (None on hardware)."""
    world = ctx.shared.get("sim.world")
    camera = ctx.devices.get("camera")
    if world is None or not hasattr(camera, "T_world_camera"):
        return None
    return invert(world.T_world("robot.base")) @ camera.T_world_camera


# -- motion and capture --------------------------------------------------------------------------


def _move(robot, T_base_flange: np.ndarray) -> None:
    """Joint move (IK through the gate) when the model is known, else a linear move; both gated."""
    T_tcp = T_base_flange @ robot.T_flange_tcp
    if robot.gate.model is not None:
        robot.gate.check_point(T_tcp[:3, 3], "calibration pose")
        q = robot.gate.solve(T_base_flange, robot.state().q, "calibration pose")
        robot.move_joint(q)
    else:
        robot.move_linear(T_tcp)


def _capture(ctx, camera, attempts: int):
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


def _scan(ctx, stage, T_goal: np.ndarray, name: str, predicted, seed: int) -> dict:
    """Move, capture, save and measure one pose; the returned record is what state.json keeps."""
    s: CalibrateSettings = ctx.settings
    robot, camera = ctx.device("robot"), ctx.device("camera")
    try:
        _move(robot, T_goal)
    except SafetyError as e:
        return {"status": "refused", "reason": e.message}
    frame = _capture(ctx, camera, s.reconnects)
    T = robot.state().T_base_flange
    cloud = frame.to_cloud()
    P = stage.flange.crop(cloud.points) if hasattr(stage, "flange") else stage.crop(cloud.points)
    rec: dict = {"T_base_flange": T.tolist(), "stamp": frame.stamp, "points": int(len(P))}
    if s.save_clouds:
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


# -- the job -------------------------------------------------------------------------------------


def _config(ctx) -> str:
    parent = ctx.profile.devices["camera"].mount.parent
    if parent in ("world", "base"):
        return "eye-on-base"
    raise JobError(
        f"the camera is mounted on '{parent}': the online flange calibration needs the camera fixed in the "
        "cell, looking at the robot's flange (eye-on-base)",
        "mount the camera on 'world'; for eye-in-hand, record samples of a fixed flange and run "
        "`weldcell calibrate hand-eye DATA_DIR --config eye-in-hand`",
    )


def _record_public(rec: dict) -> dict:
    return {k: v for k, v in rec.items() if not k.startswith("_")}


def _verification(ctx, stage, T_v: np.ndarray, seed: int):
    """The verification scan (face cloud, T_base_flange) for eq. 13: from state.json after a resume."""
    for rec in ctx.state.captures:
        if rec.get("kind") == "verification" and rec.get("status") == "ok" and "file" in rec:
            P = read_cloud(ctx.run_dir / rec["file"], units="m", frame="camera", check_scale=False).points
            m = stage.measure(P, seed=seed)
            return m.face, np.asarray(rec["T_base_flange"], float)
    with ctx.step("verification scan (eq. 13)"):
        rec = _scan(ctx, stage, T_v, "verification", None, seed)
        ctx.state.add_capture({"kind": "verification", **_record_public(rec)})
    if rec["status"] != "ok":
        raise JobError(
            f"verification scan at the box centre failed: {rec['reason']}",
            "make sure the flange at the centre of [job.settings] box_min/box_max faces the camera "
            "in range, or set verifier = 'consensus' in [stages.handeye.settings]",
        )
    return rec["_face"], np.asarray(rec["T_base_flange"], float)


def run(ctx) -> dict:
    """The whole job; returns the figures written into result.json."""
    from weldcell.plugins.handeye.report import write_report

    s: CalibrateSettings = ctx.settings
    config = _config(ctx)
    stage = ctx.stage("handeye")
    flange = getattr(stage, "flange", stage)
    feature = np.asarray(flange.s.feature, float)
    seed = ctx.profile.cell.seed if s.seed is None else s.seed
    toward = s.face_toward if s.face_toward is not None else nominal_T_base_camera(ctx)[:3, 3]
    poses, T_v = plan_poses(s.box_min, s.box_max, s.n_poses, toward, s.max_tilt, s.max_spin, seed)
    truth = ground_truth(ctx)

    done = {rec["index"]: rec for rec in ctx.state.captures if rec.get("kind") == "pose"}
    if done:
        ctx.reporter.info(f"resuming with {len(done)} pose(s) already visited")
    use_icp = stage.needs == "flange" and flange.s.verifier == "icp"
    verification = _verification(ctx, flange, T_v, seed) if (use_icp and s.verification_scan) else None
    if use_icp and verification is None:
        raise JobError(
            "the ICP verifier needs the verification scan",
            "set verification_scan = true, or verifier = 'consensus' in [stages.handeye.settings]",
        )
    pool = flange.pool(verification, verifier=None if use_icp else "consensus")
    track: list[dict] = []
    ok_recs: list[dict] = []

    def feed(rec: dict) -> None:
        T = np.asarray(rec["T_base_flange"], float)
        pool.add(np.asarray(rec["p_cam"], float), (T @ np.r_[feature, 1.0])[:3])
        ok_recs.append(rec)
        row = {"n": len(ok_recs), "cost": pool.cost}
        if truth is not None:
            if pool.H is not None:
                row["pool_error"] = pose_error(pool.H, truth)
            if len(ok_recs) >= 4:
                c = np.array([r["p_cam"] for r in ok_recs])
                d = np.array([(np.asarray(r["T_base_flange"]) @ np.r_[feature, 1.0])[:3] for r in ok_recs])
                row["all_data_error"] = pose_error(scaled_svd_fit(c, d).T, truth)
        track.append(row)

    notes: list[str] = []
    stop = "poses exhausted"
    with ctx.step("calibration poses (scan + flange + Algorithm 1)", total=len(poses)) as advance:
        for i, T_goal in enumerate(poses):
            if i in done:
                rec = done[i]
            else:
                predicted = None if pool.H is None else predicted_p_cam(pool.H, T_goal, feature)
                rec = {"kind": "pose", "index": i, **_scan(ctx, stage, T_goal, f"{i:03d}", predicted, seed)}
                ctx.state.add_capture(_record_public(rec))
            if rec["status"] == "ok":
                feed(rec)
            else:
                notes.append(f"pose {i}: {rec['status']}: {rec['reason']}")
                if i not in done:
                    ctx.reporter.info(f"[yellow]pose {i} {rec['status']}: {rec['reason']}[/yellow]")
            advance(i + 1, len(poses), f"{len(ok_recs)} centres, cost {pool.cost * 1e3:.3g} mm")
            if s.stop_at_target and pool.converged and len(ok_recs) >= s.min_poses:
                stop = f"Algorithm 1 cost {pool.cost * 1e3:.3f} mm <= e_required after {len(ok_recs)} centres"
                break
    ctx.state.data["notes"]["skipped"] = notes
    ctx.state.save()

    samples = [
        HandEyeSample(
            T_base_flange=np.asarray(r["T_base_flange"], float),
            p_cam=np.asarray(r["p_cam"], float),
            T_cam_target=None if "T_cam_target" not in r else np.asarray(r["T_cam_target"]),
            cloud=str(ctx.run_dir / r["file"]) if "file" in r else None,
            meta={"index": r["index"]},
        )
        for r in ok_recs
    ]
    if len(samples) < 4:
        raise JobError(
            f"only {len(samples)} flange centre(s) measured from {len(poses)} planned poses (need 4)",
            "check the box faces the camera in range (see the skipped poses in state.json notes), widen "
            "[job.settings] box_min/box_max or the stage's pass-through box",
        )
    with ctx.step(f"solve ({stage.name}, {getattr(stage.s, 'method', '')})"):
        result = stage.solve(samples, config, verification=verification)
    result.metrics["online"] = {
        "planned": len(poses),
        "visited": sum(1 for r in ctx.state.captures if r.get("kind") == "pose"),
        "centres": len(samples),
        "refused": sum("refused" in n for n in notes),
        "no_flange": sum("no-flange" in n for n in notes),
        "stop": stop,
        "pool": [int(ok_recs[j]["index"]) for j in pool.pool],
        "pool_cost_m": pool.cost,
        "pool_converged": pool.converged,
        "cost_history_m": [t["cost"] for t in track],
    }
    result.metrics["sample_index"] = [r["index"] for r in ok_recs]
    result.warnings += [f"skipped {n}" for n in notes]
    write_result(ctx.path("handeye.json"), result)
    write_samples(ctx.path("samples.json"), samples, config)
    figures: dict = {
        "transform": result.name,
        "method": result.method,
        "samples": len(samples),
        "inliers": int(np.sum(result.inliers)),
        "stop": stop,
        "rms_inliers_mm": 1e3 * result.metrics.get("rms_inliers_m", float("nan")),
    }
    if truth is not None:
        dt, dr = pose_error(result.T, truth)
        figures["error_vs_truth"] = {"translation_mm": dt * 1e3, "rotation_deg": float(np.degrees(dr))}
        if pool.H is not None:
            dt2, dr2 = pose_error(pool.H, truth)
            figures["algorithm1_error_vs_truth"] = {
                "translation_mm": dt2 * 1e3,
                "rotation_deg": float(np.degrees(dr2)),
            }
    if ctx.profile.output.report:
        with ctx.step("report"):
            write_report(ctx, result, track, notes, truth, stop)
    return figures
