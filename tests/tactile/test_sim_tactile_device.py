"""The simulated SRM tool's in-finger camera (``tactile.sim``): conformance, contact physics through real
rendered images, fault injection, mounting errors and registration."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import weldcell.plugins.tactile as tactile_plugin
from weldcell.hal.kinematics import get_model
from weldcell.hal.sim import WORLD_KEY
from weldcell.hal.sim.devices import SimRobot
from weldcell.hal.sim.workpieces import make_workpiece
from weldcell.hal.sim.world import SimWorld
from weldcell.plugins.tactile.marker import CameraIntrinsics, MarkerDisplacementEstimator, MarkerLost
from weldcell.plugins.tactile.sim_device import SimTactileCamera, SimTactileSettings, factory
from weldcell.plugins.tactile.srm_model import tip_deflection_from_tag
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.geometry import T_from_rpy, frame_from_axes, invert, make_T
from weldcell.testing.conformance import TactileCameraConformance

TIP = 0.18  # SRM tip offset from the flange (m)


def _cell(**settings):
    """A UR10e and a fillet T joint whose 'fillet-2' seam runs along +y at x = 0.805, wall on its -x side."""
    wp = make_workpiece("fillet-t", length=0.16, base_width=0.12, web_height=0.04, thickness=0.01)
    world = SimWorld([wp.placed(T_from_rpy(np.radians([0, 0, 90]), [0.80, 0.0, 0.25]))], seed=0)
    robot = SimRobot(get_model("ur10e"), world, flange=None)
    robot.configure()
    robot.activate()
    cam = SimTactileCamera(
        world, "robot", make_T(t=[0, 0, TIP]), SimTactileSettings(supersample=1, **settings)
    )
    return world, robot, cam


def _put_tcp(robot: SimRobot, xyz) -> None:
    """Place the SRM tip (TCP) at xyz, tool z down, travel +y (wall on the left)."""
    T_tcp = frame_from_axes([0, 1, 0], [0, 0, -1], xyz)
    robot.q = robot.model.ik(T_tcp @ invert(make_T(t=[0, 0, TIP])), robot.q)


WALL_X = 0.805  # the web's face, where the fillet-2 seam lies
SEAM_Z = 0.26


class TestSimTactileConformance(TactileCameraConformance):
    @pytest.fixture
    def device(self):
        return _cell()[2]

    @pytest.fixture
    def break_device(self):
        def _break(dev):
            dev.connected = False

        return _break


def _estimator(cam: SimTactileCamera) -> MarkerDisplacementEstimator:
    k = cam.intrinsics
    return MarkerDisplacementEstimator(
        CameraIntrinsics(k.K, np.zeros(5), k.width, k.height),
        cam.s.marker_size,
        cam.s.marker_id,
        filter="none",
    )


def test_pressing_the_wall_shows_in_the_rendered_tag_as_the_true_deflection():
    world, robot, cam = _cell()
    with cam:
        _put_tcp(robot, [WALL_X + 0.010, 0.0, SEAM_Z + 0.0035])  # free: 10 mm from the wall
        est = _estimator(cam)
        est.capture_rest([cam.capture().image for _ in range(3)])
        assert not cam.last_contact.in_contact
        # TCP 1 mm inside the tip-to-wall distance (tip radius 2 mm): the finger bends by ~1 mm, away (+x)
        _put_tcp(robot, [WALL_X + 0.001, 0.0, SEAM_Z + 0.0035])
        r = est.update(cam.capture().image, 1.0)
        c = cam.last_contact
        assert c.in_contact and c.penetration == pytest.approx(0.001, abs=1e-6)
        u_meas = tip_deflection_from_tag(r.displacement, cam.params)
        assert np.linalg.norm(u_meas - c.deflection_tool) < 3e-5  # 30 µm through real images + PnP
        # tool frame: x = +y (travel), z down, y = z × x = +x (world): pushed out of the wall = +tool y
        assert u_meas[1] == pytest.approx(0.001, abs=5e-5)
        T_tip = world.T_world("robot.flange") @ make_T(t=[0, 0, TIP])
        assert c.tip_position[0] == pytest.approx(T_tip[0, 3] + 0.001, abs=1e-6)


def test_friction_from_the_robot_motion_bends_the_finger_backwards():
    world, robot, cam = _cell()
    with cam:
        _put_tcp(robot, [WALL_X + 0.001, 0.0, SEAM_Z + 0.0035])
        cam.capture()
        robot.speed_linear(np.array([0.0, 0.01, 0.0, 0.0, 0.0, 0.0]), duration=0.1)  # slide along +y
        cam.capture()
        u = cam.last_contact.deflection_tool
        assert u[0] < -1e-5  # the tip lags behind the travel (tool x = +y): friction
        assert world.clock.t == pytest.approx(0.1)


def test_images_are_stamped_with_the_simulated_clock():
    world, robot, cam = _cell()
    with cam:
        a = cam.capture()
        robot.speed_linear(np.zeros(6) + [0, 0.001, 0, 0, 0, 0], duration=0.2)
        b = cam.capture()
        assert b.stamp - a.stamp == pytest.approx(0.2)
        assert a.image.shape == (480, 640) and a.image.dtype == np.uint8
        assert a.intrinsics.fx == 420.0 and a.frame == cam.name


def test_lost_marker_injection_gives_marker_lost_not_zero_displacement():
    _, robot, cam = _cell(lose_marker_after=3)
    with cam:
        est = _estimator(cam)
        est.capture_rest([cam.capture().image for _ in range(3)])
        r = est.update(cam.capture().image, 0.1)
        assert isinstance(r, MarkerLost) and "no marker" in r.reason


def test_mounting_off_a_flange_or_without_the_robot_is_a_clear_error():
    world = SimWorld([], seed=0)
    ctx = SimpleNamespace(
        mount=SimpleNamespace(parent="world"),
        role="tactile",
        seed=0,
        shared={WORLD_KEY: world},
        T_parent_device=np.eye(4),
    )
    with pytest.raises(DeviceError) as e:
        factory(SimTactileSettings(), ctx)
    assert "flange" in e.value.message and "robot.flange" in e.value.fix
    cam = SimTactileCamera(world, "robot", np.eye(4))
    with pytest.raises(DeviceError) as e2:
        cam.configure()
    assert "no robot 'robot'" in e2.value.message and "[devices.robot]" in e2.value.fix


def test_registration(weldcell_pm):
    weldcell_pm.register(tactile_plugin, "tactile")
    reg = weldcell_pm.registry
    dev = reg.get("device", "tactile.sim")
    assert dev.kind == "tactile_camera" and dev.settings is SimTactileSettings and dev.simulated
    assert reg.get("stage", "tactile.srm-servo").kind == "tactile-servo"
    assert {r.role for r in reg.get("job", "tactile-track").devices} == {"robot", "tactile", "camera"}
    assert reg.get("job", "calibrate-and-track") is not None
