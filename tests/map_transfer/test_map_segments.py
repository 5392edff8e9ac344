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


def test_quantised_is_the_default_within_one_millimetre_and_smaller_than_draco(small_map, tmp_path):
    pts, col, traj = small_map
    assert SegmentSettings().encoding == "quantised"
    m = write_segmented_map(tmp_path / "q", pts, col, traj, SegmentSettings())
    assert all(e["file"].endswith(".qpc") and e["encoding"] == "quantised" for e in m["segments"])
    for e in m["segments"]:
        q = e["quantisation"]
        assert 0 < q["rms_error_m"] <= q["max_error_m"] <= q["bound_m"] <= 1e-3
    back, bcol = load_world_cloud(tmp_path / "q")
    # measured independently of the writer (the points come back sorted within each local map): every
    # original point has a decoded one within 1 mm in its local map, and the counts are the same
    from scipy.spatial import cKDTree

    segs = [read_segment_points(tmp_path / "q", e) for e in m["segments"]]
    assert sum(len(s[0]) for s in segs) == len(pts) == len(back)
    for (local, T), idx in zip(segs, _segment_indices(pts, traj), strict=True):
        orig = (pts[idx] - T[:3, 3]) @ T[:3, :3]  # the original points in the local map's frame
        assert len(local) == len(idx) and cKDTree(local).query(orig)[0].max() <= 1e-3
    assert np.allclose(np.sort(bcol, axis=0), np.sort(col, axis=0), atol=0.5 / 255 + 1e-9)
    d = write_segmented_map(tmp_path / "d", pts, col, traj, SegmentSettings(encoding="draco"))
    assert sum(e["bytes"] for e in m["segments"]) < sum(e["bytes"] for e in d["segments"])


def read_segment_points(root, e):
    local, _ = codec.decode_file(root / e["file"], e["encoding"])
    return local, np.array(e["T_world_segment"])


def test_quantised_decoded_points_encode_again_to_the_same_bytes(small_map):
    pts, col, _ = small_map
    data, q = codec.encode(pts[:20_000], col[:20_000], "quantised", 1e-3)
    from weldcell.plugins.map_transfer.quantised import decode_quantised

    p2, c2 = decode_quantised(data)
    again, q2 = codec.encode(p2, c2, "quantised", 1e-3)
    assert again == data and q2.max_error == 0.0  # a new map version moves unchanged points by 0
    far = pts[:1000] + [5000.0, -3000.0, 20.0]  # far from the origin: only the deltas' width matters
    data, q = codec.encode(far, None, "quantised", 5e-4)
    back, none = decode_quantised(data)
    assert none is None and q.max_error <= 5e-4
    from scipy.spatial import cKDTree

    assert len(back) == len(far) and cKDTree(back).query(far)[0].max() <= 5e-4
    for n in (0, 1):
        back, _ = decode_quantised(codec.encode(pts[:n], col[:n], "quantised", 1e-3)[0])
        assert back.shape == (n, 3)


def test_damaged_quantised_segment_is_a_clear_error(small_map, tmp_path):
    pts, col, _ = small_map
    data, _ = codec.encode(pts[:5000], col[:5000], "quantised", 1e-3)
    bad = bytearray(data)
    bad[len(bad) // 2] ^= 0xFF
    for name, blob in (("flip", bytes(bad)), ("cut", data[:-100]), ("head", b"PLY\n" + data[4:])):
        (tmp_path / name).write_bytes(blob)
        with pytest.raises(DataError) as e:
            codec.decode_file(tmp_path / name, "quantised")
        assert "fetch" in e.value.fix
