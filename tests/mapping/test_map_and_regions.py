"""Map format round trip, voxel map, detector.sim / detector.onnx, region fusion and decisions."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mapping_rig import T_BASE_CAM
from weldcell.hal.readings import Intrinsics
from weldcell.hal.sim.rgbd import RgbdCamera
from weldcell.plugins.mapping.estimator import KeyFrame
from weldcell.plugins.mapping.frontend import FrameFeatures
from weldcell.plugins.mapping.mapstore import KEYFRAMES_SCHEMA, KeyFrameStore, VoxelMap, back_project
from weldcell.plugins.mapping.regions import (
    RegionFuser,
    SimDetector,
    SimDetectorSettings,
    apply_decisions,
    corner_distance_error,
    detection_points,
    plate_corners,
)
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rotvec
from weldcell.sdk.stages import Detection2D

K = Intrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)


def test_keyframe_store_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    feats = FrameFeatures(
        rng.random((40, 2)) * 60, rng.integers(0, 255, (40, 32), dtype=np.uint8), rng.random((40, 3))
    )
    T = T_from_rotvec([0.1, 0.2, 0.3], [1, 2, 3])
    kf = KeyFrame(
        0,
        1.5,
        1.7e9 + 1.5,
        rng.integers(0, 255, (48, 64, 3), dtype=np.uint8),
        rng.random((48, 64)).astype(np.float32),
        K,
        feats,
        T,
        np.ones(3),
        np.arange(6.0),
    )
    store = KeyFrameStore(tmp_path / "map", T_imu_cam=np.eye(4))
    store.add(kf, T @ T_BASE_CAM)
    back = KeyFrameStore.load(tmp_path / "map")
    assert json.loads((tmp_path / "map" / "keyframes.json").read_text())["schema"] == KEYFRAMES_SCHEMA
    assert back.intrinsics == K and len(back.records) == 1
    r = back.records[0]
    np.testing.assert_allclose(r.T_world_cam, T @ T_BASE_CAM)
    np.testing.assert_allclose(r.bias, np.arange(6.0))
    d = back.read(r)
    np.testing.assert_array_equal(d["descriptors"], feats.descriptors)
    np.testing.assert_array_equal(d["rgb"], kf.rgb)


def test_store_refuses_a_folder_without_keyframes(tmp_path):
    with pytest.raises(DataError, match="keyframes.json"):
        KeyFrameStore.load(tmp_path)


def test_voxel_map_memory_is_bounded_by_the_voxel_size():
    vm = VoxelMap(0.1)
    rng = np.random.default_rng(1)
    for _ in range(5):  # the same 1 m cube seen five times: cells do not grow with the frames
        vm.integrate(rng.random((20000, 3)), rng.random((20000, 3)))
    assert len(vm) == 1000
    P, C = vm.points()
    assert P.min() >= 0 and P.max() <= 1 and C.shape == P.shape


def test_back_projection_is_eq3():
    depth = np.zeros((48, 64), np.float32)
    depth[23, 31] = 2.0
    depth[10, 50] = 4.0
    P, _ = back_project(depth, K, np.eye(4))
    assert len(P) == 2
    np.testing.assert_allclose(P[0], [(50 - 31.5) * 4 / 50, (10 - 23.5) * 4 / 50, 4.0])


@pytest.fixture(scope="module")
def plate_view(site):
    """A rendered frame looking at weld plate 0 from 2.5 m."""
    plate = site.layout.plates[0]
    eye = plate.center + np.array([-2.2, -1.2, 0.9])
    z = plate.center - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = eye
    cam = RgbdCamera("zed2i", site.world.meshes(), decimation=4)
    d, c = cam.render_rgbd(T, rng=0, noise=False)
    return T, d, c


def test_sim_detector_finds_the_plate_and_regions_fuse(site, plate_view):
    T, d, c = plate_view
    det = SimDetector(SimDetectorSettings(miss_rate=0.0, false_alarms=0.0, jitter=0.0))
    meta = {"T_world_camera": T, "intrinsics": d.intrinsics, "depth": d.depth, "regions": site.weld_truth()}
    found = det(c, meta)
    assert len(found) >= 1 and all(isinstance(f, Detection2D) for f in found)
    fuser = RegionFuser()
    for k in range(3):  # the same region seen from three key frames is one region
        for f in found:
            fuser.add(f, detection_points(f, d.depth, d.intrinsics, T), k)
    plate = site.layout.plates[0]
    near = [r for r in fuser.regions if np.linalg.norm(r.center[:2] - plate.center[:2]) < 0.5]
    assert len(near) == 1 and near[0].observations == [0, 1, 2]
    corners = plate_corners(near[0].points)
    assert corners is not None
    assert corner_distance_error(corners, plate.corners) < 0.05


def test_sim_detector_misses_and_false_alarms_are_random(site, plate_view):
    T, d, c = plate_view
    meta = {"T_world_camera": T, "intrinsics": d.intrinsics, "depth": d.depth, "regions": site.weld_truth()}
    always_miss = SimDetector(SimDetectorSettings(miss_rate=1.0, false_alarms=0.0))
    assert always_miss(c, meta) == []  # a detector that finds nothing: an empty list, not an error
    noisy = SimDetector(SimDetectorSettings(miss_rate=1.0, false_alarms=3.0))
    assert sum(len(noisy(c, meta)) for _ in range(10)) > 10
    with pytest.raises(DataError, match="ground truth"):
        noisy(c, None)


def test_operator_decisions_confirm_reject_and_add(tmp_path):
    fuser = RegionFuser()
    pts = np.random.default_rng(0).random((100, 3))
    fuser.add(Detection2D((0, 0, 1, 1), "weld-region", 0, 0.9), pts, 0)
    fuser.add(Detection2D((0, 0, 1, 1), "weld-region", 0, 0.9), pts + 5, 1)
    f = tmp_path / "decisions.json"
    f.write_text(
        json.dumps(
            {
                "confirm": ["R01"],
                "reject": ["R02"],
                "add": [{"min": [0, 0, 0], "max": [1, 1, 1]}],
            }
        )
    )
    log = apply_decisions(fuser.regions, f)
    assert [r.decision for r in fuser.regions] == ["confirmed", "rejected", "added"]
    assert [e["decision"] for e in log] == ["confirmed", "rejected", "added"]
    f.write_text("{not json")
    with pytest.raises(DataError, match="not JSON"):
        apply_decisions(fuser.regions, f)
