"""Table III of paper 004: ATE and AE without and with map segmentation, on the same run.

Without: the estimator's key-frame poses (one global map). With: the poses the segmented map gives
(segment pose chained by the hand-overs x key frame pose in its segment). Both are scored the same way:
ATE = RMSE of key-frame camera positions after SE(3) Umeyama alignment; AE = the weld plates' corner
distance error from the detections back-projected at those poses and fused into regions (TSDF surface
when enabled), as :mod:`~weldcell.plugins.mapping.finish` does for the run's own figures.

One computation for the job and benchmarks/map_segmentation.py: :func:`ate_figures` takes the local maps
(live, or read back from a map folder's manifest by :func:`segments_from_manifest`), the key frames' final
poses and their ground truth, and scores both trajectories on the same key frames (those in a local map
that have a truth pose).
"""

from __future__ import annotations

import numpy as np
from weldcell.plugins.mapping.interp import ate_rmse
from weldcell.plugins.mapping.mapstore import tsdf_region
from weldcell.plugins.mapping.regions import RegionFuser, detection_points
from weldcell.plugins.mapping.segmentation import HandOver, SegmentPlan, segmented_trajectory


def segments_from_manifest(manifest: dict) -> list[SegmentPlan]:
    """The local maps of a map folder's manifest (``weldcell/map-segments@1`` with the mapping plugin's
    ``keyframes`` and ``handover`` entries) as the segmenter made them: key frames and hand-overs."""
    out = []
    for e in sorted(manifest.get("segments", []), key=lambda e: e["id"]):
        ho, h = None, e.get("handover")
        if h:
            T = np.asarray(h["T_last_first"], float)
            ho = HandOver(int(e["id"]), int(h["last_keyframe"]), int(h["first_keyframe"]), h["method"], T, T)
        out.append(SegmentPlan(int(e["id"]), keyframes=[int(k) for k in e["keyframes"]], handover=ho))
    return out


def ate_figures(segments, T_world_cam: dict[int, np.ndarray], truth: dict[int, np.ndarray]):
    """Table III's ATE without and with segmentation, on the same key frames (in a local map, with truth).

    ``T_world_cam``: the key frames' final camera poses (the estimator's, one global map); ``truth``: key
    frame -> true camera pose. Returns ``(figures, poses with segmentation, A_without, A_with)`` where the
    A are the Umeyama alignments (for the AE) or ``({}, ...)`` with fewer than 3 key frames."""
    seg = segmented_trajectory(segments, T_world_cam)
    keys = sorted(k for k in seg if k in truth)
    if len(keys) < 3:
        return {}, seg, None, None
    ref = np.array([truth[k][:3, 3] for k in keys])
    ate0, A0 = ate_rmse(np.array([T_world_cam[k][:3, 3] for k in keys]), ref)
    ate1, A1 = ate_rmse(np.array([seg[k][:3, 3] for k in keys]), ref)
    figures = {
        "ate_unsegmented_m": ate0,
        "ate_segmented_m": ate1,
        "ate_segmentation_change_pct": 100.0 * (ate1 - ate0) / ate0 if ate0 > 0 else 0.0,
        "table3_keyframes": len(keys),
    }
    return figures, seg, A0, A1


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
    vio = {k.index: k.T_world_imu @ est.T_imu_cam for k in est.keyframes}
    kf_truth = {k.index: truth[round(k.t, 6)] for k in est.keyframes if round(k.t, 6) in truth}
    out, seg, A0, A1 = ate_figures(segments, vio, kf_truth)
    if not out:
        return {}
    if ctx.settings.segmentation.evaluate_ae and tr.detections:
        ae0, ae1 = region_ae(ctx, tr, rig, vio, A0), region_ae(ctx, tr, rig, seg, A1)
        if ae0 is not None and ae1 is not None:
            out.update(
                ae_unsegmented_mm=ae0,
                ae_segmented_mm=ae1,
                ae_segmentation_change_pct=100.0 * (ae1 - ae0) / ae0 if ae0 > 0 else 0.0,
            )
    return out
