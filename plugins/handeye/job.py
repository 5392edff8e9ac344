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

Visiting a pose is :mod:`.pose_capture`; the online estimators are :mod:`.online_trackers`; this module
plans the poses and composes the job (:func:`run`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.hal.sim import true_camera_mount, world_of
from weldcell.plugins.handeye.featurefit import rotation_diversity
from weldcell.plugins.handeye.online_trackers import FeatureTracker, PoolTracker
from weldcell.plugins.handeye.pose_capture import (
    POSES,
    check_captures,
    public_record,
    scan_pose,
    verification_scan,
)
from weldcell.plugins.handeye.pose_plan import PoseCheck, Replacement, replace_unreachable
from weldcell.sdk.calibration import CalibrateSettings
from weldcell.sdk.errors import DataError, JobError, SafetyError
from weldcell.sdk.geometry import T_from_rpy, frame_from_axes, invert, pose_error
from weldcell.sdk.handeye_files import HandEyeSample, finite_json, write_result, write_samples

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
        return FeatureTracker(flange, seed, nominal_T_flange_camera(ctx), s.feature_prior), None
    use_icp = stage.needs == "flange" and flange.s.verifier == "icp"
    verification = verification_scan(ctx, flange, T_v, seed) if (use_icp and s.verification_scan) else None
    if use_icp and verification is None:
        raise JobError(
            "the ICP verifier needs the verification scan",
            "set verification_scan = true, or verifier = 'consensus' in [stages.handeye.settings]",
        )
    pool = flange.pool(verification, verifier=None if use_icp else "consensus")
    return PoolTracker(pool, np.asarray(flange.s.feature, float)), verification


@dataclass
class _Visits:
    """What the pose loop gathered: records with a centre, the estimator's track, notes, why it stopped."""

    ok_recs: list[dict] = field(default_factory=list)
    track: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    stop: str = "poses exhausted"


def run(ctx) -> dict:
    """The whole job; returns the figures written into result.json."""
    from weldcell.plugins.handeye.report import write_report

    s: CalibrateSettings = ctx.settings
    config = _config(ctx)
    stage = ctx.stage("handeye")
    seed = ctx.profile.cell.seed if s.seed is None else s.seed
    poses, T_v = _plan(ctx, config, seed)
    truth = ground_truth(ctx, config)

    check_captures(ctx)
    done = {rec["index"]: rec for rec in ctx.state.captures if rec.get("kind") == "pose"}
    if done:
        ctx.reporter.info(f"resuming with {len(done)} pose(s) already visited")
    tracker, verification = _tracker(ctx, config, stage, T_v, seed)
    visits = _visit_poses(ctx, stage, poses, done, tracker, truth, seed)
    samples, result, extra = _solve(ctx, stage, config, len(poses), tracker, verification, visits)
    write_result(ctx.path("handeye.json"), result)
    write_samples(ctx.path("samples.json"), samples, config, feature_base=extra.get("feature_base"))
    figures: dict = {
        "transform": result.name,
        "method": result.method,
        "samples": len(samples),
        "inliers": int(np.sum(result.inliers)),
        "stop": visits.stop,
        "rms_inliers_mm": 1e3 * result.metrics.get("rms_inliers_m", float("nan")),
    }
    if truth is not None:
        dt, dr = pose_error(result.T, truth)
        figures["error_vs_truth"] = {"translation_mm": dt * 1e3, "rotation_deg": float(np.degrees(dr))}
        figures.update(tracker.figures(truth, result, feature_truth(ctx)))
    if ctx.profile.output.report:
        with ctx.step("report"):
            write_report(ctx, result, visits.track, visits.notes, truth, visits.stop)
    return finite_json(figures)  # result.json: strict JSON (a NaN/inf becomes null with its reason)


def _plan(ctx, config: str, seed: int) -> tuple[np.ndarray, np.ndarray | None]:
    """The calibration poses (each reachable from the one before, with the tool, inside the box) and the
    verification pose (eye-on-base; None eye-in-hand); replaced poses are reported and noted."""
    s: CalibrateSettings = ctx.settings
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
    return poses, T_v


def _visit_poses(ctx, stage, poses, done: dict[int, dict], tracker, truth, seed: int) -> _Visits:
    """Visit every planned pose (those ``done`` in an earlier attempt are read back), feeding each centre
    to the online estimator, until the poses run out or (``stop_at_target``) the estimate is good enough."""
    s: CalibrateSettings = ctx.settings
    v = _Visits()

    def feed(rec: dict) -> None:
        tracker.add(*(np.asarray(rec[k], float) for k in ("p_cam", "T_base_flange", "normal")))
        v.ok_recs.append(rec)
        v.track.append(
            {"n": len(v.ok_recs), "cost": tracker.cost, **({} if truth is None else tracker.row(truth))}
        )

    notes = v.notes
    with ctx.step(POSES, total=len(poses), kind="checkpointed") as advance:
        for i, T_goal in enumerate(poses):
            if i in done:
                rec = done[i]
            else:
                predicted = tracker.predicted(T_goal)
                rec = {
                    "kind": "pose",
                    "index": i,
                    **scan_pose(ctx, stage, T_goal, f"{i:03d}", predicted, seed),
                }
                ctx.state.add_capture(public_record(rec))
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
                i + 1,
                len(poses),
                f"{len(v.ok_recs)} centres, {tracker.cost_name} {tracker.cost * 1e3:.3g} mm",
            )
            if s.stop_at_target and tracker.converged and len(v.ok_recs) >= s.min_poses:
                v.stop = (
                    f"{tracker.cost_name} {tracker.cost * 1e3:.3f} mm <= e_required after {len(v.ok_recs)} "
                )
                v.stop += "centres"
                break
    ctx.state.data["notes"]["skipped"] = notes
    ctx.state.save()
    return v


def _solve(ctx, stage, config: str, n_planned: int, tracker, verification, v: _Visits):
    """The stage's offline solve on every centre measured, with the online run's metrics and warnings.
    Returns (samples, result, extra solve arguments)."""
    notes = v.notes
    samples = [
        HandEyeSample(
            T_base_flange=np.asarray(r["T_base_flange"], float),
            p_cam=np.asarray(r["p_cam"], float),
            T_cam_target=None if "T_cam_target" not in r else np.asarray(r["T_cam_target"]),
            cloud=str(ctx.run_dir / r["file"]) if "file" in r else None,
            meta={"index": r["index"], "normal": r["normal"]},
        )
        for r in v.ok_recs
    ]
    if len(samples) < (4 if config == "eye-on-base" else 5):
        raise _not_seen(config, len(samples), n_planned)
    extra = {"feature_base": "estimate"} if config == "eye-in-hand" else {}
    with ctx.step(f"solve ({stage.name}, {getattr(stage.s, 'method', '')})"):
        result = stage.solve(samples, config, verification=verification, **extra)
    index = [int(r["index"]) for r in v.ok_recs]
    result.metrics["online"] = {
        "planned": n_planned,
        "visited": sum(1 for r in ctx.state.captures if r.get("kind") == "pose"),
        "centres": len(samples),
        "refused": sum("refused" in n for n in notes),
        "no_flange": sum("no-flange" in n for n in notes),
        "stop": v.stop,
        **tracker.metrics(index),
        "cost_history_m": [t["cost"] for t in v.track],
    }
    result.metrics["sample_index"] = index
    if isinstance(tracker, PoolTracker) and tracker.H is not None and not np.isfinite(tracker.cost):
        result.warnings.append(
            "online Algorithm 1 never verified a pool (eq. 13 cost +inf at every pair): the flange model "
            "does not match the verification scan; the result is the offline solve's"
        )
    result.warnings += [f"skipped {n}" for n in notes]
    return samples, result, extra
