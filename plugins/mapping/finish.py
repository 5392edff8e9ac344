"""The ``map`` job after driving: resume, map building (eq. 3), weld regions, evaluation and files."""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.plugins.mapping.estimator import KeyFrame
from weldcell.plugins.mapping.frontend import FrameFeatures
from weldcell.plugins.mapping.interp import ate_rmse, interpolate_trajectory
from weldcell.plugins.mapping.mapstore import KeyFrameStore, VoxelMap, back_project, tsdf_region
from weldcell.plugins.mapping.plate import plate_fit
from weldcell.plugins.mapping.regions import (
    REGIONS_SCHEMA,
    RegionFuser,
    apply_decisions,
    corner_distance_error,
    detection_points,
    plate_corners,
)
from weldcell.sdk import artifacts


def resume_if_any(ctx, rig, tr) -> None:
    """With key frames already in the run's store (``--resume``), restore the estimator at the last one
    and (in simulation) put the site's clock and sensors there."""
    if not ctx.state.captures or not tr.store.index_path.is_file():
        return
    old = KeyFrameStore.load(tr.store.root)
    kfs = []
    for r in sorted(old.records, key=lambda r: r.index):
        d = old.read(r)
        feats = FrameFeatures(d["pixels"].astype(float), d["descriptors"], d["points"].astype(float))
        if "depth" in d:  # each point's depth sigma, as the key frame had it (PnP and loop references)
            tr.estimator.fe.add_depth_sigmas(feats, d["depth"], old.intrinsics)
        kfs.append(
            KeyFrame(
                r.index,
                r.t,
                r.stamp,
                None,
                None,
                old.intrinsics,
                feats,
                r.T_world_imu,
                r.velocity,
                r.bias,
                r.visual,
                None,
            )
        )
    if [k.index for k in kfs] != list(range(len(kfs))):
        from weldcell.sdk.errors import DataError

        raise DataError(f"the key-frame store in {tr.store.root} has gaps", "start a new run (no --resume)")
    from weldcell.sdk.stages import Detection2D

    for c in ctx.state.captures:  # the detections of the interrupted run
        if "detections" in c:
            dets = [Detection2D(tuple(d[:4]), d[4], int(d[5]), float(d[6])) for d in c["detections"]]
            tr.detections.append((int(c["keyframe"]), dets))
    tr.store.records = old.records
    tr.store.intrinsics = old.intrinsics
    tr.estimator.restore(kfs)
    t_last = kfs[-1].t
    if rig.site is not None:
        clock = rig.site.world.clock
        clock.advance(t_last + 1e-3 - clock.t)
        for dev in (rig.imu, rig.gnss):
            if dev is not None and dev.sim is not None:
                dev.sim.t_next = max(t_last - 0.05, 0.0)
    ctx.reporter.info(f"resuming after key frame {kfs[-1].index} (t={t_last:.2f} s)")


def _tum(path, t: np.ndarray, T: np.ndarray) -> None:
    q = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    rows = [
        f"{ti:.6f} " + " ".join(f"{v:.6f}" for v in (*Ti[:3, 3], *qi))
        for ti, Ti, qi in zip(t, T, q, strict=False)
    ]
    artifacts.write_text(path, "\n".join(rows) + "\n")


def build_map(ctx, tr) -> tuple[VoxelMap, dict]:
    """Eq. (3) for every key frame at its final pose, fused into the global voxel map."""
    ms = ctx.settings.map
    vm = VoxelMap(ms.voxel)
    poses = {k.index: (k.T_world_imu, k.T_world_imu @ tr.estimator.T_imu_cam) for k in tr.estimator.keyframes}
    tr.store.update_poses(poses, {k.index: k.covariance for k in tr.estimator.keyframes})
    tr.store.save_index()
    cache = {}
    for r in tr.store.records:
        d = tr.store.read(r)
        P, C = back_project(
            d["depth"], tr.store.intrinsics, r.T_world_cam, d["rgb"], ms.pixel_step, ms.max_depth
        )
        vm.integrate(P, C)
        cache[r.index] = r
    vm.save(ctx.path("map/map.ply"))
    return vm, cache


def fuse_regions(ctx, tr) -> tuple[list, list]:
    """Detections of every key frame back-projected (camera -> IMU -> world) and fused into regions."""
    fuser = RegionFuser()
    recs = {r.index: r for r in tr.store.records}
    for idx, dets in tr.detections:
        if idx not in recs or not dets:
            continue
        d = tr.store.read(recs[idx])
        for det in dets:
            P = detection_points(det, d["depth"], tr.store.intrinsics, recs[idx].T_world_cam)
            fuser.add(det, P, idx)
    regions = fuser.regions
    for r in regions:  # a region seen once is likely a false alarm: kept, flagged for the operator
        if len(r.observations) < 2:
            r.decision = "unconfirmed"
    log = apply_decisions(regions, ctx.settings.decisions)
    if not regions:
        tr.estimator._event(
            0.0,
            "warning",
            "the detector found no weld region; add regions by hand "
            "(decisions file 'add') or check the detector's model and classes",
        )
    return regions, log


def _region_tsdf(ctx, tr, region) -> np.ndarray | None:
    ms = ctx.settings.map
    if not ms.tsdf:
        return None
    lo = region.points.min(0) - ms.region_margin
    hi = region.points.max(0) + ms.region_margin
    recs = [r for r in tr.store.records if r.index in set(region.observations)] or tr.store.records[-3:]
    kfs = []
    for r in recs[:12]:
        d = tr.store.read(r)
        kfs.append(
            {
                "rgb": d["rgb"],
                "depth": d["depth"],
                "intrinsics": tr.store.intrinsics,
                "T_world_cam": r.T_world_cam,
            }
        )
    mesh = tsdf_region(kfs, lo, hi, ms.tsdf_voxel)
    if mesh is None or len(mesh.vertices) == 0:
        return None
    import open3d as o3d

    o3d.io.write_triangle_mesh(str(ctx.path(f"map/regions/{region.id}.ply")), mesh)
    return np.asarray(mesh.vertices)


def region_crop(region) -> tuple[np.ndarray, np.ndarray]:
    """The world box whose depth pixels the plate measurement takes: the region's robust extent (2-98 %
    of its points) + 0.15 m (written to regions.json as ``pixels_box``, so a benchmark takes the same)."""
    return np.percentile(region.points, 2, axis=0) - 0.15, np.percentile(region.points, 98, axis=0) + 0.15


def region_pixels(ctx, tr, region, poses: dict | None = None):
    """The depth pixels of every key frame that observed ``region`` (at ``poses``: key frame ->
    T_world_cam, default the store's), within the region's robust extent + 0.15 m, with their rays and
    depth noise (:mod:`~weldcell.plugins.mapping.plate`)."""
    from weldcell.plugins.mapping.plate import frame_observations, merge

    if len(region.points) < 20:
        return None
    lo, hi = region_crop(region)
    from weldcell.plugins.mapping.plate_poses import camera_pose_cov

    recs = {r.index: r for r in tr.store.records}
    obs = []
    for i in dict.fromkeys(region.observations):
        if i not in recs or (poses is not None and i not in poses):
            continue
        T = recs[i].T_world_cam if poses is None else poses[i]
        d = tr.store.read(recs[i])
        cov = recs[i].covariance  # the key frame's pose error, for the box fit's pass corrections
        pc = None if cov is None or poses is not None else camera_pose_cov(recs[i].T_world_imu, cov, T)
        noise = ctx.settings.frontend.depth_noise
        obs.append(frame_observations(d["depth"], tr.store.intrinsics, T, lo, hi, noise, i, pc))
    return merge(obs) if obs else None


def evaluate(ctx, tr, rig, regions) -> dict:
    """ATE (key frames and camera-rate via eq. 2, slerp and linear) and AE on the plates."""
    est = tr.estimator
    figs: dict = {}
    t_kf, T_kf = est.keyframe_trajectory()
    truth = {round(t, 6): T for t, T in tr.truth_frames}
    have = [i for i, t in enumerate(t_kf) if round(t, 6) in truth]
    if len(have) >= 3:
        ref = np.array([truth[round(t_kf[i], 6)][:3, 3] for i in have])
        figs["ate_rmse_m"], A = ate_rmse(T_kf[have, :3, 3], ref)
        figs["ate_keyframes"] = len(have)
        tq = np.array([t for t, _ in tr.truth_frames if t_kf[0] <= t <= t_kf[-1]])
        refq = np.array([T[:3, 3] for t, T in tr.truth_frames if t_kf[0] <= t <= t_kf[-1]])
        for m in ("slerp", "linear"):
            Tq = interpolate_trajectory(t_kf, T_kf, tq, m)
            figs[f"ate_frames_{m}_m"] = ate_rmse(Tq[:, :3, 3], refq)[0]
        figs.update(_interp_effect(t_kf, T_kf, tq))
        figs["_align"] = A
    if rig.site is not None and regions:
        figs.update(_region_errors(rig, regions, figs.get("_align")))
    return figs


def _interp_effect(t_kf: np.ndarray, T_kf: np.ndarray, tq: np.ndarray) -> dict:
    """What the paper's linear rotation interpolation (eq. 2, not re-orthonormalised) does to a map point
    5 m in front of the camera, against slerp: mean and max displacement (mm)."""
    from weldcell.plugins.mapping.interp import interpolate_pose

    p = np.array([0.0, 0.0, 5.0])
    idx = np.clip(np.searchsorted(t_kf, tq, side="right") - 1, 0, len(t_kf) - 2)
    d = []
    for k, t in zip(idx, tq, strict=True):
        a, b = T_kf[k], T_kf[k + 1]
        raw = interpolate_pose(a, b, t_kf[k], t_kf[k + 1], t, "linear", project=False)
        sl = interpolate_pose(a, b, t_kf[k], t_kf[k + 1], t, "slerp")
        d.append(np.linalg.norm(raw[:3, :3] @ p - sl[:3, :3] @ p))
    d = np.asarray(d) * 1000
    return {
        "interp_linear_raw_mean_mm_at_5m": float(d.mean()),
        "interp_linear_raw_max_mm_at_5m": float(d.max()),
    }


def _plate_corners(region) -> tuple[np.ndarray | None, str, dict]:
    """A plate region's top corners and, when it is not measured, why; and what the measurement used (the
    passes whose poses it corrected, the sides' standard deviations). With the key frames' pixels the box
    fit (plate.py) measures it or says why the views do not determine it; a region without pixels (re-fused
    from points only) is measured on its points (its TSDF surface measures worse: docs/methods/mapping.md)."""
    obs = getattr(region, "plate", None)
    if obs is None:
        corners = plate_corners(region.points)
        return corners, "" if corners is not None else "too few points on the plate's top", {}
    fit = plate_fit(obs)
    if fit is None:
        return None, "too few depth pixels on the plate's top", {}
    sd = np.sqrt(np.abs(np.diag(fit.cov)))[3:5] * 1000 if np.all(np.isfinite(fit.cov)) else [np.nan] * 2
    info = {"views": fit.views, "passes": len(fit.passes), "sides_sigma_mm": [float(v) for v in sd]}
    return (fit.corners, "", info) if fit.ok else (None, fit.reason, info)


def _region_errors(rig, regions, A) -> dict:
    out: dict = {"regions_truth": 0, "regions_found": 0}
    ae, pos, unmeasured = [], [], []
    truth = [w for w in rig.site.weld_truth()]
    out["regions_truth"] = len(truth)
    for w in truth:
        c_true = (w["min"] + w["max"]) / 2
        best = None
        for r in regions:
            if r.decision == "rejected":
                continue
            c = r.center if A is None else A[:3, :3] @ r.center + A[:3, 3]
            if np.linalg.norm(c - c_true) < 0.8 and (best is None or np.linalg.norm(c - c_true) < best[1]):
                best = (r, float(np.linalg.norm(c - c_true)))
        if best is None:
            continue
        out["regions_found"] += 1
        r = best[0]
        if w["corners"] is not None:
            corners, why, info = _plate_corners(r)
            if corners is not None:
                ae.append(corner_distance_error(corners, w["corners"]))
                r.truth = w["name"]
                out.setdefault("ae_per_plate", []).append(
                    {"plate": w["name"], "ae_mm": 1000 * ae[-1], **info}
                )
            else:  # reported, not guessed: the views do not determine the plate
                unmeasured.append({"plate": w["name"], "reason": why})
        pos.append(best[1])
    if unmeasured:
        out["ae_unmeasured"] = unmeasured
    if ae:
        out["ae_mm"] = float(np.mean(ae) * 1000)
        out["ae_plates"] = len(ae)
    if pos:
        out["region_position_error_m"] = float(np.mean(pos))
    return out


def finish(ctx, rig, tr) -> dict:
    """Map, regions, evaluation, files and the report; returns the result figures."""
    from weldcell.plugins.mapping.report import write_report

    est = tr.estimator
    if not est.keyframes:
        from weldcell.sdk.errors import JobError

        raise JobError(
            "no key frame was made: the estimator never initialised",
            "keep the robot still for init_time seconds at the start with the IMU streaming",
        )
    with ctx.step("global optimisation"):  # eq. 5 over every key frame, with the loop closures
        est.finalize()
    with ctx.step("map"):
        t0 = time.perf_counter()
        vm, _ = build_map(ctx, tr)
        est.timing["map"] = [(time.perf_counter() - t0) / max(1, len(tr.store.records))]
    with ctx.step("weld regions"):
        regions, log = fuse_regions(ctx, tr)
        for r in regions:
            if r.decision != "rejected":
                r.dense = _region_tsdf(ctx, tr, r)
                r.plate = region_pixels(ctx, tr, r)
    figs = evaluate(ctx, tr, rig, regions)
    A = figs.pop("_align", None)
    _write_trajectories(ctx, tr)
    _write_regions(ctx, regions, log)
    ctx.write_json("events.json", {"schema": "weldcell/map-events@1", "events": est.events})
    figures = _result_figures(tr, figs, vm, regions)
    if ctx.profile.output.report:
        with ctx.step("report"):
            write_report(ctx, tr, rig, regions, figures, A)
    return figures


def _write_trajectories(ctx, tr) -> None:
    """trajectory_keyframes.tum, truth_keyframes.tum (simulation) and trajectory_frames.tum (eq. 2: every
    camera frame between the optimised key-frame poses)."""
    est = tr.estimator
    t_kf, T_kf = est.keyframe_trajectory()
    _tum(ctx.path("trajectory_keyframes.tum"), t_kf, T_kf)
    truth = {round(t, 6): T for t, T in tr.truth_frames}
    if truth and all(round(t, 6) in truth for t in t_kf):  # simulation: ground truth beside it
        _tum(ctx.path("truth_keyframes.tum"), t_kf, np.array([truth[round(t, 6)] for t in t_kf]))
    tf = np.array([p[0] for p in est.frame_poses if t_kf[0] <= p[0] <= t_kf[-1]])
    if len(t_kf) >= 2 and len(tf):
        method = ctx.settings.estimator.interpolation
        _tum(ctx.path("trajectory_frames.tum"), tf, interpolate_trajectory(t_kf, T_kf, tf, method))


def _write_regions(ctx, regions, log) -> None:
    """regions.json (``weldcell/weld-regions@1``): each region with its decision, box and dense surface."""
    ctx.write_json(
        "regions.json",
        {
            "schema": REGIONS_SCHEMA,
            "frame": "world",
            "units": "m",
            "regions": [
                {
                    "id": r.id,
                    "label": r.label,
                    "decision": r.decision,
                    "observations": r.observations,
                    "score": float(np.mean(r.scores)) if r.scores else None,
                    "center": r.center.tolist(),
                    "oriented_box": r.oriented_box(),
                    "points": len(r.points),
                    **({"pixels_box": [b.tolist() for b in region_crop(r)]} if len(r.points) >= 20 else {}),
                    "dense_surface": f"map/regions/{r.id}.ply"
                    if getattr(r, "dense", None) is not None
                    else None,
                }
                for r in regions
            ],
            "decisions": log,
        },
    )


def _result_figures(tr, figs: dict, vm, regions) -> dict:
    """The run's result figures: the evaluation's, the counts and the time per stage."""
    est = tr.estimator
    timing = {
        k: {"mean_ms": float(np.mean(v) * 1000), "std_ms": float(np.std(v) * 1000), "n": len(v)}
        for k, v in est.timing.items()
        if v
    }
    return {
        **{k: v for k, v in figs.items() if not isinstance(v, np.ndarray)},
        "keyframes": len(est.keyframes),
        "frames": tr.frames,
        "map_points": len(vm),
        "regions": len(regions),
        "tracking_lost_events": sum(e["kind"] == "lost" for e in est.events),
        "loop_closures": len(est.global_graph.loops),
        "gnss_aligned": est.T_world_enu is not None,
        "time_per_stage": timing,
        "frame_seconds_mean": float(np.mean(tr.frame_seconds)) if tr.frame_seconds else None,
    }
