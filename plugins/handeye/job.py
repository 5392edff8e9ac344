"""The ``calibrate`` job (paper 003): online flange-based hand-eye calibration of a depth camera fixed
in the cell (eye-on-base, ``T_base_camera``) or mounted on the robot's flange (eye-in-hand,
``T_flange_camera``).

Plan calibration poses (a grid in a box of the robot base frame with bounded random tilts: the flange
facing the camera, or, eye-in-hand, the camera facing a fixed ISO 9409-1 flange plate), drive them one
at a time through the safety gate (poses outside the robot's reach or the workspace box, with its tool,
are replaced before the run by :mod:`.pose_plan`; a pose refused anyway is skipped with a note), scan
the flange at each,
segment it and fit its centre. Eye-on-base feeds each pair to Algorithm 1 until its cost reaches
``e_required``; eye-in-hand (Fig. 14a, §4.1: the plate's position ``q`` in the base is a second
unknown) refits ``X c_i = inv(T_base_flange_i) q`` (:mod:`featurefit`) after each centre and stops
once the fit's predicted translation error reaches ``e_required``. Both stop when the poses run out.
Every capture (cloud + pose + centre) is saved at once, so an interrupted run resumes where it
stopped. Writes ``handeye.json`` (``weldcell/hand-eye@1``), ``samples.json``
(``weldcell/handeye-samples@1``, eye-on-base: usable offline by ``weldcell calibrate hand-eye
RUN_DIR``), the report and, in the simulated cell, the error against the camera's true mount.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.hal.sim import true_camera_mount, world_of
from weldcell.plugins.handeye.featurefit import fit_with_unknown_point, rotation_diversity, translation_sigma
from weldcell.plugins.handeye.pose_plan import PoseCheck, Replacement, replace_unreachable
from weldcell.plugins.handeye.stages import predicted_p_cam
from weldcell.sdk.calibration import CalibrateSettings
from weldcell.sdk.cloud import PointCloud, read_cloud, write_cloud
from weldcell.sdk.errors import DataError, DeviceError, JobError, SafetyError
from weldcell.sdk.geometry import T_from_rpy, frame_from_axes, invert, pose_error
from weldcell.sdk.handeye_files import HandEyeSample, finite_json, write_result, write_samples
from weldcell.sdk.pointfit import scaled_svd_fit

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


def nominal_T_flange_camera(ctx) -> np.ndarray:
    """The flange-mounted camera's mount as the profile states it (eye-in-hand prior)."""
    cam = ctx.profile.devices["camera"].mount
    return T_from_rpy(cam.rpy, cam.xyz)


def _drawer(s: CalibrateSettings, toward) -> Callable[[np.ndarray, int], np.ndarray]:
    """A new planned pose at a given position (the plan's facing and tilt bounds, its own seed)."""

    def draw(p: np.ndarray, k: int) -> np.ndarray:
        return plan_poses(p, p, 1, toward, s.max_tilt, s.max_spin, k)[0][0]

    return draw


def reachable_plan(
    s: CalibrateSettings,
    poses: np.ndarray,
    toward,
    check: PoseCheck | None,
    seed: int,
    to_flange=None,
    start=None,
) -> tuple[np.ndarray, list[Replacement]]:
    """The planned poses with each one the robot cannot take from the previous one (``check``: the gate's
    workspace box, reach, IK and joint move with the robot's tool; the first from the joints ``start``)
    replaced up front (:mod:`.pose_plan`); unchanged without a check."""
    if check is None:
        return poses, []
    centre = (np.asarray(s.box_min, float) + np.asarray(s.box_max, float)) / 2
    draw = _drawer(s, toward)
    return replace_unreachable(poses, centre, draw, check, seed, to_flange=to_flange, start=start)


def plan_in_hand(
    s: CalibrateSettings,
    T_flange_camera: np.ndarray,
    seed: int,
    check: PoseCheck | None = None,
    replaced: list | None = None,
    start=None,
) -> np.ndarray:
    """Eye-in-hand flange poses (n, 4, 4): :func:`plan_poses` plans the camera (grid in the box,
    optical axis toward the feature, bounded random tilts and spin) and the nominal mount turns each
    camera pose into the flange pose that carries it there; with ``check``, camera poses the robot cannot
    take are replaced first (listed in ``replaced``). Refuses a plan whose first ``min_poses`` rotate too
    little to tell the feature from the mount (:func:`rotation_diversity`)."""
    if s.feature_prior is None:
        raise JobError(
            "eye-in-hand calibration needs the fixed feature's rough position: [job.settings] "
            "feature_prior is not set",
            "measure the flange plate's face centre in the robot base frame (a tape measure, a few cm) "
            "and set feature_prior = [x, y, z]",
        )
    toward = s.face_toward if s.face_toward is not None else s.feature_prior
    cams, _ = plan_poses(s.box_min, s.box_max, s.n_poses, toward, s.max_tilt, s.max_spin, seed)
    cams, swaps = reachable_plan(s, cams, toward, check, seed, to_flange=invert(T_flange_camera), start=start)
    if replaced is not None:
        replaced += swaps
    poses = cams @ invert(T_flange_camera)
    first = poses[: s.min_poses]
    turn = rotation_diversity(np.transpose(first[:, :3, :3], (0, 2, 1)))
    if turn < s.min_rotation:
        raise JobError(
            f"the first {len(first)} planned poses turn the camera only {np.degrees(turn):.1f} deg (rms) "
            f"about their least-turned axis; {np.degrees(s.min_rotation):.1f} deg is needed to tell the "
            "feature's position from the camera's offset on the flange",
            "widen [job.settings] box_min/box_max around feature_prior (more viewing directions), raise "
            "max_spin or max_tilt, or lower min_rotation",
        )
    return poses


def ground_truth(ctx, config: str = "eye-on-base") -> np.ndarray | None:
    """The true ``T_base_camera`` (eye-in-hand: ``T_flange_camera``) in the simulated cell (None on
    hardware): :func:`weldcell.hal.sim.true_camera_mount`."""
    return true_camera_mount(ctx, config)


def feature_truth(ctx) -> np.ndarray | None:
    """The true face centre of the simulated cell's fixed flange plate in the robot base frame."""
    world = world_of(ctx)
    plates = [] if world is None else [w for w in world.workpieces if w.kind == "iso9409-plate"]
    if not plates:
        return None
    return (invert(world.T_world("robot.base")) @ plates[0].T_world_workpiece)[:3, 3]


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


# -- the job -------------------------------------------------------------------------------------


def _config(ctx) -> str:
    parent = ctx.profile.devices["camera"].mount.parent
    if parent in ("world", "base"):
        return "eye-on-base"
    if parent == "robot.flange":
        method = getattr(ctx.stage("handeye").s, "method", "")
        if method == "flange-iterative":
            raise JobError(
                "eye-in-hand estimates the fixed feature's position, which Algorithm 1's pool "
                "('flange-iterative') needs known",
                "set method = 'flange' (or 'flange-svd') in [stages.handeye.settings]",
            )
        return "eye-in-hand"
    raise JobError(
        f"the camera is mounted on '{parent}': the online calibration handles a camera fixed in the cell "
        "(eye-on-base, 'world') or on the robot's flange (eye-in-hand, 'robot.flange')",
        "mount the camera on 'world' or 'robot.flange'; for eye-on-arm or co-manipulation, record samples "
        "and run `weldcell calibrate hand-eye DATA_DIR --config ...`",
    )


class _PoolTracker:
    """Eye-on-base: Algorithm 1 online (:class:`IncrementalPool`) on (centre in the camera, the
    flange's feature in the base)."""

    cost_name = "Algorithm 1 cost"

    def __init__(self, pool, feature: np.ndarray) -> None:
        self.pool, self.feature = pool, feature
        self.c: list[np.ndarray] = []
        self.d: list[np.ndarray] = []

    def add(self, c: np.ndarray, T_base_flange: np.ndarray, normal: np.ndarray) -> None:
        self.c.append(c)
        self.d.append((T_base_flange @ np.r_[self.feature, 1.0])[:3])
        self.pool.add(c, self.d[-1])

    @property
    def H(self) -> np.ndarray | None:
        return self.pool.H

    @property
    def cost(self) -> float:
        return self.pool.cost

    @property
    def converged(self) -> bool:
        return self.pool.converged

    def predicted(self, T_goal: np.ndarray) -> np.ndarray | None:
        return None if self.H is None else predicted_p_cam(self.H, T_goal, self.feature)

    def row(self, truth: np.ndarray) -> dict:
        row = {} if self.H is None else {"pool_error": pose_error(self.H, truth)}
        if len(self.c) >= 4:
            row["all_data_error"] = pose_error(scaled_svd_fit(np.array(self.c), np.array(self.d)).T, truth)
        return row

    def metrics(self, index: list[int]) -> dict:
        return {
            "pool": [index[j] for j in self.pool.pool],
            "pool_cost_m": self.pool.cost,
            "pool_converged": self.pool.converged,
        }

    def figures(self, truth: np.ndarray, result, q_true) -> dict:
        if self.H is None:
            return {}
        dt, dr = pose_error(self.H, truth)
        return {
            "algorithm1_error_vs_truth": {"translation_mm": dt * 1e3, "rotation_deg": float(np.degrees(dr))}
        }


class _FeatureTracker:
    """Eye-in-hand: ``X c_i = inv(T_base_flange_i) q`` refit on every centre so far
    (:func:`fit_with_unknown_point`); its cost is the fit's predicted 1-sigma translation error.
    Scans are cropped around where the plate should appear: by the prior (nominal mount and
    ``feature_prior``) until the fit predicts better than :attr:`TRUST` (m), then by the fit."""

    cost_name = "predicted error (1 sigma)"
    TRUST = 0.005

    def __init__(self, flange, seed: int, X_prior: np.ndarray, q_prior) -> None:
        self.flange, self.seed = flange, seed
        self.prior = (np.asarray(X_prior, float), np.asarray(q_prior, float))
        self.c: list[np.ndarray] = []
        self.B: list[np.ndarray] = []
        self.n: list[np.ndarray] = []
        self.fit = None
        self.cost = float("inf")

    def add(self, c: np.ndarray, T_base_flange: np.ndarray, normal: np.ndarray) -> None:
        self.c.append(c)
        self.B.append(invert(T_base_flange))
        self.n.append(normal)
        C, B, fs = np.array(self.c), np.array(self.B), self.flange.s
        try:
            fit = fit_with_unknown_point(
                C,
                B,
                len(C) >= 8,
                fs.n_sigma,
                fs.min_threshold,
                rng=self.seed,
                normals=np.array(self.n),
                normal_weight=fs.normal_weight,
            )
        except DataError:  # too few centres or too little rotation so far
            return
        self.fit, self.cost = fit, translation_sigma(C, B, fit)

    @property
    def converged(self) -> bool:
        return self.fit is not None and self.cost <= self.flange.e_required

    def predicted(self, T_goal: np.ndarray) -> np.ndarray:
        X, q = (self.fit.T, self.fit.q) if self.cost < self.TRUST else self.prior
        return (invert(X) @ invert(T_goal) @ np.r_[q, 1.0])[:3]

    def row(self, truth: np.ndarray) -> dict:
        return {} if self.fit is None else {"all_data_error": pose_error(self.fit.T, truth)}

    def metrics(self, index: list[int]) -> dict:
        return {"predicted_error_m": self.cost, "converged": self.converged}

    def figures(self, truth: np.ndarray, result, q_true) -> dict:
        q = result.extra.get("feature_base")
        if q is None or q_true is None:
            return {}
        return {"feature_error_mm": float(np.linalg.norm(np.asarray(q) - q_true) * 1e3)}


def _record_public(rec: dict) -> dict:
    return {k: v for k, v in rec.items() if not k.startswith("_")}


def _verification(ctx, stage, T_v: np.ndarray, seed: int):
    """The verification scan (face cloud, T_base_flange) for eq. 13: from state.json after a resume."""
    for rec in ctx.state.captures:
        if rec.get("kind") == "verification" and rec.get("status") == "ok" and "file" in rec:
            P = read_cloud(ctx.run_dir / rec["file"], units="m", frame="camera", check_scale=False).points
            m = stage.measure(P, seed=seed)
            return m.face, np.asarray(rec["T_base_flange"], float)
    with ctx.step("verification scan (eq. 13)", kind="checkpointed"):
        rec = _scan(ctx, stage, T_v, "verification", None, seed)
        ctx.state.add_capture({"kind": "verification", **_record_public(rec)})
    if rec["status"] != "ok":
        raise JobError(
            f"verification scan at the box centre failed: {rec['reason']}",
            "make sure the flange at the centre of [job.settings] box_min/box_max faces the camera "
            "in range, or set verifier = 'consensus' in [stages.handeye.settings]",
        )
    return rec["_face"], np.asarray(rec["T_base_flange"], float)


def _not_seen(config: str, n_ok: int, n_planned: int) -> JobError:
    need = 4 if config == "eye-on-base" else 5
    if config == "eye-on-base":
        fix = (
            "check the box faces the camera in range (see the skipped poses in state.json notes), widen "
            "[job.settings] box_min/box_max or the stage's pass-through box"
        )
    else:
        fix = (
            "check [job.settings] feature_prior (the plate's face centre in the base frame) and that "
            "box_min/box_max keep the camera in range of it (see the skipped poses in state.json "
            "notes), and the stage's pass-through box box_min/box_max (camera frame)"
        )
    return JobError(
        f"only {n_ok} flange centre(s) measured from {n_planned} planned poses (need {need})", fix
    )


def _tracker(ctx, config: str, stage, T_v: np.ndarray | None, seed: int):
    """The online estimator (eye-on-base: Algorithm 1 with its verification) and the verification."""
    s: CalibrateSettings = ctx.settings
    flange = getattr(stage, "flange", stage)
    if config == "eye-in-hand":
        return _FeatureTracker(flange, seed, nominal_T_flange_camera(ctx), s.feature_prior), None
    use_icp = stage.needs == "flange" and flange.s.verifier == "icp"
    verification = _verification(ctx, flange, T_v, seed) if (use_icp and s.verification_scan) else None
    if use_icp and verification is None:
        raise JobError(
            "the ICP verifier needs the verification scan",
            "set verification_scan = true, or verifier = 'consensus' in [stages.handeye.settings]",
        )
    pool = flange.pool(verification, verifier=None if use_icp else "consensus")
    return _PoolTracker(pool, np.asarray(flange.s.feature, float)), verification


POSES = "calibration poses (scan + flange + fit)"


def _check_captures(ctx) -> None:
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


def run(ctx) -> dict:
    """The whole job; returns the figures written into result.json."""
    from weldcell.plugins.handeye.report import write_report

    s: CalibrateSettings = ctx.settings
    config = _config(ctx)
    stage = ctx.stage("handeye")
    seed = ctx.profile.cell.seed if s.seed is None else s.seed
    robot = ctx.device("robot")
    check = PoseCheck(robot.gate, robot.T_flange_tcp, robot.motion.joint_speed, robot.motion.joint_accel)
    start = robot.state().q  # the moves are checked from where the robot stands (after a resume: there)
    replaced: list[Replacement] = []
    if config == "eye-in-hand":
        poses, T_v = plan_in_hand(s, nominal_T_flange_camera(ctx), seed, check, replaced, start), None
    else:
        toward = s.face_toward if s.face_toward is not None else nominal_T_base_camera(ctx)[:3, 3]
        poses, T_v = plan_poses(s.box_min, s.box_max, s.n_poses, toward, s.max_tilt, s.max_spin, seed)
        if s.verification_scan and robot.gate.model is not None and start is not None:
            try:  # the verification scan at the box centre comes first
                start = robot.gate.solve(T_v, start, "verification pose")
            except SafetyError:
                pass  # refused when it is visited, with its own message
        poses, replaced = reachable_plan(s, poses, toward, check, seed, start=start)
    if replaced:
        moved = ", ".join(f"{r.index} ({1e3 * r.moved:.0f} mm)" for r in replaced)
        ctx.reporter.info(
            f"planned poses: {len(replaced)} of {len(poses)} could not be reached (from the pose before) "
            f"inside the robot's reach and the cell's workspace box with the tool; replaced by poses nearer "
            f"the box centre (how much nearer): {moved}"
        )
        ctx.state.data["notes"]["replanned"] = [f"pose {r.index}: {r.reason}" for r in replaced]
    truth = ground_truth(ctx, config)

    _check_captures(ctx)
    done = {rec["index"]: rec for rec in ctx.state.captures if rec.get("kind") == "pose"}
    if done:
        ctx.reporter.info(f"resuming with {len(done)} pose(s) already visited")
    tracker, verification = _tracker(ctx, config, stage, T_v, seed)
    track: list[dict] = []
    ok_recs: list[dict] = []

    def feed(rec: dict) -> None:
        tracker.add(*(np.asarray(rec[k], float) for k in ("p_cam", "T_base_flange", "normal")))
        ok_recs.append(rec)
        track.append(
            {"n": len(ok_recs), "cost": tracker.cost, **({} if truth is None else tracker.row(truth))}
        )

    notes: list[str] = []
    stop = "poses exhausted"
    with ctx.step(POSES, total=len(poses), kind="checkpointed") as advance:
        for i, T_goal in enumerate(poses):
            if i in done:
                rec = done[i]
            else:
                predicted = tracker.predicted(T_goal)
                rec = {"kind": "pose", "index": i, **_scan(ctx, stage, T_goal, f"{i:03d}", predicted, seed)}
                ctx.state.add_capture(_record_public(rec))
            if rec["status"] == "ok":
                feed(rec)
            else:
                notes.append(f"pose {i}: {rec['status']}: {rec['reason']}")
                if i not in done and rec["status"] == "refused":  # the gate keeps the robot in reach and box
                    why = (
                        "expected, as above"
                        if any(": refused: " in n for n in notes[:-1])
                        else "expected: the plan spans the whole pose box; the safety gate refuses a "
                        "pose beyond the robot's reach or the cell's workspace and the job calibrates from "
                        "the others"
                    )
                    ctx.reporter.info(f"pose {i} left out ({why}): {rec['reason']}")
                elif i not in done:
                    ctx.reporter.info(f"[yellow]pose {i} {rec['status']}: {rec['reason']}[/yellow]")
            advance(
                i + 1, len(poses), f"{len(ok_recs)} centres, {tracker.cost_name} {tracker.cost * 1e3:.3g} mm"
            )
            if s.stop_at_target and tracker.converged and len(ok_recs) >= s.min_poses:
                stop = f"{tracker.cost_name} {tracker.cost * 1e3:.3f} mm <= e_required after {len(ok_recs)} "
                stop += "centres"
                break
    ctx.state.data["notes"]["skipped"] = notes
    ctx.state.save()

    samples = [
        HandEyeSample(
            T_base_flange=np.asarray(r["T_base_flange"], float),
            p_cam=np.asarray(r["p_cam"], float),
            T_cam_target=None if "T_cam_target" not in r else np.asarray(r["T_cam_target"]),
            cloud=str(ctx.run_dir / r["file"]) if "file" in r else None,
            meta={"index": r["index"], "normal": r["normal"]},
        )
        for r in ok_recs
    ]
    if len(samples) < (4 if config == "eye-on-base" else 5):
        raise _not_seen(config, len(samples), len(poses))
    extra = {"feature_base": "estimate"} if config == "eye-in-hand" else {}
    with ctx.step(f"solve ({stage.name}, {getattr(stage.s, 'method', '')})"):
        result = stage.solve(samples, config, verification=verification, **extra)
    index = [int(r["index"]) for r in ok_recs]
    result.metrics["online"] = {
        "planned": len(poses),
        "visited": sum(1 for r in ctx.state.captures if r.get("kind") == "pose"),
        "centres": len(samples),
        "refused": sum("refused" in n for n in notes),
        "no_flange": sum("no-flange" in n for n in notes),
        "stop": stop,
        **tracker.metrics(index),
        "cost_history_m": [t["cost"] for t in track],
    }
    result.metrics["sample_index"] = index
    if isinstance(tracker, _PoolTracker) and tracker.H is not None and not np.isfinite(tracker.cost):
        result.warnings.append(
            "online Algorithm 1 never verified a pool (eq. 13 cost +inf at every pair): the flange model "
            "does not match the verification scan; the result is the offline solve's"
        )
    result.warnings += [f"skipped {n}" for n in notes]
    write_result(ctx.path("handeye.json"), result)
    write_samples(ctx.path("samples.json"), samples, config, feature_base=extra.get("feature_base"))
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
        figures.update(tracker.figures(truth, result, feature_truth(ctx)))
    if ctx.profile.output.report:
        with ctx.step("report"):
            write_report(ctx, result, track, notes, truth, stop)
    return finite_json(figures)  # result.json: strict JSON (a NaN/inf becomes null with its reason)
