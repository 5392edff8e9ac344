"""The UR adapter (robot.ur-rtde): the real ur-rtde RTDEReceiveInterface and DashboardClient against
loopback RTDE/Dashboard peers in a child process, and a kinematic fake of RTDEControlInterface."""

from __future__ import annotations

import socket
import time

import numpy as np
import pytest

pytest.importorskip("rtde_receive", reason="ur-rtde is not installed (pip install 'weldcell[ur]')")

import rtde_control  # noqa: E402
from peers_rtde import FakeRTDEControlInterface, PeerProcess  # noqa: E402
from weldcell.hal.kinematics import get_model  # noqa: E402
from weldcell.hal.lifecycle import State  # noqa: E402
from weldcell.hal.safety import SafetyGate  # noqa: E402
from weldcell.plugins import ur as ur_plugin  # noqa: E402
from weldcell.plugins.ur.adapter import URRobot, path_blends  # noqa: E402
from weldcell.plugins.ur.rtde_client import rtde_handshake  # noqa: E402
from weldcell.plugins.ur.settings import URSettings  # noqa: E402
from weldcell.sdk.cell import SafetyLimits  # noqa: E402
from weldcell.sdk.errors import DeviceError, SafetyError  # noqa: E402
from weldcell.sdk.geometry import T_from_rpy, T_to_ur_pose, invert  # noqa: E402
from weldcell.testing.conformance import RobotConformance  # noqa: E402

UR5 = get_model("ur5")


@pytest.fixture(scope="module")
def peer():
    p = PeerProcess("ur5")
    yield p
    p.close()


@pytest.fixture
def cell(peer, monkeypatch):
    """The peer reset to home, with the fake control interface patched into rtde_control."""
    peer.call("set_q", UR5.home.tolist())
    peer.call("protective_stop", False)
    peer.call("freeze", False)
    peer.call("accept_clients", True)
    monkeypatch.setattr(rtde_control, "RTDEControlInterface", FakeRTDEControlInterface)
    monkeypatch.setattr(FakeRTDEControlInterface, "peers", {peer.host: peer})
    monkeypatch.setattr(FakeRTDEControlInterface, "calls", [])
    return peer


def make_robot(host: str, dry_run: bool = False, **kw) -> URRobot:
    s = URSettings(host=host, frequency=250, state_timeout=0.3, connect_timeout=1.0, **kw)
    return URRobot(s, name="arm", gate=SafetyGate(SafetyLimits(), model=UR5), dry_run=dry_run)


def wait_disconnected(dev: URRobot) -> None:
    deadline = time.time() + 2
    while dev._r.isConnected() and time.time() < deadline:
        time.sleep(0.01)


class TestURConformance(RobotConformance):
    @pytest.fixture
    def device(self, cell):
        return make_robot(cell.host)

    @pytest.fixture
    def break_device(self, cell):
        def brk(dev):
            cell.call("drop_clients")
            wait_disconnected(dev)

        return brk


def test_state_streams_over_real_rtde(cell):
    q = UR5.home + np.array([0.1, -0.05, 0.08, 0.02, 0.1, -0.3])
    cell.call("set_q", q.tolist())
    with make_robot(cell.host, tcp_xyz=(0.0, 0.0, 0.2)) as arm:
        st = arm.state()
        np.testing.assert_allclose(st.q, q, atol=1e-12)
        np.testing.assert_allclose(st.T_base_flange, UR5.fk(q), atol=1e-9)
        np.testing.assert_allclose(st.T_base_tcp[:3, 3], (UR5.fk(q) @ [0, 0, 0.2, 1])[:3], atol=1e-9)
        assert not st.protective_stop and not st.moving and st.qd is not None
    assert ("setTcp", [0.0] * 6) in FakeRTDEControlInterface.calls  # controller TCP = flange
    setup = cell.call("setups")[-1]
    assert "actual_q" in setup and "actual_TCP_pose" in setup and "safety_mode" in setup


def test_linear_move_with_tool_offset_sends_the_flange_pose(cell):
    with make_robot(cell.host, tcp_xyz=(0.0, 0.0, 0.15), tcp_rpy=(0.0, 0.2, 0.0)) as arm:
        start = arm.state().T_base_tcp
        target = start.copy()
        target[:3, 3] += [0.03, -0.02, 0.04]
        arm.move_linear(target, speed=0.1, accel=0.5)
        cmd = [c for c in FakeRTDEControlInterface.calls if c[0] == "moveL"][-1]
        np.testing.assert_allclose(cmd[1], T_to_ur_pose(target @ invert(arm.T_flange_tcp)), atol=1e-9)
        assert cmd[2:] == (0.1, 0.5, False)  # blocking move
        got = arm.state().T_base_tcp
        np.testing.assert_allclose(got, target, atol=1e-6)


def test_follow_path_sends_one_movel_path_with_safe_blends(cell):
    with make_robot(cell.host) as arm:
        T0 = arm.state().T_base_tcp
        offs = [[0.02, 0, 0], [0.04, 0.0, 0.0], [0.04, 0.004, 0.0], [0.04, 0.03, 0.01]]
        poses = np.stack([T0 @ T_from_rpy((0, 0, 0), o) for o in offs])
        poses = np.stack(
            [
                np.block([[T0[:3, :3], (T0[:3, 3] + np.array(o))[:, None]], [np.zeros((1, 3)), 1]])
                for o in offs
            ]
        )
        arm.follow_path(poses, speed=0.05, accel=0.5, blend=0.005)
        (cmd,) = [c for c in FakeRTDEControlInterface.calls if c[0] == "moveL_path"]
        path = np.array(cmd[1])
        assert path.shape == (4, 9)
        np.testing.assert_allclose(path[:, 6:8], [[0.05, 0.5]] * 4)
        np.testing.assert_allclose(path[:, 8], [0.005, 0.45 * 0.004, 0.45 * 0.004, 0.0])
        np.testing.assert_allclose(arm.state().T_base_tcp, poses[-1], atol=1e-6)


def test_joint_move_and_speed_servo(cell):
    with make_robot(cell.host) as arm:
        q = UR5.home + np.array([0.05, 0.05, -0.05, 0.0, 0.1, 0.2])
        arm.move_joint(q, speed=0.5, accel=1.0)
        np.testing.assert_allclose(arm.state().q, q, atol=1e-12)
        p0 = arm.state().T_base_tcp[:3, 3]
        arm.speed_linear(np.array([0.0, 0.02, -0.01, 0, 0, 0]), accel=0.5, duration=0.5)
        deadline = time.monotonic() + 5.0  # the peer integrates the command in its own process
        while time.monotonic() < deadline and np.allclose(arm.state().T_base_tcp[:3, 3], p0):
            time.sleep(0.01)
        np.testing.assert_allclose(arm.state().T_base_tcp[:3, 3] - p0, [0.0, 0.01, -0.005], atol=1e-6)
        arm.stop()
        assert FakeRTDEControlInterface.calls[-1][0] == "stopL"


def test_protective_stop_enters_error_and_recover_unlocks_via_dashboard(cell):
    arm = make_robot(cell.host)
    arm.configure()
    arm.activate()
    arm.state()
    cell.call("protective_stop", True)
    time.sleep(0.05)
    with pytest.raises(DeviceError) as e:
        arm.state()
    assert "PROTECTIVE_STOP" in e.value.message
    assert arm.lifecycle is State.ERROR and "PROTECTIVE_STOP" in arm.health().message
    with pytest.raises(DeviceError):  # no motion while in ERROR
        arm.move_joint(UR5.home)
    arm.recover()
    assert cell.call("dashboard_commands")[-2:] == ["close safety popup", "unlock protective stop"]
    arm.configure()
    arm.activate()
    assert not arm.state().protective_stop
    arm.close()


def test_motion_refused_by_a_stop_during_the_move_is_an_error(cell, monkeypatch):
    with make_robot(cell.host) as arm:
        target = arm.state().T_base_tcp.copy()
        target[2, 3] += 0.01
        orig = FakeRTDEControlInterface.moveL

        def stop_then_move(self, *a, **k):
            cell.call("protective_stop", True)
            time.sleep(0.05)
            return orig(self, *a, **k)

        monkeypatch.setattr(FakeRTDEControlInterface, "moveL", stop_then_move)
        with pytest.raises(DeviceError) as e:
            arm.move_linear(target)
        assert "PROTECTIVE_STOP" in e.value.message and arm.lifecycle is State.ERROR


def test_a_silent_stream_is_a_fault(cell):
    with make_robot(cell.host) as arm:
        arm.state()
        cell.call("freeze", True)
        with pytest.raises(DeviceError) as e:
            for _ in range(100):
                arm.state()
                time.sleep(0.01)
        assert "no new RTDE data" in e.value.message and arm.lifecycle is State.ERROR


def test_dry_run_never_opens_the_control_interface(cell):
    with make_robot(cell.host, dry_run=True) as arm:
        st = arm.state()
        target = st.T_base_tcp.copy()
        target[2, 3] += 0.02
        arm.move_linear(target)
        assert [e.command for e in arm.dry_run_log] == ["move_linear"]
        np.testing.assert_allclose(arm.state().q, st.q)
        with pytest.raises(SafetyError):  # the gate still runs in dry-run mode
            arm.move_linear(target @ T_from_rpy((0, 0, 0), (3.0, 0, 0)))
    assert not [c for c in FakeRTDEControlInterface.calls if c[0] == "connect"]


def test_unreachable_controller_is_a_device_error(cell):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    free_host = "127.0.0.1"  # nothing listens on 127.0.0.1:30004 in these tests
    s.close()
    arm = URRobot(URSettings(host=free_host), name="arm")
    with pytest.raises(DeviceError) as e:
        arm.configure()
    assert free_host in e.value.message and arm.lifecycle is State.ERROR


def test_probe_reads_the_controller_version(cell):
    assert rtde_handshake(cell.host, timeout=1.0) == (5, 11, 1, 108)
    msg = ur_plugin.probe(URSettings(host=cell.host))
    assert "5.11.1.108" in msg and cell.host in msg
    with pytest.raises(DeviceError) as e:
        ur_plugin.probe(URSettings(host="127.0.0.1", connect_timeout=0.3))
    assert "30004" in e.value.message and e.value.fix


def test_registration_and_factory(weldcell_pm, cell):
    from weldcell.sdk.cell import SafetyLimits

    weldcell_pm.register(ur_plugin, "ur")
    spec = weldcell_pm.registry.get("device", "robot.ur-rtde")
    assert spec.kind == "robot" and spec.settings is URSettings and spec.probe is ur_plugin.probe

    class Ctx:
        role, dry_run, safety = "robot", False, SafetyLimits()

    dev = spec.factory(URSettings(host=cell.host, model="ur5"), Ctx())
    assert isinstance(dev, URRobot) and dev.gate.model is UR5 and dev.name == "robot"
    assert spec.factory(URSettings(model="ur16e"), Ctx()).gate.model is None  # no kinematics for it


def test_settings_are_validated():
    s = URSettings(frequency="500 Hz", tcp_xyz=("0 mm", "0 mm", "180 mm"), speed="50 mm/s")
    assert s.frequency == 500 and s.tcp_xyz[2] == pytest.approx(0.18) and s.speed == pytest.approx(0.05)
    with pytest.raises(ValueError):
        URSettings(model="ur55")
    with pytest.raises(ValueError):
        URSettings(hostname="x")


def test_path_blends_are_clamped_and_end_at_zero():
    P = np.tile(np.eye(4), (4, 1, 1))
    P[:, 0, 3] = [0.0, 0.1, 0.11, 0.3]
    np.testing.assert_allclose(path_blends(P, 0.02), [0.02, 0.0045, 0.0045, 0.0])
    assert path_blends(P[:1], 0.02).tolist() == [0.0]
