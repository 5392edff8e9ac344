"""Metrics of paper 000: fitness (eq. 20), rasterised F1 (eq. 21), pose RMSE (eq. 22)."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.plugins.scan_plan.metrics import fitness, harmonic_mean, pose_rmse, seam_f1
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rotvec, frame_from_axes, make_T

RNG = np.random.default_rng(0)


def seam(n: int = 200) -> np.ndarray:
    """A curved 3-D seam (helix segment), 10 cm long."""
    s = np.linspace(0, 1, n)
    return np.c_[0.1 * s, 0.02 * np.sin(3 * s), 0.01 * np.cos(2 * s)]


def torch_frames(P: np.ndarray, approach: np.ndarray) -> np.ndarray:
    travel = np.gradient(P, axis=0)
    return np.stack([frame_from_axes(x, z, p) for x, z, p in zip(travel, approach, P, strict=True)])


def test_fitness_eq20():
    P = RNG.random((1000, 3))
    assert fitness(P, P, max_distance=1e-6) == 1.0
    assert fitness(P[:500], P, max_distance=1e-6) == pytest.approx(0.5)  # divided by |P_t|
    assert fitness(P[:500], P, max_distance=1e-6, denominator="source") == 1.0
    shifted = fitness(P, P, make_T(t=[0.05, 0, 0]), max_distance=0.02)
    assert 0.0 < shifted < 0.9
    assert fitness(P, P, make_T(t=[0.05, 0, 0]), max_distance=0.2) == 1.0


def test_seam_f1_identical_is_one_and_drops_when_shifted():
    G = seam()
    r = seam_f1(G, G, cell=0.002)
    assert r["f1"] == r["precision"] == r["recall"] == 1.0
    assert set(r["planes"]) == {"xy", "xz", "yz"}
    shifted = seam_f1(G + [0, 0.006, 0.006], G, cell=0.002)
    assert shifted["f1"] < 0.2
    # a one-cell offset is forgiven with one cell of tolerance, not without it
    near = G + [0, 0.0021, 0]
    assert seam_f1(near, G, cell=0.002)["f1"] < 0.7
    assert seam_f1(near, G, cell=0.002, tolerance_cells=1)["f1"] > 0.95


def test_seam_f1_separates_precision_and_recall():
    G = seam()
    half = seam_f1(G[:100], G, cell=0.002)  # detected half of the seam, nothing false
    assert half["precision"] == 1.0 and 0.3 < half["recall"] < 0.7
    assert half["f1"] == pytest.approx(harmonic_mean([v["f1"] for v in half["planes"].values()]))
    noisy = seam_f1(np.r_[G, RNG.uniform(-0.05, 0.15, (200, 3))], G, cell=0.002)
    assert noisy["recall"] == 1.0 and noisy["precision"] < 0.7


def test_harmonic_mean_eq21():
    assert harmonic_mean([0.5, 1.0, 1.0]) == pytest.approx(3 / (2 + 1 + 1))
    assert harmonic_mean([0.0, 1.0, 1.0]) == 0.0


def test_pose_rmse_zero_for_ground_truth_and_known_errors():
    G = seam()
    A = np.tile([0.0, 0.0, -1.0], (len(G), 1))
    frames = torch_frames(G, A)
    r = pose_rmse(frames, G, A)
    assert r["translation_m"] < 1e-9 and r["rotation_rad"] < 1e-6 and r["n"] == len(G)
    # every torch 1 mm back along its approach axis; every torch turned 2 degrees about its approach axis
    back = pose_rmse((frames @ make_T(t=[0, 0, -0.001]))[::7], G, A, np.gradient(G, axis=0))
    assert back["translation_m"] == pytest.approx(0.001, rel=0.02)  # distance to the (curved) seam line
    turned = pose_rmse(frames @ T_from_rotvec([0, 0, np.deg2rad(2.0)]), G, A)
    assert turned["rotation_rad"] == pytest.approx(np.deg2rad(2.0), rel=1e-3)
    assert turned["approach_rad"] < 1e-6 and turned["translation_m"] < 1e-9
    tilt = frames @ T_from_rotvec([np.deg2rad(3.0), 0, 0])
    assert pose_rmse(tilt, G, A)["approach_rad"] == pytest.approx(np.deg2rad(3.0), rel=1e-3)


def test_pose_rmse_matches_along_the_seam_not_by_index():
    G = seam(50)
    A = np.tile([0.0, 0.0, -1.0], (len(G), 1))
    dense = seam(1000)  # a denser, differently sampled path on the same line
    frames = torch_frames(dense, np.tile([0.0, 0.0, -1.0], (len(dense), 1)))
    r = pose_rmse(frames, G, A)
    assert r["translation_m"] < 5e-5 and r["rotation_rad"] < np.deg2rad(0.5)


@pytest.mark.parametrize(
    "call",
    [
        lambda: seam_f1(np.empty((0, 3)), seam()),
        lambda: seam_f1(seam(), seam(), cell=0.0),
        lambda: seam_f1(np.full((3, 3), np.nan), seam()),
        lambda: fitness(np.ones((3, 2)), seam(), max_distance=0.1),
        lambda: fitness(seam(), seam(), max_distance=-1.0),
        lambda: pose_rmse(np.eye(3), seam(), np.ones((200, 3))),
        lambda: pose_rmse(np.full((2, 4, 4), np.nan), seam(), np.ones((200, 3))),
        lambda: pose_rmse(np.eye(4)[None], seam(), np.ones((10, 3))),
        lambda: pose_rmse(np.eye(4)[None], seam(), np.zeros((200, 3))),
        lambda: pose_rmse(np.eye(4)[None], seam(), np.ones((200, 3)), np.ones((5, 3))),
    ],
)
def test_bad_inputs_raise_data_error(call):
    with pytest.raises(DataError) as err:
        call()
    assert err.value.fix
