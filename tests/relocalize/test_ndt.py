"""NDT (Magnusson): score constants, regularised Gaussians, analytic derivatives, recovery of known poses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from weldcell.plugins.relocalize import synth
from weldcell.sdk.errors import DataError
from weldcell.sdk.registration import ndt


def _err(T_true, T):
    E = np.linalg.inv(T_true) @ T
    return float(np.linalg.norm(E[:3, 3])), math.degrees(Rotation.from_matrix(E[:3, :3]).magnitude())


def test_score_constants_fit_the_mixture_at_zero_and_one_sigma():
    """Thesis eq. 6.8: d1 exp(-d2 x^2/2) + d3 equals -log(c1 exp(-x^2/2) + c2) at x = 0 and x = 1."""
    for r, po in [(1.0, 0.55), (0.3, 0.2), (4.0, 0.9)]:
        d1, d2 = ndt.score_constants(r, po)
        c1, c2 = 10 * (1 - po), po / r**3
        d3 = -math.log(c2)
        assert d1 < 0 < d2
        assert d1 + d3 == pytest.approx(-math.log(c1 + c2))
        assert d1 * math.exp(-d2 / 2) + d3 == pytest.approx(-math.log(c1 * math.exp(-0.5) + c2))


def test_planar_cell_covariance_is_regularised():
    rng = np.random.default_rng(0)
    plane = np.column_stack([rng.random(500), rng.random(500), np.zeros(500)])  # one flat 1 m cell
    grid = ndt.build_cells(plane + 1e-3, 1.0, ndt.NDTSettings())
    cov = np.linalg.inv(grid.inv_cov[0])
    w = np.linalg.eigvalsh(cov)
    assert w[0] == pytest.approx(0.01 * w[2], rel=1e-6)  # thesis §6.2: raised to 1 % of the largest
    with pytest.raises(DataError):
        ndt.build_cells(plane[:3], 1.0, ndt.NDTSettings())


def test_gradient_and_hessian_match_finite_differences(monkeypatch):
    rng = np.random.default_rng(1)
    tgt = rng.normal(size=(3000, 3)) * [2, 1, 0.3]
    grid = ndt.build_cells(tgt, 1.0, ndt.NDTSettings())
    src = tgt[:400] + [0.1, -0.05, 0.02]
    fixed = ndt._pairs(grid, src, 7)
    monkeypatch.setattr(ndt, "_pairs", lambda g, p, k: fixed)  # cell assignment frozen: a smooth function

    def f(d):
        T = ndt._increment(d)
        return ndt.evaluate(grid, src @ T[:3, :3].T + T[:3, 3], 7, derivatives=False)[0]

    _, g, H, _, _ = ndt.evaluate(grid, src, 7)
    h, eye = 1e-4, np.eye(6)
    g_fd = np.array([(f(h * eye[i]) - f(-h * eye[i])) / (2 * h) for i in range(6)])
    assert np.allclose(g, g_fd, rtol=1e-4, atol=1e-4 * np.abs(g).max())
    h = 1e-3
    H_fd = np.array(
        [
            [
                (
                    f(h * (eye[i] + eye[j]))
                    - f(h * (eye[i] - eye[j]))
                    - f(h * (eye[j] - eye[i]))
                    + f(-h * (eye[i] + eye[j]))
                )
                / (4 * h * h)
                for j in range(6)
            ]
            for i in range(6)
        ]
    )
    assert np.abs(H - H_fd).max() < 2e-3 * np.abs(H).max()


@pytest.fixture(scope="module")
def scene():
    return synth.site_cloud(seed=3, size=(16.0, 12.0), spacing=0.08)


@pytest.mark.parametrize(
    "offset",
    [(0.4, -0.3, 0.1, 8.0, 1.0, -1.0), (1.5, 1.0, 0.0, -15.0, 0.0, 2.0), (-2.0, 0.5, 0.2, 25.0, 0.0, 0.0)],
)
def test_ndt_recovers_known_transform_of_structured_scene(scene, offset):
    x, y, z, yaw, roll, pitch = offset
    T_true = synth.pose(x, y, z, math.radians(yaw), math.radians(roll), math.radians(pitch))
    Ti = np.linalg.inv(T_true)
    src = synth.site_cloud(seed=3, size=(16.0, 12.0), spacing=0.08, sample_seed=9)  # resampled, new noise
    src = src @ Ti[:3, :3].T + Ti[:3, 3]
    res = ndt.ndt_align(scene, src, uncertainty=math.hypot(x, y) + 1.0)
    t_err, r_err = _err(T_true, res.T)
    assert res.converged and res.overlap > 0.95
    assert t_err < 0.02 and r_err < 0.1


def test_resolutions_follow_the_data():
    coarse = synth.site_cloud(seed=1, size=(12.0, 10.0), spacing=0.2)
    fine = synth.site_cloud(seed=1, size=(12.0, 10.0), spacing=0.05)
    s = ndt.NDTSettings()
    assert ndt.fine_resolution(fine, s) < ndt.fine_resolution(coarse, s)
    f = ndt.fine_resolution(fine, s)
    lad = ndt.resolution_ladder(fine, s, uncertainty=1.0)
    # coarse: 2 x the uncertainty, snapped to fine x 2^k (within a factor sqrt 2), so one prepared target
    # serves every uncertainty with the same cells
    assert 2.0 / np.sqrt(2) <= lad[0] <= 2.0 * np.sqrt(2) and lad[-1] == pytest.approx(f)
    assert all(np.log2(r / f) == pytest.approx(round(np.log2(r / f))) for r in lad)
    assert all(a > b for a, b in zip(lad, lad[1:], strict=False))
    top = ndt.resolution_ladder(fine, s, uncertainty=50.0)[0]
    assert np.ptp(fine, axis=0).max() / 8 < top <= np.ptp(fine, axis=0).max() / 4 * 1.001  # <= 1/4 extent
    assert set(ndt.resolution_ladder(fine, s, uncertainty=0.7)) <= set(lad) | {top}


@pytest.mark.data
def test_ndt_on_real_lidar_pair(shared_data):
    from weldcell.sdk.cloud import read_cloud

    d = shared_data / "small-gicp-lidar-pair" / "data"
    if not d.is_dir():
        pytest.skip(f"{d} not found")
    src = read_cloud(d / "source.ply", check_scale=False).points
    tgt = read_cloud(d / "target.ply", check_scale=False).points
    T_ref = np.loadtxt(d / "T_target_source.txt")
    T0 = synth.pose(1.2, -1.6, 0.0, math.radians(10.0)) @ T_ref  # 2 m, 10 deg off
    res = ndt.ndt_align(tgt, src, T0, uncertainty=2.0)
    t_err, r_err = _err(T_ref, res.T)
    assert t_err < 0.05 and r_err < 0.3
