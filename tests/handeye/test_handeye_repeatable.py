"""The hand-eye step is repeatable: the same scans give the same calibration, bit for bit, on every run.

Open3D's ICP and plane RANSAC run on oneTBB threads whose split of the work depends on the host's
load; Algorithm 1 used to stop at a wall-clock time limit. Both made two runs of the simulated
calibrate-and-track job differ from the hand-eye step on.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from weldcell.plugins.handeye.calibrate import DEFAULTS
from weldcell.plugins.handeye.flange_model import iso9409_model
from weldcell.plugins.handeye.iterative import iterative_pool
from weldcell.plugins.handeye.simulation import render_flange_scan
from weldcell.plugins.handeye.stages import FlangeHandEye, FlangeSettings
from weldcell.plugins.handeye.verification import IcpVerifier
from weldcell.sdk.geometry import T_from_rpy, invert, transform_points
from weldcell.sdk.repeatable import open3d_serial


@pytest.fixture
def threaded_open3d():
    """Open3D with its automatic (multi-threaded) default, as in a job; restored afterwards."""
    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(0)
    yield
    o3d.utility.set_max_threads(before)


def test_open3d_serial_limits_open3d_to_one_thread_and_restores_the_limit(threaded_open3d):
    before = o3d.utility.get_max_threads()
    with open3d_serial():
        assert o3d.utility.get_max_threads() == 1
        with open3d_serial():  # nested: still one thread, and the outer block keeps it
            pass
        assert o3d.utility.get_max_threads() == 1
    assert o3d.utility.get_max_threads() == before


def _measure(stage: FlangeHandEye, scan: np.ndarray) -> tuple[np.ndarray, ...]:
    m = stage.measure(scan, seed=3)
    return m.p_cam, m.normal, m.face, stage.measure_pose(m)


def test_two_runs_of_the_flange_measurement_give_identical_results(threaded_open3d):
    """Segmentation (plane RANSAC, peeled planes), circle and ICP pose of one cluttered scan, three times."""
    model = iso9409_model(50.0, spacing=0.0007)
    T_cam_flange = T_from_rpy([np.pi + 0.25, -0.2, 0.7], [0.03, -0.02, 0.72])
    scan = render_flange_scan(T_cam_flange, model, sigma=2e-4, clutter=True, rng=5)
    stage = FlangeHandEye(FlangeSettings())
    first = _measure(stage, scan)
    assert np.linalg.norm(first[0] - T_cam_flange[:3, 3]) < 5e-4  # it measured the flange
    for _ in range(2):
        again = _measure(stage, scan)
        assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))


def _pairs_and_verifier(n: int = 14):
    """Flange centres in the camera (src) and base (dst) under a true T_base_camera, with noise, and
    the ICP verifier (eq. 13) of a verification scan."""
    rng = np.random.default_rng(2)
    T_true = T_from_rpy([np.pi, 0.1, -0.3], [0.9, 0.05, 1.1])
    dst = rng.uniform([0.4, -0.2, 0.3], [0.7, 0.2, 0.5], (n, 3))
    src = transform_points(invert(T_true), dst) + rng.normal(0.0, 3e-4, (n, 3))
    model = iso9409_model(50.0, spacing=0.001, rim_depth=0.002)
    T_bf = T_from_rpy([0.0, 0.0, 0.4], [0.55, 0.0, 0.4])
    cloud = render_flange_scan(invert(T_true) @ T_bf, model, sigma=2e-4, rng=7)
    return src, dst, IcpVerifier(model, T_bf, cloud)


def test_two_runs_of_algorithm_1_with_the_icp_verifier_give_identical_results(threaded_open3d):
    src, dst, verifier = _pairs_and_verifier()
    runs = [iterative_pool(src, dst, verifier, e_required=0.0, max_verifications=25) for _ in range(2)]
    a, b = runs
    assert np.array_equal(a.H, b.H) and np.array_equal(a.history, b.history) and a.pool == b.pool
    assert a.e is not None and np.array_equal(a.e, b.e)
    # the run is cut by the number of verifier calls, at the same pair every time (never by the clock)
    assert a.timed_out and a.n_verified == b.n_verified and a.n_used == b.n_used < len(src)
    assert a.events[-1] == b.events[-1] and "verification limit 25" in a.events[-1]


def test_the_calibration_has_no_wall_clock_limit_by_default():
    assert DEFAULTS["time_limit"] is None and DEFAULTS["max_verifications"] > 0
    s = FlangeSettings()
    assert s.pool_time_limit is None and s.pool_max_verifications == DEFAULTS["max_verifications"]
