"""The key frames' pose covariance (estimator -> key-frame store) and its use in the plate's box fit: one
rigid correction per pass of the route, fitted with the box under the covariance's prior (plate_poses.py).
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X
from scipy.spatial.transform import Rotation
from weldcell.hal.sim.camera_model import RaycastCamera
from weldcell.hal.sim.camera_presets import zed_mode
from weldcell.plugins.mapping.estimator import VioEstimator
from weldcell.plugins.mapping.globalopt import GlobalGraph
from weldcell.plugins.mapping.mapstore import KeyFrameRecord, KeyFrameStore
from weldcell.plugins.mapping.plate import frame_observations, merge, plate_fit
from weldcell.plugins.mapping.plate_fit import PlateView
from weldcell.plugins.mapping.plate_poses import camera_pose_cov, group_passes
from weldcell.plugins.mapping.regions import corner_distance_error

from tests.mapping.test_plate_fit import CAMERA_HEIGHT, PLATE, VIEWS, _box, _look_at


def _T(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def test_key_frame_covariance_comes_from_the_global_batch_and_grows_along_a_chain():
    """The marginal covariance of each key frame's pose after the batch (gtsam Marginals): the first key
    frame is held by its prior, the others by a chain of relative-pose factors, so the sigma grows along
    the chain as the random walk of the factors' sigmas."""
    gg, g, vals = GlobalGraph(), gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)))
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.002] * 3 + [0.01] * 3))
    step = gtsam.Pose3(gtsam.Rot3(), gtsam.Point3(0.2, 0, 0))
    for k in range(30):
        vals.insert(X(k), gtsam.Pose3(gtsam.Rot3(), gtsam.Point3(0.2 * k, 0, 0)))
        vals.insert(V(k), np.zeros(3))
        vals.insert(B(k), gtsam.imuBias.ConstantBias())
        if k:
            g.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), step, odo))
        g.add(gtsam.PriorFactorVector(V(k), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
        g.add(gtsam.PriorFactorConstantBias(B(k), gtsam.imuBias.ConstantBias(), odo))
    gg.add(g)
    kfs = [SimpleNamespace(index=k, t=float(k), covariance=None) for k in range(30)]
    est = SimpleNamespace(global_graph=gg, keyframes=kfs, _event=lambda *a: None)
    VioEstimator._pose_covariances(est, vals)
    sd = np.array([np.sqrt(np.diag(k.covariance)) for k in kfs])
    assert sd[0, 3] < 2e-4 and sd[1, 3] == pytest.approx(0.01, rel=0.05)
    assert sd[29, 3] == pytest.approx(0.01 * np.sqrt(29), rel=0.05)  # translation random walk
    assert np.all(np.diff(sd[:, 3]) > 0)


def test_store_keeps_the_covariance_and_reads_a_store_without_it(tmp_path):
    """keyframes.json gains an optional ``covariance`` per key frame; an index written before it (no
    field) still loads, with None."""
    store = KeyFrameStore(tmp_path, None, np.eye(4))
    C = np.diag([1e-6] * 3 + [4e-4] * 3)
    for i, cov in enumerate([C, None]):
        store.records.append(
            KeyFrameRecord(
                i, i * 0.2, i * 0.2, np.eye(4), np.eye(4), np.zeros(3), np.zeros(6), "f", True, cov
            )
        )
    store.save_index()
    data = json.loads(store.index_path.read_text())
    assert "covariance" in data["keyframes"][0] and "covariance" not in data["keyframes"][1]
    back = KeyFrameStore.load(tmp_path)
    assert np.allclose(back.records[0].covariance, C) and back.records[1].covariance is None
    store.update_poses({1: (np.eye(4), np.eye(4))}, {1: 2 * C})
    assert np.allclose(store.records[1].covariance, 2 * C)


def test_camera_pose_cov_is_the_first_order_map_of_the_imu_pose_error():
    """A body-frame error ξ of T_world_imu (gtsam: T·Exp(ξ)) moves the camera mounted at T_imu_cam: the
    world rotation and the camera centre's displacement are J ξ, with J the map camera_pose_cov uses."""
    T_wi = _T([0.1, -0.2, 1.3], [3.0, -2.0, 0.5])
    T_ic = _T([-np.pi / 2, 0, -np.pi / 2], [0.2, 0.05, 0.4])
    T_wc = T_wi @ T_ic
    rng = np.random.default_rng(0)
    for _ in range(3):
        xi = rng.normal(0, 1e-4, 6)
        moved = T_wi @ gtsam.Pose3.Expmap(xi).matrix() @ T_ic
        dR = moved[:3, :3] @ T_wc[:3, :3].T
        got = np.r_[Rotation.from_matrix(dR).as_rotvec(), moved[:3, 3] - T_wc[:3, 3]]
        # the covariance of a point mass at xi: J xi xiᵀ Jᵀ; compare through its action
        C = camera_pose_cov(T_wi, np.outer(xi, xi), T_wc)
        assert np.allclose(C, np.outer(got, got), atol=1e-12 + 1e-3 * np.abs(np.outer(got, got)).max())


def test_views_are_grouped_into_passes_by_consecutive_key_frames():
    """Key frames at most PASS_GAP (the estimator's links, 3) apart are one pass; without a covariance
    on every view there is no correction."""
    cov = np.eye(6) * 1e-4

    def view(k, x):
        T = np.eye(4)
        T[0, 3] = x
        return PlateView(np.ones((2, 2)), 0, 0, 1.0, 1.0, 0.0, 0.0, T, 1e-3, k, cov)

    vs = [view(k, float(k)) for k in (40, 41, 44, 48, 120, 121, 300)]
    passes = group_passes(vs)
    assert [p.keyframes for p in passes] == [(40, 41, 44), (48,), (120, 121), (300,)]
    assert np.allclose(passes[0].pivot, [(40 + 41 + 44) / 3, 0, 0])
    # a rotation error about the pass's pivot moves the view at the lever arm: the prior carries it
    assert passes[0].cov[4, 4] > cov[4, 4]
    vs[2].pose_cov = None
    assert group_passes(vs) is None


@pytest.fixture(scope="module")
def two_passes():
    """The plate seen on two passes (six views from each of two sides, key frames 10-15 and 200-205),
    rendered at the true poses; the second pass's poses then carry a rigid error (25 mm along the first
    pass's line of sight, 15 mm up, 4 mrad of yaw about its pivot), as the passes of the route disagree."""
    preset = zed_mode("VGA")
    scene = [PLATE.workpiece(), _box([0, 0, 0.4], [0.3, 0.2, 0.8]), _box([0, 0, -0.05], [12, 12, 0.1])]
    cam = RaycastCamera(preset, scene)
    lo, hi = PLATE.center - [0.55, 0.55, 0.25], PLATE.center + [0.55, 0.55, 0.25]
    poses, depths = [], []
    for k, (az, dist) in enumerate(VIEWS):
        a = np.radians(az)
        eye = np.array([dist * np.cos(a), dist * np.sin(a), CAMERA_HEIGHT])
        poses.append(_look_at(eye, PLATE.center + [0, 0, -0.1]))
        depths.append(cam.render(poses[-1], rng=k).depth)
    pivot = np.mean([T[:3, 3] for T in poses[6:]], axis=0)
    E = _T([0, 0, 0.004], [0.025, 0.0, 0.015])
    E[:3, 3] += pivot - E[:3, :3] @ pivot
    # the prior the test assumes, world [ω, δx at the camera]: roll and pitch held by gravity
    sig = np.diag([0.001**2, 0.001**2, 0.004**2] + [0.02**2] * 3)

    def obs(correct: bool):
        out = []
        for k, (T, d) in enumerate(zip(poses, depths, strict=True)):
            Te = E @ T if k >= 6 else T
            kf = 10 + k if k < 6 else 194 + k
            cov = sig if correct else None
            out.append(frame_observations(d, cam.intrinsics, Te, lo, hi, preset.sigma2, kf, cov))
        return merge(out)

    return obs


def test_pass_correction_removes_the_disagreement_of_two_passes(two_passes):
    """With the second pass 25 mm / 15 mm / 4 mrad off, the box fitted at the key frames' poses cannot
    fit both passes (18.8 mm); with one rigid correction per pass under the covariance's prior the fit
    measures the plate within 5 mm (2.2 mm), each pass's correction plausible under its prior (squared
    Mahalanobis distance below the χ²(6) 0.999 quantile). The corrections themselves are not the error
    undone: along each pass's line of sight and vertically (against the thickness) the grazing views
    hardly tell a shift, and the fit spends the prior there (AE does not depend on it)."""
    fixed = plate_fit(two_passes(False))
    fit = plate_fit(two_passes(True))
    assert fit.ok, fit.reason
    ae_fixed = corner_distance_error(fixed.corners, PLATE.corners) if fixed.ok else np.inf
    ae = corner_distance_error(fit.corners, PLATE.corners)
    assert ae < 0.005 and ae_fixed > ae + 0.005, (ae, ae_fixed)
    assert [p["keyframes"] for p in fit.passes] == [tuple(range(10, 16)), tuple(range(200, 206))]
    assert all(p["d2"] < 22.46 for p in fit.passes), fit.passes
