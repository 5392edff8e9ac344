"""Segmentation into local maps (§II-D) and the segment encodings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from map_transfer_data import corridor, segments_of
from weldcell.plugins.map_transfer import codec
from weldcell.plugins.map_transfer.segments import (
    SegmentSettings,
    Trajectory,
    load_world_cloud,
    read_manifest,
    read_trajectory,
    write_segmented_map,
)
from weldcell.sdk.errors import DataError


def _rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


def test_cut_by_distance_keeps_every_point_once(small_map):
    pts, col, traj = small_map
    segs = segments_of(pts, col, traj, max_distance=15.0, max_points=10**9, encoding="ply")
    assert len(segs) == math.ceil(traj.travelled[-1] / 15.0)  # 50 m of travel -> 4 local maps
    assert all(s.distance < 15.0 for s in segs)
    back = np.concatenate([s.world_points() for s in segs])
    assert len(back) == len(pts)
    np.testing.assert_allclose(_rows(back), _rows(pts), atol=1e-9)
    # each local map is expressed in its own frame: the first key frame's pose
    assert np.allclose(segs[1].T_world_segment, traj.T_world[segs[1].keyframes[0]])
    assert sorted(k for s in segs for k in s.keyframes) == list(range(len(traj.T_world)))


def test_cut_by_point_count_first(small_map):
    pts, col, traj = small_map
    segs = segments_of(pts, col, traj, max_distance=15.0, max_points=9_000)
    assert all(len(s.points) <= 9_000 for s in segs)
    assert len(segs) >= math.ceil(len(pts) / 9_000)
    assert sum(len(s.points) for s in segs) == len(pts)


def test_one_key_frame_with_more_points_than_the_limit_is_split():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-5, 5, (25_000, 3))
    segs = segments_of(pts, None, Trajectory(np.eye(4)[None]), max_points=10_000)
    assert [len(s.points) for s in segs] == [10_000, 10_000, 5_000]


def test_draco_error_is_within_one_millimetre_and_reported(small_map, tmp_path):
    pts, col, traj = small_map
    m = write_segmented_map(tmp_path, pts, col, traj, SegmentSettings(encoding="draco"))
    for e in m["segments"]:
        q = e["quantisation"]
        assert q["max_error_m"] <= 1e-3 and q["bound_m"] <= 1e-3
        assert 0 < q["rms_error_m"] <= q["max_error_m"]
    back, bcol = load_world_cloud(tmp_path)
    # measured independently of the writer: order is kept, segment by segment, in travel order
    order = np.concatenate([s_idx for s_idx in _segment_indices(pts, traj)])
    err = np.linalg.norm(back - pts[order], axis=1)
    assert err.max() <= 1e-3
    assert err.max() == pytest.approx(max(e["quantisation"]["max_error_m"] for e in m["segments"]), rel=1e-3)
    assert np.abs(bcol - col[order]).max() <= 0.5 / 255 + 1e-9
    assert sum(e["bytes"] for e in m["segments"]) < 0.6 * len(pts) * 15  # vs 15 B/point of binary PLY


def _segment_indices(pts, traj):
    from weldcell.plugins.map_transfer.segments import plan_segments

    return [idx for _, _, idx in plan_segments(pts, traj, SegmentSettings())]


def test_draco_bits_follow_the_extent():
    assert codec.draco_bits(1.0, 1e-3) < codec.draco_bits(30.0, 1e-3)
    for extent in (0.5, 7.0, 40.0):
        b = codec.draco_bits(extent, 1e-3)
        assert math.sqrt(3) / 2 * extent / (2**b - 1) <= 1e-3 < math.sqrt(3) / 2 * extent / (2 ** (b - 1) - 1)


def test_trajectory_files(tmp_path, small_map):
    _, _, traj = small_map
    rows = [[i, *T[:3, 3], 0, 0, 0, 1] for i, T in enumerate(traj.T_world[:5])]
    (tmp_path / "t.tum").write_text("\n".join(" ".join(map(str, r)) for r in rows))
    assert np.allclose(read_trajectory(tmp_path / "t.tum").T_world[:, :3, 3], traj.T_world[:5, :3, 3])
    (tmp_path / "bad.tum").write_text("1 2 3\n")
    with pytest.raises(DataError, match="columns"):
        read_trajectory(tmp_path / "bad.tum")


def test_missing_or_foreign_manifest_is_a_clear_error(tmp_path):
    with pytest.raises(DataError, match="no manifest.json") as e:
        read_manifest(tmp_path)
    assert "weldcell map segment" in e.value.fix
    (tmp_path / "manifest.json").write_text('{"schema": "weldcell/other@1"}')
    with pytest.raises(DataError, match="is not weldcell/map-segments@1"):
        read_manifest(tmp_path)


def test_empty_map_refused():
    pts, col, traj = corridor(10)
    with pytest.raises(DataError, match="no points"):
        segments_of(pts[:0], None, traj)


def test_ply_segments_read_back_by_the_sdk_reader(tmp_path, small_map):
    from weldcell.sdk.cloud import load_cloud_file

    pts, col, traj = small_map
    m = write_segmented_map(tmp_path, pts[:5000], col[:5000], traj, SegmentSettings(encoding="ply"))
    e = m["segments"][0]
    ours = codec.decode_file(tmp_path / e["file"], "ply")
    sdk = load_cloud_file(tmp_path / e["file"])
    assert np.array_equal(ours[0], sdk.points) and np.allclose(ours[1], sdk.colors)
    (tmp_path / "cut.ply").write_bytes((tmp_path / e["file"]).read_bytes()[:-10])
    with pytest.raises(DataError):
        codec.decode_file(tmp_path / "cut.ply", "ply")
