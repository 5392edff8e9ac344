"""The plate measurement behind the AE figure (plate.py) and the weld regions' dense TSDF surface."""

from __future__ import annotations

import numpy as np
from weldcell.hal.readings import Intrinsics
from weldcell.hal.sim.rgbd import RgbdCamera
from weldcell.plugins.mapping.mapstore import TSDF_MAX_RESOLUTION, tsdf_region
from weldcell.plugins.mapping.plate import _interval_ml, frame_observations, merge, plate_corners_ml
from weldcell.plugins.mapping.regions import corner_distance_error

ZED_NOISE = 0.08 / (448.0 * 0.12)  # the ZED 2i's stereo depth noise, sigma_z / z^2 [1/m]


def test_interval_ml_recovers_an_edge_that_noisy_points_smear():
    """Points uniform on [0, 0.6]: a third precise (2 mm), the rest smeared by 6 cm (the grazing top
    face). The ML interval finds both ends within a few mm; the percentile box is off by centimetres."""
    rng = np.random.default_rng(0)
    x0 = rng.uniform(0, 0.6, 1500)
    s = np.where(np.arange(1500) % 3 == 0, 0.002, 0.06)
    x = x0 + rng.normal(0, s)
    a, b, _ = _interval_ml(x, s)
    assert abs(a) < 0.006 and abs(b - 0.6) < 0.006
    lo, hi = np.percentile(x, [1, 99])
    assert max(abs(lo), abs(hi - 0.6)) > 0.015


def test_plates_measured_from_the_route_with_the_stereo_noise(site):
    """The weld plates seen by the profile's ZED 2i (1.0 m high, 0.2 m above the plates) from the route,
    1.5-2.8 m away, 4-5 views each from one side, with the camera's depth noise at 320x180: the box fit
    (plate_fit.py) keeps the corner distances (AE) within 12 mm on average and 20 mm per plate (here 14.8,
    1.9 and 7.5 mm; the points' interval measurement it starts from: 20.9, 25.7 and 27.0 mm)."""
    from mapping_rig import T_BASE_CAM

    cam = RgbdCamera("zed2i", site.world.meshes(), decimation=4)
    K = cam.intrinsics
    errors = []
    for plate in site.layout.plates[:3]:  # the 30 m route passes these three
        c = plate.center
        views = []
        for t in np.arange(0.0, site.route.duration, 0.5):
            T = site.route.pose(t) @ T_BASE_CAM
            pc = np.linalg.inv(T) @ np.r_[c, 1.0]
            u = K.fx * pc[0] / pc[2] + K.cx
            if 1.5 < pc[2] < 2.8 and 0.1 * K.width < u < 0.9 * K.width:
                views.append(T)
        assert len(views) >= 4
        obs = []
        for k, T in enumerate(views[:: max(1, len(views) // 10)]):
            d, _ = cam.render_rgbd(T, rng=k)
            obs.append(
                frame_observations(d.depth, K, T, c - [0.5, 0.5, 0.25], c + [0.5, 0.5, 0.25], ZED_NOISE)
            )
        corners = plate_corners_ml(merge(obs))
        assert corners is not None
        errors.append(corner_distance_error(corners, plate.corners))
    assert max(errors) < 0.02 and np.mean(errors) < 0.012


def test_plate_measure_needs_points():
    empty = merge([])  # no key frame saw it
    assert plate_corners_ml(empty) is None


def test_tsdf_region_returns_the_surface_and_bounds_its_memory():
    """A wall 2 m in front of the camera: the region's TSDF surface lies on it (within a voxel); a box
    larger than TSDF_MAX_RESOLUTION voxels gets coarser voxels instead of more memory."""
    K = Intrinsics(160, 120, 100.0, 100.0, 79.5, 59.5)
    depth = np.full((120, 160), 2.0, np.float32)
    rgb = np.full((120, 160, 3), 128, np.uint8)
    kf = {"rgb": rgb, "depth": depth, "intrinsics": K, "T_world_cam": np.eye(4)}
    mesh = tsdf_region([kf], np.array([-0.4, -0.3, 1.6]), np.array([0.4, 0.3, 2.4]), 0.01)
    V = np.asarray(mesh.vertices)
    assert len(V) > 1000
    assert np.abs(V[:, 2] - 2.0).max() < 0.01
    big = tsdf_region([kf], np.array([-3.0, -3.0, 0.5]), np.array([3.0, 3.0, 6.5]), 0.01)
    Vb = np.asarray(big.vertices)
    assert len(Vb) > 100 and np.abs(Vb[:, 2] - 2.0).max() < 6.0 / TSDF_MAX_RESOLUTION
    blind = {**kf, "depth": np.zeros_like(depth)}  # no key frame sees the box: no surface, not an empty one
    assert tsdf_region([blind], np.array([-0.4, -0.3, 1.6]), np.array([0.4, 0.3, 2.4]), 0.01) is None
