"""Ray-cast depth cameras: exact depth without noise, the preset's noise with it, range limits,
grazing-angle degradation, back-projection onto the mesh, the V-groove seen by a D415."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
from weldcell.hal.sim.camera_model import PRESETS, CameraPreset, DepthImage, RaycastCamera, get_preset
from weldcell.hal.sim.workpieces import v_groove_butt
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy, invert, make_T, transform_points

LOOK_DOWN = np.diag([1.0, -1.0, -1.0])  # optical z = world -z, x = world x, y = world -y


def plane(size: float = 6.0) -> o3d.geometry.TriangleMesh:
    """A thin square slab whose top face is the plane z = 0."""
    m = o3d.geometry.TriangleMesh.create_box(size, size, 0.01)
    m.translate([-size / 2, -size / 2, -0.01])
    return m


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera optical frame at ``eye`` looking at ``target`` (z forward, y down)."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, np.asarray(up, float))
    x /= np.linalg.norm(x)
    return make_T(np.column_stack([x, np.cross(z, x), z]), eye)


def above(height: float, R: np.ndarray = LOOK_DOWN) -> np.ndarray:
    return make_T(R, [0.0, 0.0, height])


def test_presets_are_complete_and_intrinsics_follow_the_fov() -> None:
    assert set(PRESETS) == {"realsense-d415", "realsense-d435", "phoxi-s", "phoxi-m", "azure-kinect", "zed2i"}
    d415 = PRESETS["realsense-d415"]
    assert (d415.width, d415.height) == (1280, 720)
    assert 2 * math.degrees(math.atan(d415.width / 2 / d415.fx)) == pytest.approx(65.0)
    # Intel's RMS formula: z² · 0.08 / (f_px · 55 mm); about 0.29 % at 2 m (spec: < 2 %)
    assert d415.sigma(2.0) == pytest.approx(4.0 * 0.08 / (d415.fx * 0.055))
    assert d415.sigma(2.0) / 2.0 < 0.02
    assert PRESETS["realsense-d435"].sigma(1.0) > d415.sigma(1.0)  # wider FOV, shorter baseline
    assert PRESETS["phoxi-s"].sigma(0.442) == pytest.approx(0.05e-3)
    assert PRESETS["azure-kinect"].sigma(1.0) == pytest.approx(0.0017 + 0.001)
    for p in PRESETS.values():
        assert p.source
        assert p.min_range < p.max_range


@pytest.mark.parametrize("name", ["realsense-d415", "azure-kinect", "phoxi-m"])
def test_plane_depth_without_noise_is_exact(name) -> None:
    p = PRESETS[name]
    z0 = 0.5 * (p.min_range + min(p.max_range, 2.0))
    cam = RaycastCamera(name, [plane()], decimation=4)
    img = cam.render(above(z0), noise=False)
    assert img.valid.all()
    assert abs(float(img.depth.mean()) - z0) < 0.2e-3
    assert np.abs(img.depth - z0).max() < 0.2e-3


@pytest.mark.parametrize(
    ("name", "z0"),
    [
        ("realsense-d415", 1.0),
        ("realsense-d435", 1.5),
        ("phoxi-s", 0.442),
        ("azure-kinect", 1.2),
        ("zed2i", 2.0),
    ],
)
def test_noise_matches_the_preset(name, z0) -> None:
    cam = RaycastCamera(name, [plane()], decimation=4)
    img = cam.render(above(z0), rng=7)
    gt = cam.render(above(z0), noise=False)
    ok = img.valid
    assert ok.mean() > 0.95
    p = cam.preset
    # near the optical axis the incidence is ~0: the std is the preset's sigma(z)
    h, w = img.depth.shape
    centre = np.zeros_like(ok)
    centre[h // 2 - h // 6 : h // 2 + h // 6, w // 2 - w // 6 : w // 2 + w // 6] = True
    res = (img.depth - gt.depth)[ok & centre]
    assert abs(res.std() / p.sigma(z0) - 1.0) < 0.2
    assert abs(res.mean()) < 0.2 * p.sigma(z0)
    # everywhere, residuals normalised by sigma(z, cos θ) have unit std
    _, cos, _ = cam.cast(above(z0))
    norm = ((img.depth - gt.depth) / p.sigma(gt.depth, cos))[ok]
    assert abs(norm.std() - 1.0) < 0.2


def test_noise_is_along_the_ray_and_reproducible() -> None:
    cam = RaycastCamera("realsense-d435", [plane()], decimation=4)
    T = above(1.0)
    a, b, c = cam.render(T, rng=1), cam.render(T, rng=1), cam.render(T, rng=2)
    assert np.array_equal(a.depth, b.depth)
    assert not np.array_equal(a.depth, c.depth)
    # back-projected noisy points stay on their pixel's ray: x/z and y/z are those of the pixel
    v, u = np.nonzero(a.valid)
    pts = a.to_points()
    k = a.intrinsics
    assert np.allclose(pts[:, 0] / pts[:, 2], (u - k.cx) / k.fx, atol=1e-9)
    assert np.allclose(pts[:, 1] / pts[:, 2], (v - k.cy) / k.fy, atol=1e-9)


def test_back_projection_lands_on_the_mesh() -> None:
    wp = v_groove_butt().placed(make_T(t=[0.1, -0.05, 0.02]))
    T = look_at([0.25, -0.35, 0.45], [0.1, -0.05, 0.02])
    cam = RaycastCamera("realsense-d415", [wp], decimation=2)
    img = cam.render(T, noise=False)
    cloud = img.to_world_cloud()
    assert len(cloud) > 10_000
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(wp.mesh_in_world()))
    d = scene.compute_distance(o3d.core.Tensor(cloud.points.astype(np.float32))).numpy()
    assert np.percentile(d, 99) < 2e-5 and d.max() < 1e-4
    # one pixel by hand: its ray from the camera centre meets the mesh at the rendered depth
    v, u = np.argwhere(img.valid)[len(cloud) // 2]
    k = img.intrinsics
    ray_c = np.array([(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0])
    ray_w = np.concatenate([T[:3, 3], T[:3, :3] @ ray_c]).astype(np.float32)[None]
    t_hit = scene.cast_rays(o3d.core.Tensor(ray_w))["t_hit"].numpy()[0]
    assert img.depth[v, u] == pytest.approx(t_hit, abs=1e-6)


def test_out_of_range_surfaces_are_dropped() -> None:
    p = PRESETS["azure-kinect"]
    cam = RaycastCamera(p, [plane()], decimation=4)
    for z in (p.min_range - 0.05, p.max_range + 0.1):
        for noise in (False, True):
            assert not cam.render(above(z), rng=0, noise=noise).valid.any()
    assert cam.render(above(p.min_range + 0.05), noise=False).valid.all()
    # a step: the near half of the image is in range, the far half is not
    near = plane(0.6)
    near.translate([0.3, 0.0, 3.5])
    cam2 = RaycastCamera(p, [plane(), near], decimation=4)
    img = cam2.render(above(4.0), noise=False)
    assert img.valid.any() and not img.valid.all()
    assert np.all(img.depth[img.valid] == pytest.approx(0.5, abs=1e-4))


def test_grazing_view_has_more_dropouts_and_noise_than_frontal() -> None:
    cam = RaycastCamera("realsense-d415", [plane(20.0)], decimation=4)
    z = 1.2
    frontal = above(z)
    # tilt 80° about the camera x axis, looking at the same point on the plane
    tilt = math.radians(80)
    R = LOOK_DOWN @ np.array(
        [[1, 0, 0], [0, math.cos(tilt), -math.sin(tilt)], [0, math.sin(tilt), math.cos(tilt)]]
    )
    target = np.zeros(3)
    grazing = make_T(R, target - R[:, 2] * z)

    def stats(T):
        gt = cam.render(T, noise=False)
        img = cam.render(T, rng=5)
        sel = gt.valid & (np.abs(gt.depth - z) < 0.1)  # compare the same depth band
        drop = 1.0 - img.valid[sel].mean()
        both = sel & img.valid
        return drop, float(np.std((img.depth - gt.depth)[both]))

    d_f, s_f = stats(frontal)
    d_g, s_g = stats(grazing)
    assert d_g > d_f + 0.2
    assert s_g > 2.0 * s_f


def test_d415_sees_the_v_groove_at_0_4_m() -> None:
    wp = v_groove_butt()  # 10 mm plates, 30° bevels, 1 mm gap and root face
    T = above(0.4 + wp.params["thickness"])
    # the D415's minimum range at 1280x720 (f·B/126 = 0.44 m) is beyond 0.4 m: it sees nothing ...
    assert not RaycastCamera("realsense-d415", [wp]).render(T, rng=0).valid.any()
    # ... unless the disparity shift brings the minimum range in (min_range override)
    img = RaycastCamera("realsense-d415", [wp], min_range=0.3).render(T, rng=0)
    pts = img.to_world_cloud().points
    t, f = wp.params["thickness"], wp.params["root_face"]
    half_top = wp.params["root_gap"] / 2 + (t - f) * math.tan(wp.params["bevel_angle"])
    inside = np.abs(pts[:, 1]) < half_top - 1e-3
    groove = pts[inside]
    assert len(groove) > 5000
    assert np.mean(groove[:, 2] < t - 0.5e-3) > 0.95  # the points over the groove are below the plate top
    # the flanks: depth below the top grows with distance from the edge, as the 30° bevel says
    ys = np.abs(groove[:, 1])
    expect = t - (half_top - ys) / math.tan(wp.params["bevel_angle"])
    flank = ys > wp.params["root_gap"] / 2 + 1e-3
    assert np.median(np.abs(groove[flank, 2] - expect[flank])) < 0.5e-3
    assert groove[:, 2].min() < f + 1.5e-3  # the bottom of the groove is seen
    outside = np.abs(pts[:, 1]) > half_top + 2e-3
    assert np.median(np.abs(pts[outside, 2] - t)) < 0.5e-3


def test_stereo_shadows_drop_points_the_second_view_cannot_see() -> None:
    block = o3d.geometry.TriangleMesh.create_box(0.1, 0.3, 0.15)
    block.translate([-0.05, -0.15, 0.0])
    scene = [plane(), block]
    T = above(0.9)
    with_shadow = RaycastCamera("realsense-d415", scene, decimation=4, random_dropout=0.0, edge_dropout=0.0)
    without = RaycastCamera(
        "realsense-d415", scene, decimation=4, random_dropout=0.0, edge_dropout=0.0, shadows=False
    )
    a, b = with_shadow.render(T, rng=0), without.render(T, rng=0)
    lost = b.valid & ~a.valid
    assert lost.sum() > 100
    # the shadow is a band of floor beside the block on the side away from the partner (-x), between
    # where the block hides the floor from the camera (x = -0.05·0.9/0.75) and from the partner at +B
    gt = without.render(T, noise=False)
    pts_w = transform_points(T, _pixel_points(gt, lost))
    B, zc, h = with_shadow.preset.baseline, 0.9, 0.15
    x_cam = -0.05 * zc / (zc - h)
    x_partner = (-0.05 * zc - B * h) / (zc - h)
    assert np.all(pts_w[:, 2] < 1e-6)
    assert np.all((pts_w[:, 0] > x_partner - 1e-6) & (pts_w[:, 0] < x_cam + 1e-6))
    assert pts_w[:, 0].min() < x_partner + 5e-3
    # a flat floor alone casts no shadow
    floor = RaycastCamera("realsense-d415", [plane()], decimation=4, random_dropout=0.0, edge_dropout=0.0)
    assert floor.render(T, rng=0).valid.all()


def _pixel_points(img: DepthImage, mask: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    z = img.depth[v, u].astype(float)
    k = img.intrinsics
    return np.column_stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z])


def test_clouds_frames_and_conversions() -> None:
    cam = RaycastCamera("zed2i", [plane()], decimation=8)
    T = T_from_rpy([math.pi, 0.1, 0.0], [0.0, 0.0, 1.5])
    img = cam.render(T, rng=0, timestamp=12.5)
    cloud = img.to_cloud()
    assert cloud.frame == "camera" and len(cloud) == int(img.valid.sum())
    assert np.allclose(cloud.points, img.to_points())
    assert np.allclose(img.to_world_cloud().points, transform_points(T, cloud.points))
    frame = img.to_frame()
    assert frame.stamp == 12.5
    assert np.allclose(frame.to_cloud().points, cloud.points, atol=1e-9)
    assert np.allclose(transform_points(invert(T), img.to_world_cloud().points), cloud.points)


def test_decimation_scales_the_intrinsics() -> None:
    full = get_preset("realsense-d415")
    cam = RaycastCamera(full, [plane()], decimation=4)
    p = cam.preset
    assert (p.width, p.height) == (320, 180)
    assert p.fx == pytest.approx(full.fx / 4)
    assert p.cx == pytest.approx((full.width / 4 - 1) / 2)
    img = cam.render(above(1.0), noise=False)
    assert img.depth.shape == (180, 320)
    # a corner pixel back-projects on the same plane and at the same angle as at full resolution
    pt = img.to_points()[0]
    assert pt[2] == pytest.approx(1.0, abs=1e-5)
    assert math.atan2(-pt[0], 1.0) == pytest.approx(math.atan((full.cx + 0.5 - 2.0) / full.fx), abs=1e-3)


def test_scene_meshes_can_be_added_replaced_and_removed() -> None:
    cam = RaycastCamera("realsense-d435", decimation=8)
    T = above(1.0)
    assert not cam.render(T, rng=0).valid.any()
    h = cam.add(plane())
    assert cam.render(T, noise=False).depth.mean() == pytest.approx(1.0, abs=1e-4)
    raised = plane()
    raised.translate([0, 0, 0.2])
    cam.replace(h, raised)
    assert cam.render(T, noise=False).depth.mean() == pytest.approx(0.8, abs=1e-4)
    wp = v_groove_butt().placed(make_T(t=[0, 0, 0.3]))
    h2 = cam.add(wp)
    assert cam.render(T, noise=False).depth.min() < 0.7
    cam.remove(h2)
    cam.remove(h)
    assert not cam.render(T, noise=False).valid.any()
    with pytest.raises(DataError):
        cam.remove(h)


def test_bad_inputs_raise_data_error() -> None:
    with pytest.raises(DataError) as e:
        RaycastCamera("kinect-v9")
    assert "realsense-d415" in e.value.fix
    with pytest.raises(DataError) as e:
        RaycastCamera("realsense-d415", max_rnage=3.0)
    assert "max_range" in e.value.fix
    with pytest.raises(DataError):
        RaycastCamera("realsense-d415", decimation=0)
    with pytest.raises(DataError):
        RaycastCamera("realsense-d415", min_range=5.0, max_range=1.0)
    with pytest.raises(DataError):
        RaycastCamera("realsense-d415", meshes=["not a mesh"])
    cam = RaycastCamera("realsense-d415", [plane()], decimation=8)
    with pytest.raises(DataError):
        cam.render(np.ones((4, 4)))
    with pytest.raises(DataError):
        CameraPreset("x", 10, 10, 5.0, 5.0, 4.5, 4.5, 0.1, 1.0, edge_dropout=2.0)
