"""Flange hand-eye: point fits (eqs. 9-12), circle RANSAC, segmentation, Algorithm 1, configurations."""

import numpy as np
import pytest
from weldcell.plugins.handeye.calibrate import calibrate
from weldcell.plugins.handeye.circle import ransac_circle
from weldcell.plugins.handeye.flange_model import iso9409_model
from weldcell.plugins.handeye.iterative import iterative_pool
from weldcell.plugins.handeye.pointfit import robust_point_fit, scaled_svd_fit
from weldcell.plugins.handeye.result import HandEyeSample
from weldcell.plugins.handeye.segmentation import segment_flange
from weldcell.plugins.handeye.simulation import PAPER_T_BASE_CAMERA, render_flange_scan, simulate_cell
from weldcell.plugins.handeye.verification import (
    ConsensusVerifier,
    GroundTruthVerifier,
    IcpVerifier,
    compensate,
    error_components,
)
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy, invert, pose_error, transform_points


def _assert_T(T, T_true, t_tol=1e-9, r_tol=1e-9):
    dt, dr = pose_error(T, T_true)
    assert dt < t_tol and dr < r_tol, (dt, dr)


def test_scaled_svd_recovers_scale_and_guards_reflection():
    rng = np.random.default_rng(3)
    src = rng.uniform(-0.2, 0.2, (20, 3))
    T = T_from_rpy([0.4, -0.3, 2.0], [0.6, -0.1, 1.0])
    dst = 2.5 * src @ T[:3, :3].T + T[:3, 3]
    fit = scaled_svd_fit(src, dst, with_scale=True)
    assert fit.scale == pytest.approx(2.5, rel=1e-12)
    assert np.allclose(fit.T[:3, :3], 2.5 * T[:3, :3]) and np.allclose(fit.T[:3, 3], T[:3, 3])
    assert fit.residuals.max() < 1e-12
    # mirrored data: the best orthogonal map is a reflection; eq. 12 must return a proper rotation
    mirrored = dst * np.array([1, 1, -1])
    fit = scaled_svd_fit(src, mirrored)
    assert fit.reflection_guarded
    assert np.linalg.det(fit.T[:3, :3]) == pytest.approx(1.0)
    # coplanar points (det Σ = 0): still a proper rotation and exact recovery
    flat = src.copy()
    flat[:, 2] = 0
    fit = scaled_svd_fit(flat, transform_points(T, flat))
    _assert_T(fit.T, T, 1e-12, 1e-9)


def test_robust_fit_rejects_gross_outliers():
    rng = np.random.default_rng(0)
    src = rng.uniform(-0.15, 0.15, (40, 3))
    T = T_from_rpy([3.14, 0, -1.57], [0.6, -0.0125, 1.0])
    dst = transform_points(T, src) + rng.normal(0, 0.0002, src.shape)
    bad = [3, 17, 30]
    dst[bad] += np.array([0.035, -0.02, 0.01])
    rf = robust_point_fit(src, dst)
    assert sorted(np.flatnonzero(~rf.inliers)) == bad
    assert pose_error(rf.T, T)[0] < 0.0003
    assert pose_error(scaled_svd_fit(src, dst).T, T)[0] > 0.002  # all-data LS is pulled away


def test_ransac_circle_finds_centre_with_outliers():
    model = iso9409_model(50.0, spacing=0.0004)
    face = model[model[:, 2] == 0]
    T_cf = T_from_rpy([2.9, 0.2, 0.5], [0.05, -0.1, 0.7])
    rng = np.random.default_rng(1)
    scan = transform_points(T_cf, face) + rng.normal(0, 0.00005, face.shape)
    outl = T_cf[:3, 3] + rng.uniform(-0.04, 0.04, (300, 3)) * [1, 1, 0.05]
    fit = ransac_circle(np.vstack([scan, outl]), radius=0.0315)
    assert np.linalg.norm(fit.center - T_cf[:3, 3]) < 1e-4  # within 0.1 mm
    assert fit.radius == pytest.approx(0.0315, abs=3e-4)
    assert abs(abs(fit.normal @ T_cf[:3, 2]) - 1) < 1e-4


def test_segmentation_isolates_flange_from_clutter():
    model = iso9409_model(50.0, spacing=0.0005)
    T_cf = T_from_rpy([np.pi, 0.15, 0.3], [0.02, -0.05, 0.65])
    raw = render_flange_scan(T_cf, model, sigma=0.0001, n_outliers=200, clutter=True, rng=2)
    seg = segment_flange(raw)
    fit = ransac_circle(seg.face, radius=0.0315)
    assert np.linalg.norm(fit.center - T_cf[:3, 3]) < 2e-4
    assert seg.report["extent_mm"] == pytest.approx(63, abs=3)


def _sim_samples(config, rng=0, n=20):
    cell = simulate_cell(n_poses=n, rng=rng)
    G = cell.T_base_flange
    return cell, G


def test_exact_recovery_eye_on_base():
    cell, G = _sim_samples("eye-on-base")
    smp = [HandEyeSample(T_base_flange=g, p_cam=p) for g, p in zip(G, cell.p_cam_true, strict=True)]
    for method in ("flange", "flange-svd", "flange-iterative"):
        r = calibrate(smp, "eye-on-base", method=method, bootstrap=0)
        assert r.name == "T_base_camera"
        _assert_T(r.T, PAPER_T_BASE_CAMERA, 1e-9, 1e-6)


def test_exact_recovery_eye_in_hand_known_and_estimated_feature():
    rng = np.random.default_rng(5)
    X = T_from_rpy([0.1, -0.2, 0.3], [0.03, 0.05, 0.08])  # T_flange_camera
    g = np.array([0.4, 0.1, 0.02])  # a feature fixed in the base
    G = np.array(
        [
            T_from_rpy(
                rng.uniform(-0.5, 0.5, 3) + [np.pi, 0, 0], rng.uniform(-0.15, 0.15, 3) + [0.4, 0.1, 0.5]
            )
            for _ in range(15)
        ]
    )
    c = np.array([transform_points(invert(Gi @ X), g)[0] for Gi in G])
    smp = [HandEyeSample(T_base_flange=Gi, p_cam=ci) for Gi, ci in zip(G, c, strict=True)]
    r = calibrate(smp, "eye-in-hand", feature_base=g.tolist(), bootstrap=0)
    assert r.name == "T_flange_camera"
    _assert_T(r.T, X, 1e-9, 1e-6)
    r = calibrate(smp, "eye-in-hand", feature_base="estimate", bootstrap=0)
    _assert_T(r.T, X, 1e-8, 1e-6)
    assert np.allclose(r.extra["feature_base"], g, atol=1e-8)


def test_exact_recovery_eye_on_arm_eq7_and_eq8():
    rng = np.random.default_rng(6)
    X = T_from_rpy([0.2, 0.1, -0.4], [0.1, 0.0, 0.05])  # T_arm_camera
    A = np.array(
        [T_from_rpy(rng.uniform(-0.6, 0.6, 3), rng.uniform(-0.1, 0.1, 3) + [0.1, 0, 0.6]) for _ in range(12)]
    )
    # eq. 8: flange poses such that the flange centre lies in front of the camera
    F = np.array(
        [Ai @ X @ T_from_rpy(rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.1, 0.1, 3) + [0, 0, 0.5]) for Ai in A]
    )
    c8 = np.array(
        [transform_points(invert(Ai @ X) @ Fi, np.zeros(3))[0] for Ai, Fi in zip(A, F, strict=True)]
    )
    smp = [
        HandEyeSample(T_base_arm=Ai, T_base_flange=Fi, p_cam=ci) for Ai, Fi, ci in zip(A, F, c8, strict=True)
    ]
    r = calibrate(smp, "eye-on-arm", bootstrap=0)
    assert r.name == "T_arm_camera"
    _assert_T(r.T, X, 1e-9, 1e-6)
    g = np.array([0.5, -0.2, 0.0])  # eq. 7: feature fixed in the cell
    c7 = np.array([transform_points(invert(Ai @ X), g)[0] for Ai in A])
    smp = [HandEyeSample(T_base_arm=Ai, p_cam=ci) for Ai, ci in zip(A, c7, strict=True)]
    _assert_T(calibrate(smp, "eye-on-arm", feature_base=g.tolist(), bootstrap=0).T, X, 1e-9, 1e-6)


def test_exact_recovery_co_manipulation():
    rng = np.random.default_rng(7)
    T_b1b2 = T_from_rpy([0, 0, np.pi], [1.2, 0.1, 0.0])
    X1 = T_from_rpy([0.1, 0.0, 0.2], [0.0, 0.05, 0.08])  # T_flange1_camera
    f2_parked = T_from_rpy([0.3, 0.2, 0.1], [0.6, 0.0, 0.4])  # robot 2's parked flange in base2
    g = transform_points(T_b1b2 @ f2_parked, np.zeros(3))[0]
    a = []
    for _ in range(12):
        G1 = T_from_rpy(rng.uniform(-0.5, 0.5, 3), rng.uniform(-0.1, 0.1, 3) + [0.6, 0.1, 0.8])
        a.append(HandEyeSample(T_base_flange=G1, p_cam=transform_points(invert(G1 @ X1), g)[0], phase="a"))
    G1p = T_from_rpy([np.pi, 0, 0], [0.6, 0.1, 1.0])
    b = []
    for _ in range(10):
        F2 = T_from_rpy(rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.1, 0.1, 3) + [0.6, 0.0, 0.4])
        p = transform_points(invert(G1p @ X1) @ T_b1b2 @ F2, np.zeros(3))[0]
        b.append(HandEyeSample(T_base_flange=G1p, T_base2_flange2=F2, p_cam=p, phase="b"))
    r = calibrate(a + b, "co-manipulation", bootstrap=0)
    assert r.name == "T_base1_base2"
    _assert_T(r.T, T_b1b2, 1e-7, 1e-7)
    _assert_T(r.extra["T_flange1_camera"], X1, 1e-7, 1e-7)


def test_algorithm1_converges_and_beats_all_data_with_outliers():
    cell = simulate_cell(n_poses=60, rng=11)
    rng = np.random.default_rng(11)
    c = cell.noisy_p_cam(0.001, rng)
    c[[5, 20, 33]] += [0.03, -0.02, 0.015]
    pr = iterative_pool(c, cell.p_base, GroundTruthVerifier(cell.T_base_camera))
    assert np.all(np.diff(pr.history[3:]) <= 1e-15)  # the pool's cost never grows
    assert not set(pr.pool) & {5, 20, 33}
    err_pool = pose_error(pr.H, cell.T_base_camera)[0]
    err_all = pose_error(scaled_svd_fit(c, cell.p_base).T, cell.T_base_camera)[0]
    assert err_pool < err_all / 3
    # eq. 21: compensation with the ground-truth error recovers the truth
    _assert_T(compensate(pr.H, pr.e), cell.T_base_camera, 1e-12, 1e-7)  # arccos floor ~3e-8 rad
    # the consensus verifier (no ground truth) also keeps the outliers out
    r = calibrate(
        [HandEyeSample(p_base=p, p_cam=q) for p, q in zip(cell.p_base, c, strict=True)],
        "eye-on-base",
        method="flange-iterative",
        bootstrap=0,
    )
    assert not set(r.metrics["pool"]) & {5, 20, 33}
    assert pose_error(r.T, cell.T_base_camera)[0] < err_all


def test_icp_metric_measures_the_planted_error():
    model = iso9409_model(50.0, spacing=0.0005)
    T_bf = T_from_rpy([np.pi, 0.1, 0.4], [0.55, 0.0, 0.35])
    T_true = PAPER_T_BASE_CAMERA
    cloud = transform_points(invert(T_true) @ T_bf, model)
    e_true = T_from_rpy([0.0, 0.0, 0.01], [0.0015, -0.001, 0.0005])
    H = T_true @ invert(e_true)  # so that H @ e_true = T_true
    e = IcpVerifier(model, T_bf, cloud)(H)
    assert e is not None
    _assert_T(compensate(H, e), T_true, 3e-4, 2e-3)  # 1.9 mm planted -> < 0.3 mm left


def _board_data(config: str, sigma: float, rng: int = 0):
    """Flange poses G, board poses C (corner noise σ) and the true X for one configuration."""
    truth = T_from_rpy([3.1415, 0, -1.57], [0.6, -0.0125, 1.0])  # off Tsai's 180° singularity
    cell = simulate_cell(n_poses=12, rng=rng, T_base_camera=truth)
    gen = np.random.default_rng(rng)
    if config == "eye-on-base":
        return cell.T_base_flange, cell.board_poses(sigma, gen, T_from_rpy([0, 0, 0.2], [0, 0, 0.005])), truth
    X = T_from_rpy([0.1, -0.2, 0.3], [0.03, 0.05, 0.1])
    C = np.einsum(
        "ij,njk,kl->nil", invert(X), np.linalg.inv(cell.T_base_flange), T_from_rpy([0, 0, 0.5], [0.6, 0, 0])
    )
    C[:, :3, 3] += gen.normal(0.0, sigma, (len(C), 3))
    return cell.T_base_flange, C, X


@pytest.mark.parametrize("method", ["tsai", "park", "horaud", "andreff", "daniilidis", "shah", "li"])
def test_numpy_solvers_match_opencv(method):
    cv2 = pytest.importorskip("cv2")
    if not hasattr(cv2, "calibrateHandEye"):
        pytest.skip(f"OpenCV {cv2.__version__} has no calibrateHandEye (5.0 wheels); nothing to compare")
    from weldcell.plugins.handeye.classical import HAND_EYE_METHODS, solve_hand_eye, solve_robot_world

    solve = solve_hand_eye if method in HAND_EYE_METHODS else solve_robot_world
    for config in ("eye-on-base", "eye-in-hand"):
        for sigma in (0.0, 0.001):
            G, C, X_true = _board_data(config, sigma)
            X_cv, info_cv = solve(G, C, config, method, backend="opencv")
            X_np, info_np = solve(G, C, config, method, backend="numpy")
            assert (info_cv["backend"], info_np["backend"]) == ("opencv", "numpy")
            dt, dr = pose_error(X_cv, X_np)
            if sigma == 0.0:
                assert dt < 1e-9 and dr < 1e-7, (config, dt, dr)
                _assert_T(X_np, X_true, 1e-8, 1e-7)
            elif method == "tsai" and config == "eye-on-base":
                continue  # 0.005° from Tsai's 180° singularity both are ill-conditioned (~5° apart)
            elif method == "tsai":  # same rotation; OpenCV 4.14's translation step is not plain eq. 15 LS
                assert dr < 1e-7 and dt < 1e-3, (config, dt, dr)
            else:
                assert dt < 1e-9 and dr < 1e-7, (config, dt, dr)


def test_algorithm1_sequential_listing_and_consensus_refit():
    cell = simulate_cell(rng=5)
    rng = np.random.default_rng(5)
    c = cell.noisy_p_cam(0.001, rng)
    bad = [7, 30, 51]
    c[bad] += [[0.02, 0.0, 0.0], [0.0, -0.025, 0.0], [0.0, 0.0, 0.015]]
    oracle = GroundTruthVerifier(cell.T_base_camera)
    best = iterative_pool(c, cell.p_base, oracle)
    seq = iterative_pool(c, cell.p_base, oracle, inner="sequential")
    # the literal listing can put the new pair into several slots; its cost still never grows
    assert np.all(np.diff(seq.history[3:]) <= 1e-15) and seq.cost <= 1.5e-3
    assert not set(seq.pool) & set(bad) and not set(best.pool) & set(bad)
    # the refit keeps the consistent pairs only and beats the four-pair pool in the work volume
    from weldcell.plugins.handeye.simulation import workspace_error

    r = iterative_pool(c, cell.p_base, oracle, refit=3.0)
    assert r.refit_inliers is not None and set(r.refit_inliers).isdisjoint(bad) and len(r.refit_inliers) >= 65
    ws = lambda H: workspace_error(H, cell.T_base_camera, cell.p_cam_true)  # noqa: E731
    assert ws(r.H_refit) < 0.5 * ws(r.H)
    assert ws(r.H_refit) < 0.5 * ws(scaled_svd_fit(c, cell.p_base).T)  # all-data is spoilt by the outliers
    with pytest.raises(Exception, match="inner"):
        iterative_pool(c, cell.p_base, oracle, inner="fancy")


def test_simulation_follows_the_paper_protocol():
    from weldcell.plugins.handeye.simulation import workspace_error

    assert np.allclose(PAPER_T_BASE_CAMERA[:3, :3], [[0, -1, 0], [-1, 0, 0], [0, 0, -1]])  # eq. 19
    cell = simulate_cell()
    P = cell.p_base
    assert len(P) == 75 and len(np.unique(P.round(6), axis=0)) == 75  # a 5 x 5 x 3 grid
    assert np.allclose(P.min(0), [0.45, -0.15, 0.2]) and np.allclose(P.max(0), [0.75, 0.15, 0.4])
    z_flange = cell.T_base_flange[:, :3, 2]  # faces the downward-looking camera within the ±0.3 rad jitter
    assert np.all(z_flange[:, 2] > np.cos(0.3 * np.sqrt(2)) - 1e-9)
    rng = np.random.default_rng(0)
    d = cell.noisy_p_cam(0.002, rng) - cell.p_cam_true
    assert d.std() == pytest.approx(0.002, rel=0.15)  # eq. 20: isotropic N(0, σ)
    d = cell.noisy_p_cam(0.002, rng, model="ray") - cell.p_cam_true
    u = cell.p_cam_true / np.linalg.norm(cell.p_cam_true, axis=1, keepdims=True)
    assert np.allclose(np.cross(d, u), 0, atol=1e-12)  # along the line of sight only
    # the error in the work volume is zero for the truth and the lever-arm product for a rotation
    assert workspace_error(cell.T_base_camera, cell.T_base_camera, cell.p_cam_true) == 0.0
    H = cell.T_base_camera @ T_from_rpy([0, 0, 0.001], [0, 0, 0])
    r = np.linalg.norm(cell.p_cam_true[:, :2], axis=1)
    assert workspace_error(H, cell.T_base_camera, cell.p_cam_true) == pytest.approx(
        0.001 * np.sqrt(np.mean(r**2)), rel=1e-3
    )


def test_resolve_translation_option():
    from weldcell.plugins.handeye.classical import solve_hand_eye, solve_robot_world

    G, C, X_true = _board_data("eye-in-hand", 0.0)
    for backend in ("numpy", "auto"):
        X, _ = solve_hand_eye(G, C, "eye-in-hand", "andreff", backend, resolve_translation=True)
        _assert_T(X, X_true, 1e-8, 1e-7)
        X, _ = solve_robot_world(G, C, "eye-in-hand", "li", backend, resolve_translation=True)
        _assert_T(X, X_true, 1e-8, 1e-7)
    G, C, _ = _board_data("eye-in-hand", 0.002)
    for method, solve, changes in (
        ("park", solve_hand_eye, False),  # already the least-squares translation
        ("andreff", solve_hand_eye, True),  # joint-solution translation replaced
        ("shah", solve_robot_world, False),
        ("li", solve_robot_world, True),
    ):
        X0, _ = solve(G, C, "eye-in-hand", method, "numpy")
        X1, _ = solve(G, C, "eye-in-hand", method, "numpy", resolve_translation=True)
        assert np.allclose(X0[:3, :3], X1[:3, :3])
        assert (np.abs(X0[:3, 3] - X1[:3, 3]).max() > 1e-6) == changes, method


def _pool_data(n=30, seed=0, sigma=0.001):
    cell = simulate_cell(n_poses=n, rng=seed)
    c = cell.noisy_p_cam(sigma, np.random.default_rng(seed))
    if n > 17:
        c[[6, 17]] += [[0.02, 0.0, 0.0], [0.0, 0.0, -0.015]]  # two false segmentations
    return cell, c


class _Counting:
    """A verifier wrapper recording how many calls each number of pairs seen received."""

    def __init__(self, verifier):
        self.verifier, self.calls = verifier, []

    def __call__(self, H, n_seen):
        self.calls.append(n_seen)
        return self.verifier(H, n_seen) if isinstance(self.verifier, ConsensusVerifier) else self.verifier(H)


def test_wide_search_never_costs_more_than_the_published_loop():
    for seed in range(3):
        cell, c = _pool_data(seed=seed)
        for verifier, sees in (
            (GroundTruthVerifier(cell.T_base_camera), False),
            (ConsensusVerifier(c, cell.p_base), True),
        ):
            pub = iterative_pool(c, cell.p_base, verifier, verifier_sees_count=sees)
            wide = iterative_pool(
                c, cell.p_base, verifier, verifier_sees_count=sees, search="wide", budget=8, seed=seed
            )
            assert np.all(wide.history[3:] <= pub.history[3:] + 1e-15), (
                seed
            )  # after every pair, not only at the end
            assert wide.cost <= pub.cost and not set(wide.pool) & {6, 17}
    # with the oracle the extra subsets pay off: a lower δt than the published greedy path finds
    cell, c = _pool_data(n=75, seed=4)
    oracle = GroundTruthVerifier(cell.T_base_camera)
    assert (
        iterative_pool(c, cell.p_base, oracle, search="wide", budget=64).cost
        < 0.6 * iterative_pool(c, cell.p_base, oracle).cost
    )


def test_calibrate_passes_the_pool_search_through():
    """calibrate(method="flange-iterative", search="wide") runs the wide search (more verifier work,
    same false segmentations kept out) and a bad search name is one clear error."""
    cell, c = _pool_data(seed=2)
    samples = [HandEyeSample(T_base_flange=T, p_cam=p) for T, p in zip(cell.T_base_flange, c, strict=True)]
    pub = calibrate(samples, "eye-on-base", "flange-iterative", bootstrap=0)
    wide = calibrate(samples, "eye-on-base", "flange-iterative", bootstrap=0, search="wide", budget=8)
    assert wide.metrics["cost"] <= pub.metrics["cost"] and not set(wide.metrics["pool"]) & {6, 17}
    with pytest.raises(DataError, match="search"):
        calibrate(samples, "eye-on-base", "flange-iterative", bootstrap=0, search="widest")


def test_wide_search_respects_budget_and_is_exhaustive_when_it_can_be():
    from itertools import combinations

    from weldcell.plugins.handeye.pointfit import rigid_fit_batch

    cell, c = _pool_data(n=40, seed=1)
    counter = _Counting(GroundTruthVerifier(cell.T_base_camera))
    pr = iterative_pool(c, cell.p_base, counter, verifier_sees_count=True, search="wide", budget=10, seed=3)
    per_pair = np.bincount(counter.calls)[5:]  # calls while pair n_seen - 1 was the new one
    # budget + the replacements of the published and of the best pool + 2 re-verifications
    assert len(counter.calls) == pr.n_verified and per_pair.max() <= 10 + 2 * 4 + 2 and per_pair.min() > 4
    # a budget covering every subset: the wide search finds the best 4-subset of all pairs
    cell, c = _pool_data(n=9, seed=2)
    oracle = GroundTruthVerifier(cell.T_base_camera)
    pr = iterative_pool(c, cell.p_base, oracle, search="wide", budget=100)
    subsets = np.array(list(combinations(range(9), 4)))
    costs = [np.linalg.norm(oracle(H)[:3, 3]) for H in rigid_fit_batch(c[subsets], cell.p_base[subsets])]
    assert sorted(pr.pool) == list(subsets[int(np.argmin(costs))]) and pr.cost == pytest.approx(min(costs))


def test_wide_search_is_reproducible_and_checks_its_arguments():
    cell, c = _pool_data(n=50, seed=5)
    oracle = GroundTruthVerifier(cell.T_base_camera)
    a, b = (iterative_pool(c, cell.p_base, oracle, search="wide", budget=8, seed=11) for _ in range(2))
    g = iterative_pool(c, cell.p_base, oracle, search="wide", budget=8, seed=np.random.default_rng(11))
    assert a.pool == b.pool == g.pool and np.array_equal(a.history, b.history) and np.array_equal(a.H, g.H)
    for budget in (0, -3, 2.5, True):
        with pytest.raises(DataError, match="budget"):
            iterative_pool(c, cell.p_base, oracle, search="wide", budget=budget)
    with pytest.raises(DataError, match="pool_size"):
        iterative_pool(c[:5], cell.p_base[:5], oracle, pool_size=6)
    with pytest.raises(DataError, match="search"):
        iterative_pool(c, cell.p_base, oracle, search="everything")


def test_pairs_crlb_is_what_the_all_data_fit_attains():
    from weldcell.plugins.handeye.simulation import crlb_workspace_rms, pairs_crlb

    cell = simulate_cell(rng=0)
    cov = pairs_crlb(cell.p_cam_true, 0.001)
    rng = np.random.default_rng(1)
    E = np.array(
        [
            invert(scaled_svd_fit(cell.noisy_p_cam(0.001, rng), cell.p_base).T) @ cell.T_base_camera
            for _ in range(400)
        ]
    )
    assert np.allclose(E[:, :3, 3].std(0), np.sqrt(np.diag(cov)[:3]), rtol=0.12)  # LS is efficient
    # in the work volume (the fit's own points) the bound is sqrt(6 / n) σ: 6 parameters from n points
    assert crlb_workspace_rms(cov, cell.p_cam_true) == pytest.approx(np.sqrt(6 / 75) * 0.001, rel=1e-9)


def test_scan_verifier_measures_an_estimate_against_a_noisy_verification_scan():
    from weldcell.plugins.handeye.simulation import scan_verifier

    cell = simulate_cell(rng=0)
    v = scan_verifier(cell, 0.0002, rng=1)
    planted = T_from_rpy([0.002, -0.001, 0.0], [0.004, -0.002, 0.001])
    H = cell.T_base_camera @ invert(planted)
    left = error_components(invert(compensate(H, v(H))) @ cell.T_base_camera)
    # 4.6 mm and 2.2 mrad of tilt planted -> < 1 mm and < 1 mrad left (yaw about the flange axis
    # is barely observable from the near-symmetric flange: not asserted, see docs/methods/hand-eye.md)
    assert np.linalg.norm([left["dx"], left["dy"], left["dz"]]) < 0.001
    assert abs(left["droll"]) < 0.001 and abs(left["dpitch"]) < 0.001


def test_consensus_verifier_does_not_let_the_pool_verify_itself():
    """With e_required = 0 (the calibrate() default) Algorithm 1 must not stop after four pairs
    because the consensus of the pool's own four pairs reproduces its fit (e = I, cost 0)."""
    from weldcell.plugins.handeye.pointfit import rigid_fit_batch

    rng = np.random.default_rng(9001)  # a run of the §3.1 outlier study that used to stop at 4 pairs
    cell = simulate_cell(rng=rng)
    c = cell.noisy_p_cam(0.001, rng)
    bad = rng.choice(75, 3, replace=False)
    d = rng.normal(size=(3, 3))
    c[bad] += d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.01, 0.03, (3, 1))
    cv = ConsensusVerifier(c, cell.p_base)
    assert cv(rigid_fit_batch(c[None, :4], cell.p_base[None, :4])[0], 4) is None  # nothing to check it with
    pr = iterative_pool(c, cell.p_base, cv, verifier_sees_count=True)
    assert pr.n_used == 75 and pr.cost > 0 and not set(pr.pool) & set(bad)
