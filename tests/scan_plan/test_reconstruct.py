"""Multi-view reconstruction (paper 000, eq. 1 + ICP against the growing model)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from weldcell.plugins.scan_plan.reconstruct import PosedScan, ReconstructOptions, merge_views, reconstruct
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rotvec, invert, make_T, pose_error, transform_points

from .synthetic import corner_workpiece

T_BASE_PART = make_T(t=[0.45, -0.1, 0.02])
T_FLANGE_CAMERA = T_from_rotvec([0.0, 0.0, np.pi / 2], [0.0, 0.06, 0.04])
CENTRES = [(-0.04, -0.05), (0.04, -0.05), (-0.03, 0.02), (0.05, 0.02)]


def look_down(target: np.ndarray, height: float = 0.3) -> np.ndarray:
    """A flange pose whose camera looks straight down (camera z = -base z) at ``target``."""
    T_base_camera = make_T(np.diag([1.0, -1.0, -1.0]), np.asarray(target) + [0, 0, height])
    return T_base_camera @ invert(T_FLANGE_CAMERA)


def make_views(kin_error: bool = True, first_too: bool = False):
    """Four overlapping views of the corner workpiece; views 1..3 (all four with ``first_too``) carry a
    kinematic pose error."""
    rng = np.random.default_rng(7)
    scans, truth = [], []
    for i, (dx, dy) in enumerate(CENTRES):
        P, _ = corner_workpiece(spacing=0.0015, noise=0.0002, seed=10 + i)
        P = transform_points(T_BASE_PART, P)
        centre = transform_points(T_BASE_PART, np.array([[0.1 + dx, 0.15 + dy, 0.0]]))[0]
        P = P[np.linalg.norm(P[:, :2] - centre[:2], axis=1) < 0.09]
        T_bf = look_down(centre)
        T_bc = T_bf @ T_FLANGE_CAMERA
        cloud = PointCloud(transform_points(invert(T_bc), P), frame="camera")
        T_rec = T_bf
        if kin_error and (i > 0 or first_too):
            axis = rng.normal(size=3)
            err = T_from_rotvec(np.deg2rad(0.4) * axis / np.linalg.norm(axis), rng.normal(size=3) * 0.0018)
            T_rec = T_bf @ err
        scans.append(PosedScan(cloud, T_rec, timestamp=float(i)))
        truth.append(T_bc)
    return scans, truth


def test_merge_views_eq1_puts_points_in_base_frame():
    scans, truth = make_views(kin_error=False)
    merged = merge_views(scans, T_FLANGE_CAMERA)
    assert merged.frame == "base" and len(merged) == sum(len(s.cloud) for s in scans)
    expected = np.concatenate(
        [transform_points(T, s.cloud.points) for s, T in zip(scans, truth, strict=True)]
    )
    assert np.allclose(merged.points, expected, atol=1e-12)
    np.testing.assert_allclose(merged.viewpoints, [T[:3, 3] for T in truth], atol=1e-12)
    on_surface = transform_points(invert(T_BASE_PART), merged.points)
    assert np.percentile(np.abs(np.min(np.abs(on_surface[:, [2]]), axis=1)), 40) < 0.001


def test_reconstruct_corrects_kinematic_errors_against_the_growing_model():
    scans, truth = make_views()
    calls = []
    res = reconstruct(
        scans,
        T_FLANGE_CAMERA,
        ReconstructOptions(voxel=0.003, anchor="first"),
        progress=lambda i, n, m: calls.append((i, n)),
    )
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)]
    assert all(res.accepted) and res.icp[0] is None and np.array_equal(res.corrections[0], np.eye(4))
    for i in range(1, 4):
        before = pose_error(scans[i].T_base_flange @ T_FLANGE_CAMERA, truth[i])
        after = pose_error(res.T_base_camera[i], truth[i])
        assert before[0] > 0.001 or before[1] > np.deg2rad(0.2)
        assert after[0] < 6e-4 and after[1] < np.deg2rad(0.1), (i, before, after)
        assert after[0] < before[0] / 4 and after[1] < before[1] / 4
        assert res.fitness[i] >= res.fitness_before[i]
    assert res.cloud.frame == "base"
    # the merged model lies on the workpiece: the floor points are flat to the noise level
    local = transform_points(invert(T_BASE_PART), res.cloud.points)
    floor = local[(local[:, 0] < 0.09) & (local[:, 1] < 0.14)]
    assert np.sqrt(np.mean(floor[:, 2] ** 2)) < 3e-4


def test_mean_anchor_places_the_model_by_all_views_not_the_first():
    scans, truth = make_views(first_too=True)  # every view's kinematic pose is off, differently
    first = reconstruct(scans, T_FLANGE_CAMERA, ReconstructOptions(voxel=0.003, anchor="first"))
    mean = reconstruct(scans, T_FLANGE_CAMERA, ReconstructOptions(voxel=0.003))
    assert np.array_equal(first.anchor_shift, np.eye(4)) and not np.allclose(mean.anchor_shift, np.eye(4))

    def err(res):
        e = np.array([pose_error(T, T_true) for T, T_true in zip(res.T_base_camera, truth, strict=True)])
        return e.mean(axis=0)

    (t_first, r_first), (t_mean, r_mean) = err(first), err(mean)
    assert t_mean < 0.7 * t_first and r_mean < 0.7 * r_first, (t_first, t_mean, r_first, r_mean)
    # the views stay registered to each other: only the whole model moved
    for a, b in zip(first.T_base_camera, mean.T_base_camera, strict=True):
        assert np.allclose(mean.anchor_shift @ a, b, atol=1e-9)
    # the corrections now average to the identity
    C = np.asarray(mean.corrections)
    assert np.abs(C[:, :3, 3].mean(axis=0)).max() < 1e-9
    # the model says where its cameras were (the placed poses), for the seam stage's normals
    for res in (first, mean):
        np.testing.assert_allclose(res.cloud.viewpoints, [T[:3, 3] for T in res.T_base_camera], atol=1e-12)


def test_unknown_anchor_is_refused():
    scans, _ = make_views(kin_error=False)
    with pytest.raises(DataError, match="anchor"):
        reconstruct(scans, T_FLANGE_CAMERA, ReconstructOptions(voxel=0.003, anchor="middle"))


def test_without_registration_views_are_only_merged():
    scans, _ = make_views()
    res = reconstruct(scans, T_FLANGE_CAMERA, ReconstructOptions(voxel=None, register_to_model=False))
    assert all(np.array_equal(c, np.eye(4)) for c in res.corrections)
    assert len(res.cloud) == sum(len(s.cloud) for s in scans)


def test_implausible_correction_is_rejected_and_kinematics_kept():
    scans, _ = make_views()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = reconstruct(
            scans, T_FLANGE_CAMERA, ReconstructOptions(voxel=0.003, max_correction=(1e-5, 1e-5))
        )
    assert not any(res.accepted[1:]) and len(caught) == 3 and "rejected" in str(caught[0].message)
    assert all(np.array_equal(c, np.eye(4)) for c in res.corrections)


@pytest.mark.parametrize(
    "mutate",
    [
        lambda s: [],
        lambda s: [PosedScan(PointCloud(s[0].cloud.points, frame="base"), s[0].T_base_flange)],
        lambda s: [PosedScan(s[0].cloud, np.eye(3))],
        lambda s: [PosedScan(s[0].cloud, 2 * s[0].T_base_flange)],
        lambda s: [PosedScan(PointCloud(np.full((4, 3), np.nan), frame="camera"), s[0].T_base_flange)],
        lambda s: [PosedScan(PointCloud(np.empty((0, 3)), frame="camera"), s[0].T_base_flange)],
        lambda s: [s[0].cloud],
    ],
)
def test_bad_inputs_raise_data_error(mutate):
    scans, _ = make_views(kin_error=False)
    with pytest.raises(DataError) as err:
        reconstruct(mutate(scans), T_FLANGE_CAMERA, ReconstructOptions(voxel=0.003))
    assert err.value.fix


def test_bad_voxel_or_hand_eye_raise_data_error():
    scans, _ = make_views(kin_error=False)
    with pytest.raises(DataError):
        reconstruct(scans, T_FLANGE_CAMERA, ReconstructOptions(voxel=-1.0))
    with pytest.raises(DataError):
        merge_views(scans, np.zeros((4, 4)))


def test_stage_settings_take_a_pose_prior_in_units_and_refuse_non_positive_ones():
    from pydantic import ValidationError
    from weldcell.plugins.scan_plan.stages import ReconstructSettings

    s = ReconstructSettings(pose_prior=["2 mm", "0.3 deg"], anchor="first")
    assert s.pose_prior == pytest.approx((0.002, np.deg2rad(0.3))) and s.anchor == "first"
    for bad in (["-2 mm", "0.3 deg"], ["2 mm", "0 deg"]):
        with pytest.raises(ValidationError, match="greater than 0"):
            ReconstructSettings(pose_prior=bad)
    with pytest.raises(ValidationError):
        ReconstructSettings(anchor="middle")


# ------------------------------------------------------------------ anchor "hand-eye": one correction
def look_at_corner(azimuth_deg: float, elevation_deg: float, distance: float = 0.3) -> np.ndarray:
    """A camera pose (z forward) looking at the corner workpiece's joint from azimuth / elevation."""
    from weldcell.sdk.geometry import frame_from_axes

    target = transform_points(T_BASE_PART, np.array([[0.1, 0.15, 0.0]]))[0]
    az, el = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    eye = target + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return frame_from_axes(np.cross(target - eye, [0.0, 0.0, 1.0]), target - eye, eye)


def planted_views(error: np.ndarray, directions=((200, 50), (250, 60), (180, 70), (225, 35), (260, 45))):
    """Views of the corner workpiece from varied directions, posed through a hand-eye transform that is
    off by ``error`` (``T_flange_camera_given = T_flange_camera_true @ error``)."""
    scans, truth = [], []
    for i, (az, el) in enumerate(directions):
        P, _ = corner_workpiece(spacing=0.0015, noise=0.0002, seed=20 + i)
        T_bc = look_at_corner(az, el)
        cloud = PointCloud(transform_points(invert(T_bc), transform_points(T_BASE_PART, P)), frame="camera")
        scans.append(PosedScan(cloud, T_bc @ invert(T_FLANGE_CAMERA), timestamp=float(i)))
        truth.append(T_bc)
    return scans, truth, T_FLANGE_CAMERA @ error


PLANTED = T_from_rotvec(np.deg2rad(0.5) * np.array([0.6, -0.48, 0.64]), [0.0012, -0.0015, 0.0008])


def test_hand_eye_anchor_recovers_a_planted_hand_eye_error():
    scans, truth, T_fc = planted_views(PLANTED)
    res = reconstruct(scans, T_fc, ReconstructOptions(voxel=0.003, anchor="hand-eye"))
    fit = res.hand_eye
    assert fit.applied and fit.views == [0, 1, 2, 3, 4] and fit.passes == 2 and fit.spread_deg > 10
    # the corrected hand-eye is the true one within 0.1 mm / 0.02 deg (the error was 2.1 mm / 0.5 deg)
    t, r = pose_error(T_fc @ fit.D, T_FLANGE_CAMERA)
    assert t < 1e-4 and r < np.deg2rad(0.02), (t, np.rad2deg(r))
    assert fit.sigma_mm < 0.2 and fit.residual_mm < 0.5
    # every view is placed by the one correction, in the true base frame
    for T, T_true, scan in zip(res.T_base_camera, truth, scans, strict=True):
        assert np.allclose(T, scan.T_base_flange @ T_fc @ fit.D, atol=1e-12)
        t, r = pose_error(T, T_true)
        assert t < 3e-4 and r < np.deg2rad(0.03)
    # better than averaging the views' kinematic placements
    mean = reconstruct(scans, T_fc, ReconstructOptions(voxel=0.003))

    def worst(rec) -> float:
        return max(pose_error(T, T_true)[0] for T, T_true in zip(rec.T_base_camera, truth, strict=True))

    assert worst(res) < worst(mean) / 3 and res.cloud.meta["anchor"] == "hand-eye"


def test_hand_eye_anchor_falls_back_to_the_mean_when_view_rotations_are_alike():
    scans, _ = make_views(first_too=True)  # every camera looks straight down: one rotation for all
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = reconstruct(scans, T_FLANGE_CAMERA, ReconstructOptions(voxel=0.003, anchor="hand-eye"))
    assert not res.hand_eye.applied and "not observable" in res.hand_eye.note
    assert np.array_equal(res.hand_eye.D, np.eye(4)) and res.hand_eye.spread_deg < 1.0
    assert any("placed the model by the mean anchor" in str(w.message) for w in caught)
    mean = reconstruct(scans, T_FLANGE_CAMERA, ReconstructOptions(voxel=0.003))
    for a, b in zip(res.T_base_camera, mean.T_base_camera, strict=True):
        assert np.allclose(a, b, atol=1e-12)


def test_hand_eye_anchor_leaves_out_a_refused_view():
    scans, _, T_fc = planted_views(PLANTED)
    # view 3's robot pose is off by another 8 mm: its ICP correction is larger than max_correction
    bad = scans[3].T_base_flange @ make_T(t=[0.008, 0.0, 0.0])
    scans[3] = PosedScan(scans[3].cloud, bad, timestamp=3.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = reconstruct(
            scans, T_fc, ReconstructOptions(voxel=0.003, anchor="hand-eye", max_correction=(0.006, 0.1))
        )
    assert not res.accepted[3] and any("view 3" in str(w.message) for w in caught)
    fit = res.hand_eye
    assert fit.applied and 3 not in fit.views and len(fit.views) == 4
    t, r = pose_error(T_fc @ fit.D, T_FLANGE_CAMERA)
    assert t < 3e-4 and r < np.deg2rad(0.05), (t, np.rad2deg(r))


def test_default_anchor_is_still_the_mean_and_fits_no_hand_eye():
    from weldcell.plugins.scan_plan.stages import ReconstructSettings

    scans, _, T_fc = planted_views(PLANTED)
    res = reconstruct(scans, T_fc, ReconstructOptions(voxel=0.003))
    assert res.hand_eye is None and res.cloud.meta["anchor"] == "mean"
    s = ReconstructSettings()
    assert s.anchor == "mean" and s.hand_eye_passes == 2
    assert ReconstructSettings(anchor="hand-eye", hand_eye_passes=0).anchor == "hand-eye"
    with pytest.raises(DataError, match="hand_eye_passes"):
        reconstruct(scans, T_fc, ReconstructOptions(voxel=0.003, anchor="hand-eye", hand_eye_passes=-1))


def test_fit_hand_eye_solves_exact_poses_and_measures_rotation_spread():
    from weldcell.plugins.scan_plan.hand_eye_fit import fit_hand_eye, rotation_spread

    rng = np.random.default_rng(3)
    G = T_from_rotvec([0.002, -0.004, 0.003], [0.002, 0.001, -0.003])
    B = [T_from_rotvec(rng.normal(size=3) * 0.5, rng.normal(size=3) * 0.3) for _ in range(6)]
    A = [G @ b @ PLANTED for b in B]
    fit = fit_hand_eye(A, B, [np.eye(6)] * 6, [1.0] * 6)
    assert fit.applied and np.allclose(fit.D, PLANTED, atol=1e-9) and np.allclose(fit.G, G, atol=1e-9)
    assert fit.residual_mm < 1e-6
    z = [T_from_rotvec([0.0, 0.0, a])[:3, :3] for a in (0.0, 0.5, 1.0)]
    assert rotation_spread(z) < 1e-6  # all about one axis: a correction about it is not observable
    two = [np.eye(3), T_from_rotvec([0.3, 0.0, 0.0])[:3, :3]]
    assert rotation_spread(two) < 1e-6  # two rotations always differ about one axis only
    three = [*two, T_from_rotvec([0.0, 0.3, 0.0])[:3, :3]]
    assert 0.15 < rotation_spread(three) < 0.3
    assert not fit_hand_eye(A[:3], B[:3], [np.eye(6)] * 3, [1.0, 0.0, 1.0]).applied  # 2 views left


@pytest.mark.filterwarnings("ignore:view .* rejected")
def test_reconstruct_command_reports_the_hand_eye_correction(tmp_path):
    import json

    from click.testing import CliRunner
    from weldcell.sdk.cli import main
    from weldcell.sdk.cloud import write_cloud

    scans, _, T_fc = planted_views(PLANTED)
    recs = []
    for i, s in enumerate(scans):
        write_cloud(tmp_path / f"{i:03d}.ply", s.cloud)
        recs.append({"cloud": f"{i:03d}.ply", "T_base_flange": s.T_base_flange.tolist(), "stamp": float(i)})
    doc = {"schema": "weldcell/posed-scans@1", "units": "m", "scans": recs}
    (tmp_path / "scans.json").write_text(json.dumps(doc))
    he = {"schema": "weldcell/hand-eye@1", "transform": "T_flange_camera", "T": T_fc.tolist(), "units": "m"}
    (tmp_path / "he.json").write_text(json.dumps(he))
    out = tmp_path / "model.ply"
    args = [str(tmp_path), "-o", str(out), "--hand-eye", str(tmp_path / "he.json"), "--anchor", "hand-eye"]
    res = CliRunner().invoke(main, ["reconstruct", *args, "--set", "reconstruct.voxel='3 mm'"])
    assert res.exit_code == 0, res.output
    assert "hand-eye        correction" in res.output and "from 5 views" in res.output
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["hand_eye_correction"]["applied"] and report["stage"]["settings"]["anchor"] == "hand-eye"
    t, r = pose_error(np.array(report["T_flange_camera_corrected"]), T_FLANGE_CAMERA)
    assert t < 1e-4 and r < np.deg2rad(0.02)


def test_icp_information_shows_which_directions_the_geometry_constrains():
    from weldcell.plugins.scan_plan.registration import IcpOptions, linear_icp, point_to_plane_information

    rng = np.random.default_rng(4)
    plane = np.c_[rng.uniform(-0.05, 0.05, (3000, 2)), rng.normal(0.0, 1e-4, 3000)]
    res = linear_icp(plane + [0, 0, 0.001], plane, IcpOptions(max_correspondence_distance=0.01))
    # twist (omega, p): a plane z = 0 constrains p_z, omega_x and omega_y, not p_x, p_y or omega_z
    d = np.diag(res.information)
    assert d[5] > 0.9 and max(d[3], d[4]) < 1e-3 * d[5] and d[2] < 1e-3 * min(d[0], d[1])
    exact = point_to_plane_information(plane, np.tile([0.0, 0.0, 1.0], (len(plane), 1)))
    assert np.allclose(exact[5, 5], 1.0) and np.allclose(exact[3:5, 3:5], 0.0)
    assert np.allclose(res.information, exact, rtol=0.05, atol=1e-3)
