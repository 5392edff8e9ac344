"""Map segmentation while driving (§II-D): the cut policy, chaining by hand-overs, and the second
visit's priors when GNSS has no fix."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
from weldcell.plugins.mapping.segmentation import (
    HandOver,
    SegmentationSettings,
    Segmenter,
    chain_poses,
    segmented_trajectory,
)

K = SimpleNamespace(fx=50.0, fy=50.0, cx=20.0, cy=15.0, width=40, height=30)


def _kf(i, depth=2.0):
    return SimpleNamespace(index=i, depth=np.full((30, 40), depth, np.float32), intrinsics=K, visual=True)


def _pose(x, yaw=0.0):
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3] = x
    return T


class _NoFrontend:  # the hand-over is not under test here: "vio" never calls the front end
    pass


def test_cut_by_distance_then_by_points():
    s = SegmentationSettings(max_distance=1.0, max_points=10**6, handover="vio")
    seg = Segmenter(s, 0.05, 4, 6.0)
    for i in range(12):
        seg.add(
            _kf(i),
            _pose(0.25 * i),
            _NoFrontend(),
            _kf(i - 1) if i else None,
            _pose(0.25 * (i - 1)) if i else None,
        )
    assert [g.keyframes[0] for g in seg.segments] == [0, 4, 8]  # a new local map every 1 m
    assert all(g.handover.method == "vio" for g in seg.segments[1:])
    s = SegmentationSettings(max_distance=100.0, max_points=1000, handover="vio")
    seg = Segmenter(s, 0.01, 1, 6.0)
    for i in range(6):  # every frame sees a new 40 x 30 patch at 1 m spacing: 1200 voxels > 1000
        seg.add(
            _kf(i),
            _pose(1.0 * i),
            _NoFrontend(),
            _kf(i - 1) if i else None,
            _pose(1.0 * (i - 1)) if i else None,
        )
    assert len(seg.segments) == 6 and all(len(g.keyframes) == 1 for g in seg.segments)
    assert SegmentationSettings().max_distance == 15.0 and SegmentationSettings().max_points == 500_000


def test_segments_are_chained_by_their_hand_overs():
    poses = {i: _pose(0.5 * i, 0.02 * i) for i in range(6)}
    s = SegmentationSettings(max_distance=1.0, handover="vio")
    seg = Segmenter(s, 0.05, 4, 6.0)
    for i in range(6):
        seg.add(_kf(i), poses[i], _NoFrontend(), _kf(i - 1) if i else None, poses.get(i - 1))
    same = segmented_trajectory(seg.segments, poses)
    assert all(np.allclose(same[i], poses[i]) for i in poses)  # estimator's hand-over: no change
    bump = _pose(0.0)
    bump[1, 3] = 0.1  # a hand-over 10 cm off moves every later local map by it
    g = seg.segments[1]
    g.handover = HandOver(
        1,
        g.handover.last_keyframe,
        g.handover.first_keyframe,
        "orb-ndt",
        g.handover.T_last_first @ bump,
        g.handover.T_estimator,
    )
    T_ws, local = chain_poses(seg.segments, poses)
    moved = segmented_trajectory(seg.segments, poses)
    assert np.allclose(moved[0], poses[0]) and not np.allclose(moved[5], poses[5])
    assert np.allclose(T_ws[0], poses[0]) and set(local) == set(poses)


def test_second_visit_without_gnss_fix_falls_back_to_keyframe_sampling():
    from weldcell.plugins.mapping.settings import MapJobSettings
    from weldcell.plugins.mapping.visits import priors

    def tr(enu):
        kfs = [SimpleNamespace(T_world_imu=_pose(0.3 * i)) for i in range(5)]
        return SimpleNamespace(estimator=SimpleNamespace(T_world_enu=enu, keyframes=kfs, T_imu_cam=np.eye(4)))

    ctx = SimpleNamespace(settings=MapJobSettings())
    out, notes = priors(ctx, tr(np.eye(4)), tr(None), 1.0, 0.25)  # the second visit never had a fix
    assert "position" not in out and len(out["keyframe_positions"]) == 5
    assert out["yaw"] == 0.75 and any("GNSS not aligned" in n for n in notes)
    out, _ = priors(ctx, tr(_pose(2.0)), tr(_pose(-1.0)), None, 0.25)
    assert np.allclose(out["position"], [3.0, 0, 0]) and "yaw" not in out
