"""Linear point-to-plane ICP (paper 000, eqs. 2-8, 20) against known transforms and real LiDAR data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan.cloud_numerics import pca_normals, voxel_downsample
from weldcell.plugins.scan_plan.metrics import fitness
from weldcell.plugins.scan_plan.registration import (
    IcpOptions,
    LazyNormals,
    NearestCache,
    linear_icp,
    point_to_plane_step,
)
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rotvec, invert, pose_error, transform_points

from .synthetic import corner_workpiece

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "small-gicp-lidar-pair" / "data"


def _pair(noise: float = 0.0002, outliers: int = 0):
    """Target and an independently sampled source with T_target_source = 5 deg about a tilted axis + 2 cm."""
    target, normals = corner_workpiece(noise=noise, seed=1)
    surf, _ = corner_workpiece(noise=noise, seed=2)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    T_true = T_from_rotvec(np.deg2rad(5.0) * axis, [0.012, -0.01, 0.0125])  # |t| = 2.0 cm
    source = transform_points(invert(T_true), surf)
    if outliers:
        rng = np.random.default_rng(3)
        source = np.concatenate([source, rng.uniform(-0.05, 0.25, (outliers, 3))])
    return source, target, normals, T_true


def test_recovers_known_transform_with_given_normals():
    source, target, normals, T_true = _pair()
    res = linear_icp(
        source,
        target,
        IcpOptions(max_correspondence_distance=0.05, max_iterations=50),
        target_normals=normals,
    )
    dt, dr = pose_error(res.T, T_true)
    assert dt < 2e-4 and dr < np.deg2rad(0.02)
    assert res.converged and res.iterations < 50
    fits = [h["fitness"] for h in res.history]
    assert fits[0] <= res.fitness and np.all(np.diff(fits) >= -1e-3)
    # at a tight inlier distance the share of aligned points (eq. 20) rises from well below to ~all
    assert fitness(source, target, np.eye(4), max_distance=0.004) < 0.3
    assert fitness(source, target, res.T, max_distance=0.004) > 0.99
    assert res.plane_rmse < 4e-4 and res.history[0]["plane_rmse"] > 10 * res.plane_rmse  # 0.2 mm noise
    assert res.history[0]["inlier_rmse"] > 5 * res.inlier_rmse
    assert np.allclose(res.T[:3, :3] @ res.T[:3, :3].T, np.eye(3), atol=1e-12)  # rigid after every step


def test_recovers_known_transform_with_pca_normals_and_paper_update():
    source, target, _, T_true = _pair()
    for update in ("exact", "linear"):
        res = linear_icp(source, target, IcpOptions(max_correspondence_distance=0.05, update=update))
        dt, dr = pose_error(res.T, T_true)
        assert dt < 3e-4 and dr < np.deg2rad(0.03), update


def test_fitness_is_eq20_inliers_over_target_points():
    source, target, normals, T_true = _pair(noise=0.0)
    half = source[::2]
    res = linear_icp(
        half, target, IcpOptions(max_correspondence_distance=0.004), target_normals=normals, init=T_true
    )
    assert res.fitness == pytest.approx(len(half) / len(target) * res.inlier_fraction)
    assert res.fitness == pytest.approx(len(half) / len(target), rel=0.02)


def test_robust_kernel_resists_outliers():
    source, target, normals, T_true = _pair(outliers=6000)
    plain = linear_icp(source, target, IcpOptions(max_correspondence_distance=0.05), target_normals=normals)
    for kernel in ("huber", "tukey"):
        robust = linear_icp(
            source,
            target,
            IcpOptions(max_correspondence_distance=0.05, robust=kernel),
            target_normals=normals,
        )
        dt, dr = pose_error(robust.T, T_true)
        assert dt < 5e-4 and dr < np.deg2rad(0.05), kernel
        assert dt < pose_error(plain.T, T_true)[0]


def test_initial_guess_is_used():
    source, target, normals, T_true = _pair()
    res = linear_icp(
        source, target, IcpOptions(max_correspondence_distance=0.01), target_normals=normals, init=T_true
    )
    assert res.history[0]["fitness"] > 0.95 * res.fitness and res.iterations <= 5


def test_single_linear_step_solves_a_small_motion():
    target, normals = corner_workpiece(seed=4)
    T = T_from_rotvec([0.0, 0.0, 1e-4], [1e-4, -2e-4, 5e-5])
    x = point_to_plane_step(transform_points(invert(T), target), target, normals)
    assert np.allclose(x, [0.0, 0.0, 1e-4, 1e-4, -2e-4, 5e-5], atol=2e-7)


@pytest.mark.parametrize("n_source", [2000, 6000])  # 6000: searched in Morton order, results in caller order
def test_nearest_cache_matches_a_full_query(n_source):
    rng = np.random.default_rng(5)
    target = rng.uniform(0, 1, (3000, 3))
    source = rng.uniform(0, 1, (n_source, 3))
    tree = cKDTree(target)
    cache = NearestCache(tree, target, 0.08, len(source))
    pts = source
    for step in range(12):
        pts = transform_points(
            T_from_rotvec(rng.normal(0, 0.01, 3), rng.normal(0, 0.01 / (step + 1), 3)), pts
        )
        d, i = cache.query(pts)
        d_ref, i_ref = tree.query(pts, k=1, distance_upper_bound=0.08)
        assert np.array_equal(np.isfinite(d), np.isfinite(d_ref))
        ok = np.isfinite(d)
        assert np.array_equal(i[ok], i_ref[ok]) and np.allclose(d[ok], d_ref[ok])
    assert cache.n_queries < 12 * len(source)  # re-queried only points that may have changed neighbour


def test_lazy_normals_give_the_result_of_all_normals_and_report_distances():
    source, target, _, T_true = _pair()
    full = linear_icp(
        source, target, IcpOptions(max_correspondence_distance=0.05), target_normals=pca_normals(target, k=20)
    )
    tree = cKDTree(target)
    lazy = linear_icp(source, target, IcpOptions(max_correspondence_distance=0.05), target_tree=tree)
    assert lazy.iterations == full.iterations and lazy.fitness == full.fitness
    assert np.allclose(lazy.T, full.T, atol=1e-12)
    # the distances are those of a nearest-neighbour search at the initial and the final pose
    d0, _ = tree.query(source, k=1, distance_upper_bound=0.05)
    d1, _ = tree.query(transform_points(lazy.T, source), k=1, distance_upper_bound=0.05)
    assert np.allclose(lazy.initial_distances, d0) and np.allclose(lazy.distances, d1)
    # normals are estimated only where asked, equal (up to sign) to pca_normals
    ln = LazyNormals(target, tree, k=20)
    ln.ensure(np.arange(0, len(target), 7))
    assert ln.n_estimated == len(range(0, len(target), 7))
    ref = pca_normals(target, k=20)[::7]
    assert np.allclose(np.abs(np.einsum("ij,ij->i", ln.table[::7, :3], ref)), 1.0, atol=1e-9)
    with pytest.raises(DataError):
        linear_icp(
            source, target, IcpOptions(max_correspondence_distance=0.05), target_tree=cKDTree(target[:-1])
        )


@pytest.mark.data
def test_real_lidar_pair_matches_reference():
    if not (DATA / "source.ply").is_file():
        pytest.skip(f"recorded LiDAR pair not found at {DATA}")
    from weldcell.sdk.cloud import read_cloud

    src = read_cloud(DATA / "source.ply", check_scale=False).points  # metres; 58 m extent (outdoor LiDAR)
    tgt = read_cloud(DATA / "target.ply", check_scale=False).points
    T_ref = np.loadtxt(DATA / "T_target_source.txt")
    s, t = voxel_downsample(src, voxel_size=0.25), voxel_downsample(tgt, voxel_size=0.25)
    # identity start, 0.49 m away from the reference: the correspondence distance must exceed the offset
    res = linear_icp(s, t, IcpOptions(max_correspondence_distance=0.5, max_iterations=50))
    dt, dr = pose_error(res.T, T_ref)
    dt0, _ = pose_error(np.eye(4), T_ref)
    assert dt0 > 0.4
    assert dt < 0.01 and dr < np.deg2rad(0.5)
    assert res.converged and res.fitness > res.history[0]["fitness"]


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(source=np.empty((0, 3))),
        dict(source=np.array([[0, 0, 0], [1, np.nan, 0], [0, 1, 0], [1, 1, 1.0]])),
        dict(target=np.ones((10, 2))),
        dict(target_normals=np.ones((5, 3))),
        dict(init=np.diag([2.0, 1, 1, 1])),
        dict(max_correspondence_distance=0.0),
        dict(robust="cauchy"),
        dict(update="quadratic"),
    ],
)
def test_bad_inputs_raise_data_error(kwargs):
    target, normals = corner_workpiece(spacing=0.01)
    args = dict(
        source=target + 0.001, target=target, target_normals=normals, max_correspondence_distance=0.01
    )
    args.update(kwargs)
    options = {k: args.pop(k) for k in ("max_correspondence_distance", "robust", "update") if k in args}
    with pytest.raises(DataError) as err:  # bad options are refused when the options are made
        linear_icp(options=IcpOptions(**options), **args)
    assert err.value.fix


def test_no_overlap_raises_data_error():
    target, normals = corner_workpiece(spacing=0.01)
    with pytest.raises(DataError, match="no correspondences"):
        linear_icp(target + 5.0, target, IcpOptions(max_correspondence_distance=0.01), target_normals=normals)


def test_prior_weighs_the_correction_against_the_data():
    source, target, normals, T_true = _pair()
    free = linear_icp(source, target, IcpOptions(max_correspondence_distance=0.05), target_normals=normals)
    loose = linear_icp(
        source,
        target,
        IcpOptions(max_correspondence_distance=0.05, prior=(10.0, 10.0)),
        target_normals=normals,
    )
    assert np.allclose(loose.T, free.T, atol=1e-6)  # a vague prior changes nothing
    # a prior of the size of the true offset still lets a well-constrained part register
    fair = linear_icp(
        source,
        target,
        IcpOptions(max_correspondence_distance=0.05, prior=(0.02, np.deg2rad(5))),
        target_normals=normals,
    )
    dt, dr = pose_error(fair.T, T_true)
    assert dt < 3e-4 and dr < np.deg2rad(0.03)
    # a prior far tighter than the data's pull keeps the initial guess
    tight = linear_icp(
        source,
        target,
        IcpOptions(max_correspondence_distance=0.05, prior=(1e-7, 1e-7)),
        target_normals=normals,
    )
    dt, dr = pose_error(tight.T, np.eye(4))
    assert dt < 1e-4 and dr < np.deg2rad(0.01)


def test_prior_keeps_weakly_observable_directions_near_the_initial_guess():
    # a noisy plane seen twice: rotation about its normal and sliding along it are observable only
    # through the noise of the estimated normals, so a plain solve wanders along them; a prior of the
    # kinematics' size keeps them near the initial guess and still corrects the 1 mm normal offset
    rng = np.random.default_rng(5)
    tgt = np.c_[rng.uniform(-0.1, 0.1, (4000, 2)), rng.normal(0, 3e-4, 4000)]
    src = np.c_[rng.uniform(-0.1, 0.1, (4000, 2)), 0.001 + rng.normal(0, 3e-4, 4000)]
    plain = linear_icp(src, tgt, IcpOptions(max_correspondence_distance=0.01))
    held = linear_icp(src, tgt, IcpOptions(max_correspondence_distance=0.01, prior=(0.002, np.deg2rad(0.3))))
    for r in (plain, held):
        assert abs(r.T[2, 3] + 0.001) < 5e-5
    assert np.linalg.norm(plain.T[:2, 3]) > 1.5e-3 and abs(plain.T[1, 0]) > np.deg2rad(2)  # wandered
    assert np.linalg.norm(held.T[:2, 3]) < 1e-3 and abs(held.T[1, 0]) < np.deg2rad(0.4)


@pytest.mark.parametrize("prior", [(0.0, 0.01), (0.002, -1.0), (float("nan"), 0.01), (0.002,), 0.002, "2 mm"])
def test_bad_prior_is_refused(prior):
    source, target, normals, _ = _pair()
    with pytest.raises(DataError, match="prior"):
        linear_icp(
            source, target, IcpOptions(max_correspondence_distance=0.05, prior=prior), target_normals=normals
        )
