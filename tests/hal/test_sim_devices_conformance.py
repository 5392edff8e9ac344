"""The simulated cell's devices pass the same conformance suites as real adapters.

Each ``device`` fixture builds the device with its plugin factory (plugins/sim/factories.py) from its
settings and a :class:`~weldcell.sdk.jobs.DeviceContext`, in a world with one workpiece, as a run does.
"""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.plugins.sim import factories
from weldcell.plugins.sim import settings as sim_settings
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.jobs import DeviceContext
from weldcell.sdk.profile import LoadedProfile, Mount, Profile
from weldcell.testing.conformance import (
    DepthCameraConformance,
    DisplacementSensorConformance,
    GestureSensorConformance,
    GnssConformance,
    ImuConformance,
    LaserProjectorConformance,
    RobotConformance,
)

LOOK_DOWN = (np.pi, 0.0, 0.0)  # optical z pointing at the table


def make_ctx(tmp_path, role: str, mount: Mount | None = None, shared: dict | None = None) -> DeviceContext:
    profile = Profile.model_validate(
        {
            "name": "conformance",
            "job": {"name": "none"},
            "sim": {"workpieces": [{"kind": "fillet-t", "params": {"length": 0.2}, "xyz": (0.45, 0.0, 0.0)}]},
        }
    )
    loaded = LoadedProfile(profile=profile, path=tmp_path / "conformance.toml")
    return DeviceContext(
        role=role,
        mount=mount or Mount(),
        profile=loaded,
        shared={} if shared is None else shared,
        devices={},
        dry_run=False,
        safety=SafetyLimits(),
        seed=11,
    )


def set_attr(name: str, value):
    def _break(dev) -> None:
        setattr(dev, name, value)

    return _break


class TestSimRobot(RobotConformance):
    @pytest.fixture
    def device(self, tmp_path):
        s = sim_settings.SimRobotSettings(model="ur5", start_xyz=(0.45, 0.0, 0.35), tcp_xyz=(0, 0, "150 mm"))
        return factories.robot(s, make_ctx(tmp_path, "robot"))

    @pytest.fixture
    def break_device(self):
        return set_attr("connected", False)

    def test_world_frames_follow_the_robot(self, device):
        world = device.world
        with device as d:
            np.testing.assert_allclose(world.T_world("robot.flange"), d.state().T_base_flange, atol=1e-12)
            target = d.state().T_base_tcp.copy()
            target[0, 3] += 0.02
            d.move_linear(target)
            np.testing.assert_allclose(world.T_world("robot.flange")[:3, 3], d.state().T_base_flange[:3, 3])
            assert world.clock.t > 0  # the simulated motion took simulated time


class TestSimDepthCamera(DepthCameraConformance):
    @pytest.fixture
    def device(self, tmp_path):
        s = sim_settings.SimCameraSettings(preset="realsense-d415", decimation=4)
        # 0.6 m above the table: a D415 at full resolution sees nothing nearer than about 0.44 m
        mount = Mount(parent="world", xyz=(0.45, 0.0, 0.6), rpy=LOOK_DOWN)
        return factories.camera(s, make_ctx(tmp_path, "camera", mount))

    @pytest.fixture
    def break_device(self):
        return set_attr("delivering", False)

    def test_sees_the_workpiece_at_the_right_distance(self, device):
        with device as d:
            f = d.capture()
            depth = f.depth[f.depth > 0]
            # the table is 0.6 m below the camera; the top of the fillet-T web (0.11 m high) at 0.49 m
            assert np.median(depth) == pytest.approx(0.6, abs=0.03)
            assert np.sum(np.abs(depth - 0.49) < 0.01) > 50
            assert f.intrinsics.width == d.intrinsics().width


class TestSimGestureSensor(GestureSensorConformance):
    @pytest.fixture
    def device(self, tmp_path):
        return factories.gesture(
            sim_settings.SimGestureSettings(script="survey"), make_ctx(tmp_path, "gesture")
        )

    @pytest.fixture
    def break_device(self):
        return set_attr("connected", False)


class TestSimDisplacementSensor(DisplacementSensorConformance):
    @pytest.fixture
    def device(self, tmp_path):
        mount = Mount(parent="world", xyz=(0.2, 0.3, 0.1), rpy=LOOK_DOWN)  # 10 cm above the bare table
        return factories.displacement(
            sim_settings.SimDisplacementSettings(noise=0.0), make_ctx(tmp_path, "laser", mount)
        )

    def test_measures_the_distance_to_the_table(self, device):
        with device as d:
            assert d.read().distance == pytest.approx(0.1, abs=2e-4)


class TestSimProjector(LaserProjectorConformance):
    @pytest.fixture
    def device(self, tmp_path):
        return factories.projector(None, make_ctx(tmp_path, "projector"))

    def test_records_what_it_draws(self, device):
        with device as d:
            seg = np.array([[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], [[0.1, 0.0, 0.0], [0.1, 0.1, 0.0]]])
            p = d.project(seg, "outline")
            assert p.label == "outline" and p.segments.shape == (2, 2, 3)
            assert d.drawn[0][0] == "outline"
            d.clear()
            assert d.drawn == []


class TestSimImu(ImuConformance):
    @pytest.fixture
    def device(self, tmp_path):
        return factories.imu(sim_settings.SimImuSettings(), make_ctx(tmp_path, "imu"))

    def test_measures_gravity(self, device):
        with device as d:
            acc = np.mean([d.read().accel for _ in range(50)], axis=0)
            np.testing.assert_allclose(acc, [0.0, 0.0, 9.80665], atol=0.02)


class TestSimGnss(GnssConformance):
    @pytest.fixture
    def device(self, tmp_path):
        return factories.gnss(
            sim_settings.SimGnssSettings(latitude=45.0, longitude=7.0, altitude=200.0),
            make_ctx(tmp_path, "gnss"),
        )

    def test_fix_is_at_the_world_origin(self, device):
        with device as d:
            fix = d.read()
            assert fix.latitude == pytest.approx(45.0, abs=1e-5) and fix.longitude == pytest.approx(
                7.0, abs=1e-5
            )
            assert fix.altitude == pytest.approx(200.0, abs=0.2)
