"""The ABB adapter (robot.abb-rws): the real abb-robot-client RWS and EGM clients against loopback peers
speaking RWS 1.0 (Digest login, session cookies) and EGM (protobuf over UDP, 250 Hz), with the
WeldcellServer RAPID module emulated from its own PERS declarations."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip(
    "abb_robot_client", reason="abb-robot-client is not installed (pip install 'weldcell[abb]')"
)

from peers_abb import AbbPeer, free_udp_port, module_variables  # noqa: E402
from weldcell.hal.kinematics import get_model  # noqa: E402
from weldcell.hal.lifecycle import State  # noqa: E402
from weldcell.hal.safety import SafetyGate  # noqa: E402
from weldcell.plugins.abb import RAPID_MODULE  # noqa: E402
from weldcell.plugins.abb import rapid_values as V  # noqa: E402
from weldcell.plugins.abb.adapter import ABBRobot  # noqa: E402
from weldcell.plugins.abb.settings import ABBSettings  # noqa: E402
from weldcell.sdk.cell import SafetyLimits  # noqa: E402
from weldcell.sdk.errors import DeviceError  # noqa: E402
from weldcell.sdk.geometry import T_from_rpy  # noqa: E402
from weldcell.testing.conformance import RobotConformance  # noqa: E402

IRB = get_model("abb-irb2600")
PASSWORD = "s3cret-pw"


@pytest.fixture(scope="module")
def pc_port():
    return free_udp_port()


@pytest.fixture(scope="module")
def peer(pc_port):
    p = AbbPeer(pc_port, password=PASSWORD)
    yield p
    p.close()


@pytest.fixture
def ctrl(peer):
    peer.reset()
    return peer


def make_robot(peer: AbbPeer, port: int, dry_run: bool = False, **kw) -> ABBRobot:
    kw = {
        "url": peer.url,
        "password": PASSWORD,
        "egm_host": "127.0.0.1",
        "egm_port": port,
        "state_timeout": 0.25,
        "motion_timeout_margin": 2.0,
        "egm_timeout": 0.5,
        **kw,
    }
    s = ABBSettings(**kw)
    return ABBRobot(s, name="arm", gate=SafetyGate(SafetyLimits(), model=IRB), dry_run=dry_run)


class TestABBConformance(RobotConformance):
    @pytest.fixture
    def device(self, ctrl, pc_port):
        return make_robot(ctrl, pc_port)

    @pytest.fixture
    def break_device(self, ctrl):
        def brk(dev):
            ctrl.ctrl.stop_program()  # the operator pressed Stop: RAPID and the EGM stream end
            time.sleep(0.3)

        return brk


def test_module_declares_what_the_adapter_writes():
    decl = module_variables()
    for name in (
        "wc_version",
        "wc_seq",
        "wc_done",
        "wc_status",
        "wc_errno",
        "wc_cmd",
        "wc_n",
        "wc_acc",
        "wc_stop",
        "wc_egm_time",
        "wc_speed",
        "wc_zone",
        "wc_jtarget",
        "wc_path",
    ):
        assert name in decl, name
    assert decl["wc_path"][:2] == ("robtarget", 100)


def test_pose_conventions_round_trip():
    T = T_from_rpy((0.3, -1.2, 2.5), (0.81, -0.25, 0.6))
    p, q = V.T_to_abb(T)
    np.testing.assert_allclose(p, [810.0, -250.0, 600.0])
    assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
    np.testing.assert_allclose(V.robtarget_to_T(V.robtarget(T)), T, atol=1e-7)
    np.testing.assert_allclose(
        np.radians(V.parse_value(V.jointtarget([0.1, 0.2, 0.3, 0, 0, 0]))[0])[:3], [0.1, 0.2, 0.3], atol=1e-7
    )


def test_state_over_egm_matches_rws_and_the_model(ctrl, pc_port):
    q = IRB.home + np.array([0.1, -0.05, 0.08, 0.02, 0.1, -0.3])
    ctrl.ctrl.q = q.copy()
    logins, requests = ctrl.rws.logins, len(ctrl.rws.requests)
    with make_robot(ctrl, pc_port, tcp_xyz=(0.0, 0.0, 0.2)) as arm:
        st = arm.state()
        np.testing.assert_allclose(st.q, q, atol=1e-9)
        np.testing.assert_allclose(st.T_base_flange, IRB.fk(q), atol=1e-6)
        np.testing.assert_allclose(st.T_base_tcp[:3, 3], (IRB.fk(q) @ [0, 0, 0.2, 1])[:3], atol=1e-6)
        time.sleep(0.1)
        samples = arm.stream()
        assert len(samples) >= 10, "the EGM stream runs at 250 Hz"
        dt = np.diff([s.stamp for s in samples])
        assert np.all(dt > 0) and np.median(dt) < 0.01
        assert np.all(np.diff([s.seqno for s in samples]) > 0)
        assert np.all(np.diff([s.device_stamp for s in samples]) >= 0)  # the controller's clock (ms)
    # one Digest login for the session: its cookie carries every later request
    assert ctrl.rws.logins == logins + 1 and len(ctrl.rws.requests) - requests > 5


def test_state_through_rws_only_and_session_survives_a_controller_restart(ctrl, pc_port):
    with make_robot(ctrl, pc_port, use_egm=False) as arm:
        before = ctrl.rws.logins
        st = arm.state()
        np.testing.assert_allclose(st.q, IRB.home, atol=1e-6)
        ctrl.drop_sessions()  # cookies and nonces invalid: requests' Digest auth logs in again
        st = arm.state()
        np.testing.assert_allclose(st.T_base_flange, IRB.fk(IRB.home), atol=1e-6)
        assert ctrl.rws.logins == before + 1


def test_linear_move_writes_rapid_and_reaches_the_target(ctrl, pc_port):
    with make_robot(ctrl, pc_port, tcp_xyz=(0.0, 0.0, 0.15), tcp_rpy=(0.0, 0.2, 0.0)) as arm:
        start = arm.state().T_base_tcp
        target = start.copy()
        target[:3, 3] += [0.02, -0.015, 0.03]
        arm.move_linear(target, speed=0.2, accel=0.8)
        got = arm.state().T_base_tcp
        np.testing.assert_allclose(got, target, atol=1e-5)
        w = dict(ctrl.ctrl.writes)
        assert w["wc_cmd"] == "1" and w["wc_n"] == "1" and ctrl.ctrl.writes[-1][0] == "wc_seq"
        sent = V.robtarget_to_T(V.parse_value(w["wc_path"])[0])
        np.testing.assert_allclose(sent, target @ np.linalg.inv(arm.T_flange_tcp), atol=1e-6)
        assert V.parse_value(w["wc_speed"])[0] == pytest.approx(200.0)  # mm/s
        assert float(w["wc_acc"]) == pytest.approx(0.8)


def test_follow_path_in_chunks_with_blends(ctrl, pc_port):
    with make_robot(ctrl, pc_port, path_chunk=3) as arm:
        T0 = arm.state().T_base_tcp
        offs = [[0.01, 0, 0], [0.02, 0, 0], [0.02, 0.01, 0], [0.02, 0.02, 0.005], [0.0, 0.02, 0.005]]
        poses = np.stack(
            [np.block([[T0[:3, :3], (T0[:3, 3] + o)[:, None]], [np.zeros((1, 3)), 1]]) for o in offs]
        )
        arm.follow_path(poses, speed=0.25, accel=1.0, blend=0.004)
        np.testing.assert_allclose(arm.state().T_base_tcp, poses[-1], atol=1e-5)
        paths = [v for k, v in ctrl.ctrl.writes if k == "wc_path"]
        ns = [v for k, v in ctrl.ctrl.writes if k == "wc_n"]
        assert ns == ["3", "2"] and len(paths) == 2
        zone = V.parse_value(dict(ctrl.ctrl.writes)["wc_zone"])
        assert zone[0] is False and zone[1] == pytest.approx(4.0)


def test_joint_move_and_egm_speed_servo(ctrl, pc_port):
    with make_robot(ctrl, pc_port) as arm:
        q = IRB.home + np.array([0.05, 0.05, -0.05, 0.0, 0.1, 0.2])
        arm.move_joint(q, speed=1.0, accel=2.0)
        np.testing.assert_allclose(arm.state().q, q, atol=1e-6)
        jt = V.parse_value(dict(ctrl.ctrl.writes)["wc_jtarget"])
        np.testing.assert_allclose(np.radians(jt[0]), q, atol=1e-6)
        p0 = arm.state().T_base_tcp[:3, 3]
        arm.speed_linear(np.array([0.0, 0.05, -0.02, 0, 0, 0]), accel=0.5, duration=0.05)  # starts EGM
        t0 = time.monotonic()
        # at least 0.3 s of servoing and 20 EGM exchanges (a loaded machine slows the 250 Hz peer down)
        while time.monotonic() < t0 + 0.3 or (ctrl.egm.corrections <= 20 and time.monotonic() < t0 + 5):
            arm.speed_linear(np.array([0.0, 0.05, -0.02, 0, 0, 0]), accel=0.5, duration=0.05)
            time.sleep(0.02)
        servoed = time.monotonic() - t0
        time.sleep(0.08)
        moved = arm.state().T_base_tcp[:3, 3] - p0
        assert ctrl.egm.corrections > 20  # EgmSensor messages answered the feedback
        np.testing.assert_allclose(
            moved / np.linalg.norm(moved), np.array([0, 5, -2]) / np.linalg.norm([0, 5, 2]), atol=0.02
        )
        v = np.linalg.norm([0.05, 0.02])
        assert 0.5 * v * 0.3 < np.linalg.norm(moved) < v * (servoed + 0.05 + 0.05)
        arm.stop()
        assert ctrl.ctrl.mci_running is False
        # a RAPID move after servoing
        target = arm.state().T_base_tcp.copy()
        target[2, 3] += 0.005
        arm.move_linear(target, speed=0.1)
        np.testing.assert_allclose(arm.state().T_base_tcp, target, atol=1e-5)


def test_stop_interrupts_a_running_move(ctrl, pc_port):
    import threading

    with make_robot(ctrl, pc_port) as arm:
        T0 = arm.state().T_base_tcp
        target = T0.copy()
        target[1, 3] += 0.2
        errors = []

        def run():
            try:
                arm.move_linear(target, speed=0.1)
            except DeviceError as e:
                errors.append(e)

        t = threading.Thread(target=run)
        t.start()
        time.sleep(0.3)
        arm.stop()
        t.join(2.0)
        assert errors and "stopped" in errors[0].message
        y = arm.state().T_base_tcp[1, 3] - T0[1, 3]
        assert 0.001 < y < 0.1, "stopped on the way, well before the target 0.2 m away"
        time.sleep(0.1)
        assert arm.state().T_base_tcp[1, 3] - T0[1, 3] == pytest.approx(y, abs=1e-6), "and stays stopped"
        assert ctrl.ctrl.num("wc_status") == 1


def test_manual_mode_and_motors_off_refuse_motion_with_a_fix(ctrl, pc_port):
    with make_robot(ctrl, pc_port) as arm:
        target = arm.state().T_base_tcp.copy()
        target[2, 3] += 0.01
        ctrl.ctrl.opmode = "MANR"
        n = len(ctrl.ctrl.writes)
        with pytest.raises(DeviceError) as e:
            arm.move_linear(target)
        assert "MANR" in e.value.message and "AUTO" in e.value.fix
        assert len(ctrl.ctrl.writes) == n, "nothing was written to RAPID"
        assert arm.lifecycle is State.ACTIVE and "MANR" in arm.health().message
        ctrl.ctrl.opmode = "AUTO"
        ctrl.ctrl.motors_off()
        time.sleep(0.3)
        with pytest.raises(DeviceError) as e:
            arm.state()
        assert "motors went off" in e.value.message and arm.lifecycle is State.ERROR
        arm.recover()
        with pytest.raises(DeviceError) as e:
            arm.configure()  # start_program needs motors on
        assert "motors are off" in e.value.message and "Motors On" in e.value.fix
    # motors_on = true switches them on through RWS in AUTO
    with make_robot(ctrl, pc_port, motors_on=True) as arm:
        assert ctrl.ctrl.ctrlstate == "motoron" and ctrl.ctrl.execution == "running"
        arm.move_linear(target, speed=0.1)


def test_emergency_stop_mid_move_is_a_fault_and_blocks_until_reset(ctrl, pc_port):
    import threading

    with make_robot(ctrl, pc_port) as arm:
        target = arm.state().T_base_tcp.copy()
        target[0, 3] -= 0.1
        threading.Timer(0.2, ctrl.ctrl.emergency_stop).start()
        with pytest.raises(DeviceError) as e:
            arm.move_linear(target, speed=0.1)
        assert "emergency stop" in e.value.message and "release the emergency stop" in e.value.fix
        assert arm.lifecycle is State.ERROR and "emergency" in arm.health().message
        arm.recover()
        with pytest.raises(DeviceError):
            arm.configure()
        ctrl.ctrl.ctrlstate = "emergencystopreset"
        arm.recover()
        arm.settings.motors_on = True
        arm.configure()
        arm.activate()
        arm.move_linear(target, speed=0.2)
        np.testing.assert_allclose(arm.state().T_base_tcp, target, atol=1e-5)


def test_unreachable_target_reported_with_the_rapid_error(ctrl, pc_port):
    with make_robot(ctrl, pc_port) as arm:
        target = arm.state().T_base_flange.copy()
        target[:3, 3] = [2.5, 0.0, 0.1]  # beyond the IRB 2600's 1.65 m
        with pytest.raises(DeviceError) as e:
            arm._move_linear(target, 2.0, 2.0)  # the driver side: the gate would have refused it
        assert "RAPID error" in e.value.message and "event log" in e.value.fix


def test_wrong_password_and_missing_password(ctrl, pc_port):
    arm = make_robot(ctrl, pc_port, password="wrong")
    with pytest.raises(DeviceError) as e:
        arm.configure()
    assert "rejected user" in e.value.message and "ABB_RWS_PASSWORD" in e.value.fix
    arm.close()
    s = ABBSettings(url=ctrl.url)
    assert s.password is None
    with pytest.raises(DeviceError) as e:
        ABBRobot(s).configure()
    assert "${env:ABB_RWS_PASSWORD}" in e.value.fix
    assert PASSWORD not in repr(ABBSettings(url=ctrl.url, password=PASSWORD))


def test_egm_frame_mismatch_is_refused(ctrl, pc_port):
    ctrl.ctrl.egm_frame_offset = np.array([0.0, 0.0, 25.0])
    arm = make_robot(ctrl, pc_port)
    with pytest.raises(DeviceError) as e:
        arm.configure()
    assert "tool0" in e.value.fix
    arm.close()


def test_dry_run_sends_nothing(ctrl, pc_port):
    ctrl.ctrl.start()
    with make_robot(ctrl, pc_port, dry_run=True) as arm:
        target = arm.state().T_base_tcp.copy()
        target[2, 3] += 0.01
        arm.move_linear(target)
        assert arm.dry_run_log[-1].command == "move_linear"
    assert not [k for k, _ in ctrl.ctrl.writes if k == "wc_seq"]


def test_network_loss_is_a_fault_and_recover_reconnects(ctrl, pc_port):
    with make_robot(ctrl, pc_port) as arm:
        arm.state()
        ctrl.rws.offline, ctrl.egm.paused = True, True  # the cable is pulled: no HTTP, no EGM
        time.sleep(0.3)
        with pytest.raises(DeviceError) as e:
            arm.state()
        assert arm.lifecycle is State.ERROR and "RWS request" in arm.health().message
        assert ctrl.url.split("//")[1] in e.value.message or "RWS" in e.value.message
        ctrl.rws.offline, ctrl.egm.paused = False, False
        arm.recover()
        arm.configure()
        arm.activate()
        np.testing.assert_allclose(arm.state().q, IRB.home, atol=1e-6)


def test_missing_module_is_named_or_installed_through_rws(ctrl, pc_port):
    ctrl.ctrl.unload()
    arm = make_robot(ctrl, pc_port)
    with pytest.raises(DeviceError) as e:
        arm.configure()
    assert "is not loaded in task T_ROB1" in e.value.message and "install_module" in e.value.fix
    arm.close()
    with make_robot(ctrl, pc_port, install_module=True) as arm:
        assert ctrl.ctrl.loads == ["$HOME/WeldcellServer.mod"]
        assert ctrl.ctrl.files["$HOME/WeldcellServer.mod"] == RAPID_MODULE.read_bytes()
        assert ctrl.ctrl.mastership is None, "mastership released"
        target = arm.state().T_base_tcp.copy()
        target[2, 3] += 0.01
        arm.move_linear(target, speed=0.1)
        np.testing.assert_allclose(arm.state().T_base_tcp, target, atol=1e-5)


def test_probe_reports_the_controller_state(ctrl):
    from weldcell.plugins import abb as abb_plugin

    ctrl.ctrl.opmode = "MANR"
    text = abb_plugin.probe(ABBSettings(url=ctrl.url, password=PASSWORD))
    assert "motoron" in text and "MANR" in text and "RAPID stopped" in text
    with pytest.raises(DeviceError) as e:
        abb_plugin.probe(ABBSettings(url="http://127.0.0.1:9", password=PASSWORD))
    assert "does not answer RWS" in e.value.message


def test_joint_move_time_limit_covers_the_tcp_speed_cap(ctrl, pc_port, monkeypatch):
    with make_robot(ctrl, pc_port) as arm:
        planned = []
        monkeypatch.setattr(arm, "_run", lambda cmd, data, t, what: planned.append((data, t)))
        q = IRB.home + np.array([0.6, 0, 0, 0, 0, 0])
        arm.move_joint(q, speed=1.0, accel=2.0)
        data, t = planned[0]
        tcp_path = 0.6 * np.linalg.norm(IRB.fk(IRB.home)[:2, 3])  # an arc about axis 1
        assert t == pytest.approx(tcp_path / arm.gate.limits.max_linear_speed, rel=0.02)
        assert V.parse_value(data["wc_speed"])[:2] == pytest.approx([250.0, np.degrees(1.0)], abs=1e-3)
