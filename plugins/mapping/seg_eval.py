"""Table III of paper 004: ATE and AE without and with map segmentation, on the same run.

Without: the estimator's key-frame poses (one global map). With: the poses the segmented map gives
(segment pose chained by the hand-overs x key frame pose in its segment). Both are scored the same way:
ATE = RMSE of key-frame camera positions after SE(3) Umeyama alignment; AE = the weld plates' corner
distance error from the detections back-projected at those poses and fused into regions (TSDF surface
when enabled), as :mod:`~weldcell.plugins.mapping.finish` does for the run's own figures.
"""

from __future__ import annotations

import numpy as np
from weldcell.plugins.mapping.interp import ate_rmse
from weldcell.plugins.mapping.mapstore import tsdf_region
from weldcell.plugins.mapping.regions import RegionFuser, detection_points
from weldcell.plugins.mapping.segmentation import segmented_trajectory


def region_ae(ctx, tr, rig, poses: dict[int, np.ndarray], A: np.ndarray | None) -> float | None:
    """Mean plate AE (mm) of the run's detections placed at ``poses`` (key frame -> T_world_cam)."""
    from weldcell.plugins.mapping.finish import _region_errors

    fuser = RegionFuser()
    recs = {r.index: r for r in tr.store.records}
    cache: dict[int, dict] = {}

    def read(i):
        if i not in cache:
            cache[i] = tr.store.read(recs[i])
        return cache[i]

    for idx, dets in tr.detections:
        if idx not in recs or idx not in poses or not dets:
            continue
        for det in dets:
            fuser.add(det, detection_points(det, read(idx)["depth"], tr.store.intrinsics, poses[idx]), idx)
    regions = [r for r in fuser.regions if len(r.observations) >= 2]
    ms = ctx.settings.map
    for r in regions:
        r.dense = None
        if not ms.tsdf:
            continue
        lo, hi = r.points.min(0) - ms.region_margin, r.points.max(0) + ms.region_margin
        kfs = [
            {
                "rgb": read(i)["rgb"],
                "depth": read(i)["depth"],
                "intrinsics": tr.store.intrinsics,
                "T_world_cam": poses[i],
            }
            for i in r.observations[:12]
            if i in poses
        ]
        mesh = tsdf_region(kfs, lo, hi, ms.tsdf_voxel)
        if mesh is not None and len(mesh.vertices):
            r.dense = np.asarray(mesh.vertices)
    out = _region_errors(rig, regions, A)
    return out.get("ae_mm")


def evaluate_segmentation(ctx, rig, tr, segments) -> dict:
    """Table III figures of this run (simulation: needs ground truth)."""
    est = tr.estimator
    truth = {round(t, 6): T for t, T in tr.truth_frames}
    kfs = [k for k in est.keyframes if round(k.t, 6) in truth]
    if len(kfs) < 3:
        return {}
    vio = {k.index: k.T_world_imu @ est.T_imu_cam for k in est.keyframes}
    seg = segmented_trajectory(segments, vio)
    ref = np.array([truth[round(k.t, 6)][:3, 3] for k in kfs])
    ate0, A0 = ate_rmse(np.array([vio[k.index][:3, 3] for k in kfs]), ref)
    ate1, A1 = ate_rmse(np.array([seg[k.index][:3, 3] for k in kfs]), ref)
    out = {
        "ate_unsegmented_m": ate0,
        "ate_segmented_m": ate1,
        "ate_segmentation_change_pct": 100.0 * (ate1 - ate0) / ate0 if ate0 > 0 else 0.0,
    }
    if ctx.settings.segmentation.evaluate_ae and tr.detections:
        ae0, ae1 = region_ae(ctx, tr, rig, vio, A0), region_ae(ctx, tr, rig, seg, A1)
        if ae0 is not None and ae1 is not None:
            out.update(
                ae_unsegmented_mm=ae0,
                ae_segmented_mm=ae1,
                ae_segmentation_change_pct=100.0 * (ae1 - ae0) / ae0 if ae0 > 0 else 0.0,
            )
    return out
