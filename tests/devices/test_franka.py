"""robot.franka against a fake franky.Robot (franky's own value classes, a kinematic Panda behind it)."""

from __future__ import annotations

import re

import franky
import numpy as np
import pytest
from peers_cell2_franky import FakeFrankyRobot, FrankaWorld
from weldcell.hal.kinematics import get_model
from weldcell.hal.lifecycle import State
from weldcell.hal.safety import SafetyGate
from weldcell.plugins import franka as franka_plugin
from weldcell.plugins.franka.adapter import FrankaRobot, probe_franka
from weldcell.plugins.franka.settings import FrankaSettings
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import DeviceError, SafetyError
from weldcell.sdk.geometry import T_from_rpy, invert
from weldcell.testing.conformance import RobotConformance


def _doc_params(fn) -> list[str]:
    """Parameter names of the first overload in a pybind11 docstring."""
    line = next(ln for ln in fn.__doc__.splitlines() if "(" in ln and "self" in ln)
    inner = line[line.index("(") + 1 : line.rindex(")")]
    return [p.split(":")[0].strip() for p in re.split(r",\s*(?![^\[]*\])", inner) if p.strip()][1:]


def test_fake_mirrors_frankys_robot_signatures():
    import inspect

    real = franky._franky._RobotInternal  # noqa: SLF001
    for name in ("move", "join_motion", "stop", "recover_from_errors"):
        want = _doc_params(getattr(real, name))
        got = [p for p in inspect.signature(getattr(FakeFrankyRobot, name)).parameters if p != "self"]
        assert got == want, f"{name}: fake {got} vs franky {want}"
    want_init = _doc_params(real.__init__)[:4]
    got_init = list(inspect.signature(FakeFrankyRobot.__init__).parameters)[1:5]
    assert got_init == want_init
    for prop in (
        "state",
        "has_errors",
        "current_joint_state",
        "current_cartesian_state",
        "relative_dynamics_factor",
        "fci_hostname",
    ):
        assert hasattr(real, prop) and isinstance(getattr(FakeFrankyRobot, prop), property)


@pytest.fixture
def world():
    return FrankaWorld()


def _robot(world, **kw) -> FrankaRobot:
    s = FrankaSettings(host="172.16.0.2", **kw)
    return FrankaRobot(
        s,
        name="franka",
        gate=SafetyGate(SafetyLimits(), model=get_model("franka-panda")),
        robot_factory=world.robot,
    )


class TestFrankaConformance(RobotConformance):
    @pytest.fixture
    def device(self, world):
        return _robot(world)

    @pytest.fixture
    def break_device(self, world):
        return lambda dev: world.reflex("cartesian_reflex")


def test_flange_pose_maps_through_the_end_effector_frame(world):
    with _robot(world) as r:
        st = r.state()
        np.testing.assert_allclose(st.T_base_flange, world.flange(), atol=1e-12)
        # franky reports O_T_EE with the hand's 10.34 cm NE offset; weldcell reports the flange
        O_T_EE = np.asarray(FakeFrankyRobot("x", world=world).state.O_T_EE.matrix)
        assert np.linalg.norm(O_T_EE[:3, 3] - st.T_base_flange[:3, 3]) == pytest.approx(0.1034, abs=1e-6)
        target = st.T_base_tcp @ T_from_rpy([0.0, 0.0, 0.1], [0.02, -0.01, 0.03])
        r.move_linear(target, speed=0.1, accel=0.5)
        m = world.motions[-1]
        assert isinstance(m, franky.CartesianMotion)
        sent = np.asarray(m.target.pose.end_effector_pose.matrix)
        np.testing.assert_allclose(sent, target @ world.F_T_EE, atol=1e-9)
        np.testing.assert_allclose(r.state().T_base_flange, target, atol=1e-6)
        assert m.relative_dynamics_factor.velocity == pytest.approx(0.1 / 1.7)
        assert m.relative_dynamics_factor.acceleration == pytest.approx(0.5 / 13.0)


def test_tcp_offset_path_joint_and_servo(world):
    with _robot(world, tcp_xyz=(0.0, 0.0, 0.2)) as r:
        st = r.state()
        path = np.stack([st.T_base_tcp.copy() for _ in range(3)])
        path[:, 0, 3] += [0.01, 0.02, 0.03]
        r.follow_path(path, speed=0.05)
        m = world.motions[-1]
        assert isinstance(m, franky.CartesianWaypointMotion) and len(m.waypoints) == 3
        np.testing.assert_allclose(r.state().T_base_tcp, path[-1], atol=1e-6)
        q = r.state().q + np.array([0.05, 0, 0, 0, 0, 0, 0.05])
        r.move_joint(q, speed=0.3)
        assert isinstance(world.motions[-1], franky.JointMotion)
        np.testing.assert_allclose(r.state().q, q, atol=1e-12)
        # servo: a pure TCP translation; franky gets the EE-origin twist (adds w x r for rotations)
        p0 = r.state().T_base_tcp[:3, 3].copy()
        r.speed_linear(np.array([0.02, 0.0, 0.0, 0.0, 0.0, 0.0]), duration=0.1)
        vm = world.motions[-1]
        assert isinstance(vm, franky.CartesianVelocityMotion)
        assert vm.duration.to_sec() == pytest.approx(0.1)
        np.testing.assert_allclose(r.state().T_base_tcp[:3, 3] - p0, [0.002, 0, 0], atol=1e-6)
        r.speed_linear(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.2]), duration=0.05)
        st = r.state()
        tw = world.motions[-1].target.end_effector_twist
        r_ee = (st.T_base_flange @ world.F_T_EE)[:3, 3] - st.T_base_flange[:3, 3]
        # the flange (TCP-converted) twist moved to the EE origin: v_EE = v_F + w x r_F->EE
        assert np.linalg.norm(np.asarray(tw.angular) - [0, 0, 0.2]) < 1e-9
        assert np.linalg.norm(tw.linear) > 0 and abs(np.dot(tw.linear, r_ee)) < 1e-9


def test_gate_refuses_unsafe_commands_before_franky(world):
    with _robot(world) as r:
        n0 = len(world.motions)
        st = r.state()
        near = st.T_base_tcp.copy()
        near[2, 3] += 0.01
        with pytest.raises(SafetyError, match="TCP speed"):
            r.move_linear(near, speed=0.5)  # over the cell's 0.25 m/s cap
        bad_q = st.q.copy()
        bad_q[3] = 0.5  # joint 4 of the Panda must stay negative
        with pytest.raises(SafetyError, match="joint 4"):
            r.move_joint(bad_q)
        with pytest.raises(SafetyError):
            r.speed_linear(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 5.0]))
        assert len(world.motions) == n0, "a refused command reached franky"


def test_reflex_error_state_and_recover_from_errors(world):
    r = _robot(world)
    with r:
        world.reflex("cartesian_reflex_flag")
        with pytest.raises(DeviceError, match="reflex"):
            r.state()
        assert r.lifecycle is State.ERROR and "reflex" in r.health().message
        with pytest.raises(DeviceError):
            r.move_linear(np.eye(4))  # not active: refused without touching the robot
        world.fail_recovery = True
        with pytest.raises(DeviceError, match="recover"):
            r.recover()
        assert r.lifecycle is State.ERROR
        world.fail_recovery = False
        r.recover()
        assert world.recover_calls == 2 and world.errors == ""
        assert r.lifecycle is State.UNCONFIGURED
        r.configure()
        r.activate()
        assert np.all(np.isfinite(r.state().q))
        assert len(world.connections) == 1, "recovery keeps the FCI connection"


def test_reflex_during_a_motion_faults(world, monkeypatch):
    with _robot(world) as r:
        start = r.state().T_base_tcp
        goal = start.copy()
        goal[2, 3] += 0.01
        orig = FakeFrankyRobot.move

        def collide(self, motion, *a, **k):
            world.reflex("cartesian_reflex")
            return orig(self, motion, *a, **k)

        monkeypatch.setattr(FakeFrankyRobot, "move", collide)
        with pytest.raises(DeviceError, match="ControlException"):
            r.move_linear(goal)
        assert r.lifecycle is State.ERROR


def test_connection_refused_and_probe(world, weldcell_pm):
    world.reachable = False
    r = _robot(world)
    with pytest.raises(DeviceError, match="FCI"):
        r.configure()
    with pytest.raises(DeviceError, match="1337"):
        probe_franka(FrankaSettings(host="127.0.0.1"), timeout=0.2)
    weldcell_pm.register(franka_plugin, "franka")
    spec = weldcell_pm.registry.get("device", "robot.franka")
    assert spec.kind == "robot" and spec.settings is FrankaSettings and spec.requires == {"franky": "franka"}


def test_factory_builds_a_gated_robot():
    from types import SimpleNamespace

    from weldcell.plugins.franka.adapter import make_franka

    ctx = SimpleNamespace(role="arm", safety=SafetyLimits(max_linear_speed=0.1), dry_run=True)
    r = make_franka(FrankaSettings(), ctx)
    assert r.name == "arm" and r.dry_run and r.gate.model.name == "franka-panda"
    assert r.gate.limits.max_linear_speed == 0.1
    assert invert(np.eye(4)).shape == (4, 4)
