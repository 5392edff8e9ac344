"""The simulated laser displacement sensor (optoNCDT 1402 model), the simulated robot's timed trajectory and
the sensor's stream at 1.5 kHz along it."""

from __future__ import annotations

import time

import numpy as np
import pytest
from weldcell.hal.kinematics import get_model
from weldcell.hal.robot import RobotMotionSettings
from weldcell.hal.safety import SafetyGate
from weldcell.hal.sim.devices import SimDisplacementSensor, SimRobot
from weldcell.hal.sim.laser_model import PRESETS, CouplingError, LaserModel, preset
from weldcell.hal.sim.weldment import weldment_workpiece
from weldcell.hal.sim.world import SimWorld
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy

DOWN = np.diag([1.0, -1.0, -1.0])


def pose(x: float, y: float, z: float, yaw: float = 0.0) -> np.ndarray:
    T = T_from_rpy([np.pi, 0.0, 0.0], [x, y, z])
    T[:3, :3] = T_from_rpy([0, 0, yaw])[:3, :3] @ DOWN
    return T


def bar_world(height: float = 0.05, x0: float = 0.0) -> SimWorld:
    """A 40 mm wide, ``height`` tall bar along y on the table, its left edge at x = ``x0``."""
    outline = np.array([[x0, -0.2], [x0 + 0.04, -0.2], [x0 + 0.04, 0.2], [x0, 0.2]])
    return SimWorld([weldment_workpiece([outline], [height], [])])


def test_flat_matte_surface_has_the_papers_accuracy():
    spec = preset("ild1402-200")
    model = LaserModel(spec, SimWorld([]).meshes(), seed=1)
    T = np.tile(pose(0.3, 0.3, 0.16), (20000, 1, 1))
    d = model.measure(T)
    truth = LaserModel(spec.with_overrides(accuracy=0.0), SimWorld([]).meshes()).measure(T[:1])[0]
    assert truth == pytest.approx(0.16, abs=2e-4)  # (the simulated table top is 0.1 mm below z = 0)
    assert np.isfinite(d).all()
    assert np.mean(d) == pytest.approx(truth, abs=1e-5)
    assert np.std(d) == pytest.approx(0.288e-3, rel=0.05)  # §II: 0.288 mm on a flat, matte surface


def test_out_of_range_is_no_reading_never_zero():
    spec = preset("ild1402-200")  # 60 .. 260 mm
    model = LaserModel(spec, SimWorld([]).meshes(), seed=1)
    far = model.measure(np.tile(pose(0.3, 0.3, 0.40), (100, 1, 1)))
    near = model.measure(np.tile(pose(0.3, 0.3, 0.03), (100, 1, 1)))
    assert np.isnan(far).all() and np.isnan(near).all()
    with pytest.raises(DataError, match="ild1402-100"):
        preset("ild9999")


def test_an_edge_is_sheared_and_drops_out_only_where_the_spot_straddles_it():
    spec = preset("ild1402-200").with_overrides(accuracy=1e-9, edge_dropout=0.5)
    model = LaserModel(spec, bar_world(0.05).meshes(), seed=3)
    # across the bar's left edge (x = 0) along x, baseline along y (parallel to the edge: no shadow)
    xs = np.linspace(-0.01, 0.01, 2001)
    d = model.measure(np.stack([pose(x, 0.0, 0.20, yaw=np.pi / 2) for x in xs]))
    z = 0.20 - d
    r = spec.spot_diameter / 2
    far = np.abs(xs) > r + 1e-4
    assert np.isfinite(z[far]).all()
    assert np.allclose(z[far & (xs < 0)], 0.0, atol=2e-4) and np.allclose(z[far & (xs > 0)], 0.05, atol=2e-4)
    near = ~far
    mixed = np.isfinite(z[near]) & (z[near] > 1e-3) & (z[near] < 0.049)
    assert 0.3 < np.isnan(z[near]).mean() < 0.7  # dropouts at the edge, about edge_dropout of them
    assert mixed.mean() > 0.3  # the rest read between top and bottom: the true edge is unreadable


def test_triangulation_shadow_hides_the_table_behind_an_edge_across_the_baseline():
    spec = preset("ild1402-200").with_overrides(accuracy=1e-9, edge_dropout=0.0)
    model = LaserModel(spec, bar_world(0.05, x0=0.0).meshes(), seed=3)
    # baseline along +x: the receiver looks past the bar's left wall from the table left of it
    xs = np.linspace(-0.04, -0.001, 400)
    d = model.measure(np.stack([pose(x, 0.0, 0.20) for x in xs]))
    shadow = xs[np.isnan(d)]
    assert len(shadow) > 0
    # the lit point at x is hidden when its line of sight to the receiver passes below the wall's top
    width = 0.05 * spec.baseline / 0.20  # similar triangles: wall 50 mm, receiver 200 mm above the table
    assert -shadow.min() == pytest.approx(width, rel=0.15)
    # the same edge scanned with the baseline along it has no shadow
    d2 = model.measure(np.stack([pose(x, 0.0, 0.20, yaw=np.pi / 2) for x in xs]))
    assert np.isfinite(d2[xs < -spec.spot_diameter]).all()


def test_robot_sensor_coupling_is_bounded_and_smooth():
    c = CouplingError(0.4e-3, seed=5)
    t = np.arange(0, 200.0, 1 / 1500)
    e = c(t)
    n = np.linalg.norm(e, axis=1)
    assert n.max() <= 0.4e-3 + 1e-12
    assert 0.1e-3 < np.sqrt(np.mean(n**2)) < 0.3e-3
    assert np.abs(np.diff(e, axis=0)).max() < 1e-5  # low-frequency: < 10 um between samples at 1.5 kHz
    assert np.allclose(CouplingError(0.0)(t[:10]), 0.0)


@pytest.fixture
def cell():
    model = get_model("abb-irb2600")
    world = bar_world(0.05, x0=1.0)
    gate = SafetyGate(SafetyLimits(workspace_min=[0.2, -1, -0.05], workspace_max=[1.8, 1, 1.5]), model=model)
    robot = SimRobot(
        model,
        world,
        name="robot",
        gate=gate,
        motion=RobotMotionSettings(tcp_xyz=(0, 0, 0.35)),
        q_start=model.ik(pose(0.95, 0.0, 0.50), model.home),
    )
    laser = SimDisplacementSensor(
        world,
        T_from_rpy([0, 0, 0], [0.0, 0.0, 0.30]),
        parent="robot.flange",
        spec=PRESETS["ild1402-200"],
        latency=0.004,
        seed=7,
    )
    with robot, laser:
        yield robot, laser


def test_timed_trajectory_follows_the_trapezoid_of_the_motion_time(cell):
    robot, _ = cell
    T0 = robot.state().T_base_flange
    t0 = robot.world.clock.t
    T1 = T0.copy()
    T1[0, 3] += 0.2
    robot._move_linear(T1, 0.1, 0.5)
    dur = robot.world.clock.t - t0
    assert dur == pytest.approx(0.2 / 0.1 + 0.1 / 0.5)
    P = robot.timed.poses(np.array([t0, t0 + 0.1, t0 + dur / 2, t0 + dur, t0 + dur + 1]))
    x = P[:, 0, 3] - T0[0, 3]
    assert x[0] == pytest.approx(0.0, abs=1e-9) and x[3] == pytest.approx(0.2, abs=1e-7)
    assert x[1] == pytest.approx(0.5 * 0.5 * 0.1**2, abs=1e-7)  # still accelerating
    assert x[2] == pytest.approx(0.1, abs=1e-6) and x[4] == pytest.approx(0.2, abs=1e-7)


def test_stream_samples_at_the_sensor_rate_along_the_motion(cell):
    robot, laser = cell
    laser.start_stream()
    t0 = robot.world.clock.t
    T = robot.state().T_base_tcp
    T[0, 3] += 0.10  # the sensor crosses the bar's left edge at x = 1.0
    robot.move_linear(T, speed=0.1, accel=1.0)
    dur = robot.world.clock.t - t0
    got = []
    deadline = time.monotonic() + 5
    while (not got or got[-1].stamp < robot.world.clock.t) and time.monotonic() < deadline:
        got += laser.read_available(timeout=0.05)
    got += laser.stop_stream()
    stamps = np.array([r.stamp for r in got])
    assert len(got) == pytest.approx(dur * 1500, abs=2)
    assert np.allclose(np.diff(stamps), 1 / 1500)
    assert stamps[0] == pytest.approx(t0 + 0.004, abs=1 / 1500)  # stamped latency late
    d = np.array([np.nan if r.distance is None else r.distance for r in got])
    assert np.nanmax(d) - np.nanmin(d) > 0.045  # it saw the 50 mm step
    assert all(r.distance is None or r.distance > 0 for r in got)  # gaps are None, never zero
