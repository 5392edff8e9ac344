"""Multi-view reconstruction (paper 000, eq. 1 + ICP against the growing model)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from weldcell.plugins.scan_plan.reconstruct import PosedScan, merge_views, reconstruct
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
    on_surface = transform_points(invert(T_BASE_PART), merged.points)
    assert np.percentile(np.abs(np.min(np.abs(on_surface[:, [2]]), axis=1)), 40) < 0.001


def test_reconstruct_corrects_kinematic_errors_against_the_growing_model():
    scans, truth = make_views()
    calls = []
    res = reconstruct(
        scans, T_FLANGE_CAMERA, voxel=0.003, anchor="first", progress=lambda i, n, m: calls.append((i, n))
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
    first = reconstruct(scans, T_FLANGE_CAMERA, voxel=0.003, anchor="first")
    mean = reconstruct(scans, T_FLANGE_CAMERA, voxel=0.003)
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


def test_unknown_anchor_is_refused():
    scans, _ = make_views(kin_error=False)
    with pytest.raises(DataError, match="anchor"):
        reconstruct(scans, T_FLANGE_CAMERA, voxel=0.003, anchor="middle")


def test_without_registration_views_are_only_merged():
    scans, _ = make_views()
    res = reconstruct(scans, T_FLANGE_CAMERA, voxel=None, register_to_model=False)
    assert all(np.array_equal(c, np.eye(4)) for c in res.corrections)
    assert len(res.cloud) == sum(len(s.cloud) for s in scans)


def test_implausible_correction_is_rejected_and_kinematics_kept():
    scans, _ = make_views()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = reconstruct(scans, T_FLANGE_CAMERA, voxel=0.003, max_correction=(1e-5, 1e-5))
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
        reconstruct(mutate(scans), T_FLANGE_CAMERA, voxel=0.003)
    assert err.value.fix


def test_bad_voxel_or_hand_eye_raise_data_error():
    scans, _ = make_views(kin_error=False)
    with pytest.raises(DataError):
        reconstruct(scans, T_FLANGE_CAMERA, voxel=-1.0)
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
