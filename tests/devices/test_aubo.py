"""robot.aubo: the real pyaubo_sdk RpcClient against a local JSON-RPC/TCP ARCS peer, and an in-process fake
of the pyaubo_sdk classes (both drive the same simulated AUBO i5)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyaubo_sdk
import pytest
from peers_cell2_aubo import PARAMS, AuboSim, FakeRpcClient, peer_request
from weldcell.hal.kinematics import get_model
from weldcell.hal.lifecycle import State
from weldcell.hal.safety import SafetyGate
from weldcell.plugins import aubo as aubo_plugin
from weldcell.plugins.aubo.adapter import AuboRobot, T_to_pose, pose_to_T, probe_aubo
from weldcell.plugins.aubo.settings import AuboSettings
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import DeviceError, SafetyError
from weldcell.sdk.geometry import T_from_rpy
from weldcell.testing.conformance import RobotConformance

PEER = Path(__file__).resolve().parent / "peers_cell2_aubo.py"


def test_fake_mirrors_pyaubo_sdk_names():
    classes = {
        "MotionControl": pyaubo_sdk.MotionControl,
        "RobotState": pyaubo_sdk.RobotState,
        "RobotConfig": pyaubo_sdk.RobotConfig,
        "RobotManage": pyaubo_sdk.RobotManage,
    }
    for key, names in PARAMS.items():
        cls, meth = key.split(".")
        assert meth in dir(classes[cls]), f"pyaubo_sdk.{key} does not exist"
        n_args = classes[cls].__dict__[meth].__doc__.split("->")[0].count("arg")
        assert n_args == len(names), f"{key}: SDK takes {n_args} args, peer maps {names}"
    for meth in (
        "connect",
        "login",
        "logout",
        "disconnect",
        "hasConnected",
        "hasLogined",
        "getRobotNames",
        "getRobotInterface",
        "setRequestTimeout",
    ):
        assert meth in dir(pyaubo_sdk.RpcClient) and hasattr(FakeRpcClient, meth)


@pytest.fixture(scope="module")
def peer():
    p = subprocess.Popen([sys.executable, str(PEER)], stdout=subprocess.PIPE, text=True)
    try:
        port = int(p.stdout.readline())
        yield port
    finally:
        p.kill()
        p.wait(5)


@pytest.fixture
def fresh_peer(peer):
    peer_request(peer, "__peer__.set", {"safety": "Normal", "robot_mode": "Running"})
    return peer


def _gate() -> SafetyGate:
    return SafetyGate(SafetyLimits(), model=get_model("aubo-i5"))


def _tcp_robot(port: int, **kw) -> AuboRobot:
    s = AuboSettings(host="127.0.0.1", port=port, request_timeout=0.5, poll_period=0.005, **kw)
    return AuboRobot(s, name="aubo", gate=_gate())


class TestAuboOverJsonRpc(RobotConformance):
    @pytest.fixture
    def device(self, fresh_peer):
        return _tcp_robot(fresh_peer)

    @pytest.fixture
    def break_device(self, fresh_peer):
        return lambda dev: peer_request(fresh_peer, "__peer__.drop")


def test_sdk_wire_calls_and_flange_mapping(fresh_peer, monkeypatch):
    monkeypatch.setenv("AUBO_PASSWORD", "secret")
    with _tcp_robot(fresh_peer) as r:
        st = r.state()
        sim = AuboSim()  # same model/offset as the peer process
        np.testing.assert_allclose(st.T_base_flange, sim.model.fk(st.q), atol=1e-9)
        np.testing.assert_allclose(r.T_flange_ctrltcp, T_from_rpy([0, 0, 0.3], [0, 0, 0.1]), atol=1e-12)
        target = st.T_base_tcp @ T_from_rpy([0.0, 0.05, 0.0], [0.01, 0.02, -0.015])
        t0 = time.monotonic()
        r.move_linear(target, speed=0.05)
        assert time.monotonic() - t0 >= 0.1, "the adapter must wait for the controller to finish the move"
        np.testing.assert_allclose(r.state().T_base_flange, target, atol=1e-6)
        q = r.state().q + 0.05
        r.move_joint(q, speed=0.5)
        np.testing.assert_allclose(r.state().q, q, atol=1e-9)
        base = r.state().T_base_tcp
        path = np.stack([base.copy(), base.copy()])
        path[0, 0, 3] += 0.01
        path[1, 0, 3] += 0.02
        r.follow_path(path, speed=0.1, blend=0.002)
        np.testing.assert_allclose(r.state().T_base_tcp, path[-1], atol=1e-6)
        p0 = r.state().T_base_tcp[:3, 3]
        r.speed_linear(np.array([0.0, 0.02, 0.0, 0, 0, 0]), duration=0.1)
        np.testing.assert_allclose(r.state().T_base_tcp[:3, 3] - p0, [0, 0.002, 0], atol=1e-6)
        r.stop()
    calls = peer_request(fresh_peer, "__peer__.state")["log"]
    for name in (
        "MotionControl.moveLine",
        "MotionControl.moveJoint",
        "MotionControl.getExecId",
        "MotionControl.speedLine",
        "MotionControl.stopLine",
        "RobotConfig.getTcpOffset",
    ):
        assert name in calls


def test_protective_stop_faults_and_recover_unlocks(fresh_peer):
    with _tcp_robot(fresh_peer) as r:
        assert not r.state().protective_stop
        peer_request(fresh_peer, "__peer__.set", {"safety": "ProtectiveStop"})
        assert r.state().protective_stop
        goal = r.state().T_base_tcp
        goal[2, 3] += 0.01
        with pytest.raises(DeviceError, match="refused|ProtectiveStop"):
            r.move_linear(goal)
        assert r.lifecycle is State.ERROR
        r.recover()
        r.configure()
        r.activate()
        assert not r.state().protective_stop
        assert "RobotManage.setUnlockProtectiveStop" in peer_request(fresh_peer, "__peer__.state")["log"]


def test_not_running_and_emergency_stop_are_refused(fresh_peer):
    peer_request(fresh_peer, "__peer__.set", {"robot_mode": "PowerOff"})
    with pytest.raises(DeviceError, match="PowerOff"):
        _tcp_robot(fresh_peer).configure()
    peer_request(fresh_peer, "__peer__.set", {"robot_mode": "Running", "safety": "RobotEmergencyStop"})
    with pytest.raises(DeviceError, match="RobotEmergencyStop"):
        _tcp_robot(fresh_peer).configure()


def test_unreachable_controller_and_probe(fresh_peer, weldcell_pm):
    with pytest.raises(DeviceError, match="cannot connect"):
        _tcp_robot(1).configure()
    assert "rob1" in probe_aubo(AuboSettings(host="127.0.0.1", port=fresh_peer))
    with pytest.raises(DeviceError, match="does not answer"):
        probe_aubo(AuboSettings(host="127.0.0.1", port=1), timeout=0.2)
    weldcell_pm.register(aubo_plugin, "aubo")
    spec = weldcell_pm.registry.get("device", "robot.aubo")
    assert spec.kind == "robot" and spec.settings is AuboSettings and spec.requires == {"pyaubo_sdk": "aubo"}


# ------------------------------------------------------------------------------- in-process SDK fake
def _fake_robot(sim: AuboSim, monkeypatch, **kw) -> AuboRobot:
    monkeypatch.setenv("AUBO_PASSWORD", "aubo-test-pw")
    s = AuboSettings(poll_period=0.002, **kw)
    return AuboRobot(s, name="aubo", gate=_gate(), rpc_factory=lambda: FakeRpcClient(sim))


class TestAuboWithSdkFake(RobotConformance):
    @pytest.fixture
    def device(self, monkeypatch):
        return _fake_robot(AuboSim(max_motion_time=0.02), monkeypatch)

    @pytest.fixture
    def break_device(self):
        return lambda dev: dev._rpc.disconnect()  # noqa: SLF001


def test_password_from_the_environment(monkeypatch):
    sim = AuboSim()
    monkeypatch.setenv("AUBO_PASSWORD", "wrong")
    r = AuboRobot(AuboSettings(), rpc_factory=lambda: FakeRpcClient(sim))
    with pytest.raises(DeviceError, match="login") as e:
        r.configure()
    assert "AUBO_PASSWORD" in e.value.fix


def test_gate_refuses_before_the_sdk(monkeypatch):
    sim = AuboSim(max_motion_time=0.01)
    with _fake_robot(sim, monkeypatch) as r:
        n = len(sim.log)
        st = r.state()
        with pytest.raises(SafetyError):
            r.move_linear(st.T_base_tcp, speed=1.0)
        q = st.q.copy()
        q[0] = 4.0  # beyond the i5's +-175 deg
        with pytest.raises(SafetyError):
            r.move_joint(q)
        assert [m for m, _ in sim.log[n:] if m.startswith("MotionControl.move")] == []


def test_pose_conversion_roundtrip():
    T = T_from_rpy([0.3, -0.2, 1.1], [0.4, -0.1, 0.25])
    np.testing.assert_allclose(pose_to_T(T_to_pose(T)), T, atol=1e-12)
