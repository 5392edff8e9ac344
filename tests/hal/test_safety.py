"""The safety gate in front of every robot command, dry-run, and the TCP offset (checked on the sim UR5)."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.hal.kinematics import get_model
from weldcell.hal.robot import RobotMotionSettings
from weldcell.hal.safety import SafetyGate
from weldcell.hal.sim.devices import SimRobot
from weldcell.hal.sim.world import SimWorld
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import SafetyError
from weldcell.sdk.geometry import T_from_rotvec, T_from_rpy, invert, pose_error

UR5 = get_model("ur5")
SENT = ("_move_linear", "_move_joint", "_follow_path", "_speed_linear")


def make_robot(limits: SafetyLimits | None = None, dry_run: bool = False, q_start=None, **motion) -> SimRobot:
    r = SimRobot(
        UR5,
        SimWorld([]),
        gate=SafetyGate(limits or SafetyLimits(), model=UR5),
        motion=RobotMotionSettings(**motion),
        dry_run=dry_run,
        q_start=q_start,
    )
    r.configure()
    r.activate()
    return r


@pytest.fixture
def sent(monkeypatch):
    """Spy on the driver methods of a robot: what actually reached the (simulated) controller."""

    def _spy(robot):
        calls: list[str] = []
        for name in SENT:
            orig = getattr(robot, name)

            def spy(*a, _n=name, _o=orig, **k):
                calls.append(_n)
                return _o(*a, **k)

            monkeypatch.setattr(robot, name, spy)
        return calls

    return _spy


def shifted(T, dx=0.0, dy=0.0, dz=0.0):
    out = np.array(T, dtype=float)
    out[:3, 3] += (dx, dy, dz)
    return out


# -- single checks ------------------------------------------------------------------------------
def test_target_outside_the_box_names_the_axis_and_the_box():
    gate = SafetyGate(SafetyLimits(workspace_min=(-0.5, -0.5, 0.0), workspace_max=(0.8, 0.5, 0.9)))
    gate.check_point([0.3, 0.2, 0.4])
    with pytest.raises(SafetyError) as e:
        gate.check_point([0.3, 0.7, 0.4], "weld start")
    msg = e.value.message
    assert msg.startswith("weld start [0.300, 0.700, 0.400] m is outside the cell's workspace box")
    assert "(axis y; box [-0.500, -0.500, 0.000] m .. [0.800, 0.500, 0.900] m)" in msg
    assert "workspace_min/max" in e.value.fix
    with pytest.raises(SafetyError, match="axis z"):
        gate.check_point([0.3, 0.2, -0.01])
    with pytest.raises(SafetyError, match="NaN"):
        gate.check_point([np.nan, 0, 0])


def test_beyond_reach_with_an_explicit_limit_and_with_the_model():
    gate = SafetyGate(SafetyLimits(max_reach=0.5))
    with pytest.raises(SafetyError) as e:
        gate.check_point([0.6, 0.0, 0.2])
    assert "is 0.632 m from the robot's base, beyond its reach of 0.500 m" in e.value.message
    model_gate = SafetyGate(SafetyLimits(), model=UR5)  # UR5: 850 mm from the shoulder
    model_gate.check_point([0.7, 0.0, 0.3])
    with pytest.raises(SafetyError) as e:
        model_gate.check_point([0.9, 0.0, 0.3])
    assert "from the robot's shoulder, beyond its reach of 0.850 m" in e.value.message
    assert SafetyGate(SafetyLimits()).reach is None  # no model, no limit: the box alone applies


def test_joint_limits():
    panda = get_model("franka-panda")
    gate = SafetyGate(SafetyLimits(), model=panda)
    q = np.array(panda.home, dtype=float)
    gate.check_joints(q)
    q[3] = panda.joint_limits[3, 1] + 0.1
    with pytest.raises(SafetyError) as e:
        gate.check_joints(q, "joint move target")
    hi = np.degrees(panda.joint_limits[3])
    assert f"joint move target joint 4 = {np.degrees(q[3]):.1f} deg is outside its limits" in e.value.message
    assert f"[{hi[0]:.1f}, {hi[1]:.1f}] deg" in e.value.message
    with pytest.raises(SafetyError, match="has 6 joint values; the franka-panda has 7 joints"):
        gate.check_joints(np.zeros(6))


def test_joint_move_beyond_the_limits_never_reaches_the_driver(sent):
    r = make_robot()
    calls = sent(r)
    q = np.array(UR5.home)
    q[0] = 7.0
    with pytest.raises(SafetyError, match="joint 1 = 401.1 deg is outside its limits"):
        r.move_joint(q)
    assert calls == []


def test_speed_and_acceleration_caps(sent):
    r = make_robot(SafetyLimits(max_linear_speed="100 mm/s", max_linear_accel=1.0, max_joint_speed=1.0))
    calls = sent(r)
    target = shifted(r.state().T_base_tcp, dz=0.01)
    with pytest.raises(SafetyError) as e:
        r.move_linear(target, speed=0.2)
    assert e.value.message == "TCP speed 0.2 m/s is not within (0, 0.1] m/s (the cell's cap)"
    assert "max_linear_speed" in e.value.fix
    with pytest.raises(SafetyError, match=r"TCP acceleration 3 m/s\^2 is not within \(0, 1\]"):
        r.move_linear(target, speed=0.05, accel=3.0)
    with pytest.raises(SafetyError, match="TCP speed 0 m/s"):
        r.move_linear(target, speed=0.0)
    with pytest.raises(SafetyError, match=r"joint speed 2 rad/s is not within \(0, 1\] rad/s"):
        r.move_joint(UR5.home, speed=2.0)
    with pytest.raises(SafetyError, match="TCP speed 0.5 m/s"):
        r.follow_path(np.stack([target]), speed=0.5)
    assert calls == []
    r.move_linear(target, speed=0.1, accel=1.0)  # at the caps exactly: allowed
    assert calls == ["_move_linear"]


def test_default_motion_settings_over_the_cell_cap_are_refused(sent):
    r = make_robot(SafetyLimits(max_linear_speed=0.02), speed=0.05)
    calls = sent(r)
    with pytest.raises(SafetyError, match="TCP speed 0.05 m/s"):
        r.move_linear(shifted(r.state().T_base_tcp, dz=0.01))
    assert calls == []


# -- whole motions -------------------------------------------------------------------------------
def test_path_leaving_the_box_midway_is_refused_before_anything_is_sent(sent):
    r = make_robot(SafetyLimits(workspace_min=(-0.2, -0.5, 0.1), workspace_max=(0.6, 0.5, 0.6)))
    calls = sent(r)
    start = r.state()
    a = shifted(start.T_base_tcp, dx=0.05)
    b = shifted(start.T_base_tcp, dx=0.05, dz=0.25)  # above the box top (0.406 + 0.25 > 0.6)
    c = shifted(start.T_base_tcp, dx=0.10)
    with pytest.raises(SafetyError) as e:
        r.follow_path(np.stack([a, b, c]), speed=0.05)
    assert e.value.message.startswith("path pose 1 [")
    assert "outside the cell's workspace box (axis z" in e.value.message
    assert calls == []
    np.testing.assert_allclose(r.state().q, start.q)
    r.follow_path(np.stack([a, c]), speed=0.05)
    assert calls[0] == "_follow_path" and calls.count("_follow_path") == 1
    assert pose_error(r.state().T_base_tcp, c)[0] < 1e-4


def test_joint_move_sweeping_out_of_the_box_midway_is_refused(sent):
    """Both ends of the joint move are inside the box; the arc of the TCP between them is not."""
    home_angle = np.arctan2(*UR5.fk(UR5.home)[1::-1, 3])
    q0, q1 = np.array(UR5.home), np.array(UR5.home)
    q0[0] += np.radians(70) - home_angle
    q1[0] += np.radians(-70) - home_angle
    limits = SafetyLimits(workspace_min=(-0.5, -0.5, 0.0), workspace_max=(0.25, 0.5, 0.8))
    r = make_robot(limits, q_start=q0)
    calls = sent(r)
    for q in (q0, q1):
        SafetyGate(limits).check_point(UR5.fk(q)[:3, 3], "end of the move")
    with pytest.raises(SafetyError) as e:
        r.move_joint(q1)
    assert "joint move at" in e.value.message and "% of the motion" in e.value.message
    assert "axis x" in e.value.message
    assert calls == []


def test_linear_move_through_the_base_is_refused():
    """A straight line between two reachable points that passes the robot's own base column."""
    r = make_robot()
    start = r.state()
    T_other = start.T_base_tcp.copy()
    T_other[:2, 3] = -start.T_base_tcp[:2, 3]  # the mirror point: the line runs through the base axis
    with pytest.raises(SafetyError, match="linear move at [0-9]+% of the path"):
        r.move_linear(T_other, speed=0.05)
    np.testing.assert_allclose(r.state().q, start.q)


def test_velocity_command_caps_and_box(sent):
    r = make_robot(SafetyLimits(max_linear_speed=0.25, max_angular_speed=1.0))
    calls = sent(r)
    with pytest.raises(SafetyError) as e:
        r.speed_linear([0.3, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert e.value.message == "velocity command 0.3 m/s exceeds the cap 0.25 m/s"
    with pytest.raises(SafetyError, match="angular velocity command 2 rad/s exceeds the cap 1 rad/s"):
        r.speed_linear([0.0, 0.0, 0.0, 0.0, 0.0, 2.0])
    with pytest.raises(SafetyError, match="NaN"):
        r.speed_linear([np.nan, 0, 0, 0, 0, 0])
    assert calls == []
    p = r.state().T_base_tcp[:3, 3]
    near = SafetyLimits(workspace_min=(-1, -1, 0), workspace_max=(p[0] + 0.005, 1, 1))
    r2 = make_robot(near)
    calls2 = sent(r2)
    r2.speed_linear([0.2, 0.0, 0.0, 0.0, 0.0, 0.0], duration=0.008)  # 1.6 mm: still 3.4 mm from the wall
    with pytest.raises(
        SafetyError, match=r"velocity command \(TCP after [0-9.]+ s of 0.05 s\) .* outside.*axis x"
    ):
        r2.speed_linear([0.2, 0.0, 0.0, 0.0, 0.0, 0.0], duration=0.05)  # 10 mm: through the wall
    r2.speed_linear([-0.2, 0.0, 0.0, 0.0, 0.0, 0.0], duration=0.05)  # away from the wall is fine
    assert calls2 == ["_speed_linear", "_speed_linear"]


def test_malformed_path_is_refused():
    r = make_robot()
    with pytest.raises(SafetyError, match=r"\(K, 4, 4\)"):
        r.follow_path(np.eye(4))


def test_commands_need_an_active_robot():
    r = SimRobot(UR5, SimWorld([]))
    from weldcell.sdk.errors import DeviceError

    with pytest.raises(DeviceError, match="not active"):
        r.move_linear(np.eye(4))
    r.stop()  # stop is always allowed


# -- dry run ------------------------------------------------------------------------------------
def test_dry_run_logs_instead_of_sending(sent):
    r = make_robot(dry_run=True, tcp_xyz=(0, 0, 0.1))
    calls = sent(r)
    st = r.state()
    target = shifted(st.T_base_tcp, dz=0.02)
    r.move_linear(target, speed=0.05)
    r.move_joint(UR5.home, speed=0.3)
    r.speed_linear([0.01, 0, 0, 0, 0, 0])
    r.stop()
    assert calls == []
    assert [e.command for e in r.dry_run_log] == ["move_linear", "move_joint", "speed_linear", "stop"]
    logged = r.dry_run_log[0].args
    assert logged["speed"] == 0.05
    np.testing.assert_allclose(logged["T_base_flange"], target @ invert(r.T_flange_tcp), atol=1e-12)
    np.testing.assert_allclose(r.state().q, st.q)  # nothing moved
    assert r.trajectory == []
    with pytest.raises(SafetyError):  # the gate still runs in dry-run mode, and refusals are not logged
        r.move_linear(shifted(target, dx=3.0))
    assert len(r.dry_run_log) == 4


# -- TCP offset ---------------------------------------------------------------------------------
def test_tcp_offset_is_applied_to_state_and_moves():
    r = make_robot(tcp_xyz=(0.0, "20 mm", "200 mm"), tcp_rpy=(0.0, "15 deg", 0.0))
    T_flange_tcp = T_from_rpy((0.0, np.radians(15), 0.0), (0.0, 0.02, 0.2))
    np.testing.assert_allclose(r.T_flange_tcp, T_flange_tcp, atol=1e-12)
    st = r.state()
    np.testing.assert_allclose(st.T_base_tcp, st.T_base_flange @ T_flange_tcp, atol=1e-12)
    np.testing.assert_allclose(st.T_base_flange, UR5.fk(st.q), atol=1e-12)
    target = shifted(st.T_base_tcp, dx=0.03, dz=-0.02) @ T_from_rpy((0.1, 0.0, 0.2))
    r.move_linear(target, speed=0.05)
    after = r.state()
    dp, dr = pose_error(after.T_base_tcp, target)
    assert dp < 1e-5 and dr < 1e-5
    dp, dr = pose_error(after.T_base_flange, target @ invert(T_flange_tcp))
    assert dp < 1e-5 and dr < 1e-5


def test_the_gate_checks_the_tcp_not_the_flange():
    r = make_robot(SafetyLimits(workspace_min=(-1, -1, 0.1), workspace_max=(1, 1, 1)), tcp_xyz=(0, 0, 0.2))
    st = r.state()
    assert st.T_base_tcp[2, 3] == pytest.approx(st.T_base_flange[2, 3] - 0.2)  # the torch points down
    target = shifted(st.T_base_tcp, dz=-(st.T_base_tcp[2, 3] - 0.05))  # TCP at z = 5 cm, flange at 25 cm
    with pytest.raises(SafetyError, match="axis z"):
        r.move_linear(target, speed=0.05)


def test_speed_linear_rotation_about_the_tcp_keeps_the_tcp_in_place():
    """The TCP twist is moved to the flange (v_f = v_tcp - w x r): a pure rotation pivots about the tip."""
    r = make_robot(tcp_xyz=(0.0, 0.0, 0.2))
    st0 = r.state()
    w = np.array([0.0, 0.5, 0.0])
    for _ in range(50):  # 0.5 s of servoing at 100 Hz: 0.25 rad about the base y axis
        r.speed_linear(np.concatenate([np.zeros(3), w]), duration=0.01)
    st1 = r.state()
    moved = np.linalg.norm(st1.T_base_tcp[:3, 3] - st0.T_base_tcp[:3, 3])
    assert moved < 1e-3, f"the TCP drifted {moved * 1000:.2f} mm"
    dR = st1.T_base_tcp[:3, :3] @ st0.T_base_tcp[:3, :3].T
    np.testing.assert_allclose(T_from_rotvec(w * 0.5)[:3, :3], dR, atol=5e-3)
    assert (
        np.linalg.norm(st1.T_base_flange[:3, 3] - st0.T_base_flange[:3, 3]) > 0.04
    )  # the flange swung round


def test_speed_linear_translation_moves_the_tcp_by_v_times_t():
    r = make_robot(tcp_xyz=(0.0, 0.0, 0.15))
    p0 = r.state().T_base_tcp[:3, 3]
    v = np.array([0.02, -0.01, 0.01])
    for _ in range(20):
        r.speed_linear(np.concatenate([v, np.zeros(3)]), duration=0.01)
    np.testing.assert_allclose(r.state().T_base_tcp[:3, 3] - p0, v * 0.2, atol=2e-4)


# -- issue 15: malformed inputs, work bounds, executed motions --------------------------------------
def _no_tracking(monkeypatch, gate):
    def fail(*a, **k):
        raise AssertionError("the gate interpolated or tracked a motion it should have refused at once")

    monkeypatch.setattr(gate, "_track", fail)
    monkeypatch.setattr(gate, "_sweep", fail)


@pytest.mark.parametrize(
    "mangle, message",
    [
        (lambda T: T[:3], r"has shape \(3, 4\), not \(4, 4\)"),
        (lambda T: np.vstack([T[:3], [np.nan, 0, 0, 1]]), "NaN or infinite"),
        (lambda T: np.vstack([T[:3], [0, 0, 0, 2]]), r"last row \[0.0, 0.0, 0.0, 2.0\]"),
        (lambda T: np.where(np.arange(16).reshape(4, 4) == 3, np.inf, T), "NaN or infinite"),
        (lambda T: np.block([[T[:3, :3] * 1.5, T[:3, 3:]], [np.array([[0, 0, 0, 1]])]]), "not orthonormal"),
        (
            lambda T: T @ np.array([[1, 0.2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]),
            "not orthonormal",
        ),
        (lambda T: T @ np.diag([-1.0, 1, 1, 1]), r"mirrored rotation \(det R = -1\)"),
        (lambda T: [[1, 2], [3]], "not a 4x4 array of numbers"),
        (lambda T: "home", "not a 4x4 array of numbers"),
    ],
    ids=["3x4", "nan-last-row", "bad-last-row", "inf", "scaled", "sheared", "mirrored", "ragged", "string"],
)
def test_malformed_poses_are_refused_before_any_math(mangle, message, sent, monkeypatch):
    r = make_robot()
    calls = sent(r)
    _no_tracking(monkeypatch, r.gate)
    T = shifted(r.state().T_base_tcp, dz=0.01)
    with pytest.raises(SafetyError, match=message):
        r.move_linear(mangle(T))
    with pytest.raises(SafetyError, match=message):
        r.follow_path([T, mangle(T)])
    assert calls == []


def test_a_scaled_rotation_is_not_silently_corrected():
    """On a real UR a scaled rotation is a different pose; the gate refuses it and says how to build one."""
    r = make_robot()
    T = shifted(r.state().T_base_tcp, dz=0.05)
    T[:3, :3] *= 1.001
    with pytest.raises(SafetyError) as e:
        r.move_linear(T)
    assert "scaled or sheared" in e.value.message and "orthonormalize" in e.value.fix
    assert e.value.exit_code == 6


@pytest.mark.parametrize("distance", [1e5, 1e6, 1e300])
def test_a_target_far_away_is_refused_without_interpolating(distance, sent, monkeypatch):
    r = make_robot()
    calls = sent(r)
    _no_tracking(monkeypatch, r.gate)
    with pytest.raises(SafetyError, match="outside the cell's workspace box|beyond its reach"):
        r.move_linear(shifted(r.state().T_base_tcp, dx=distance))
    with pytest.raises(SafetyError, match="path pose 0 .* outside"):
        r.follow_path([shifted(r.state().T_base_tcp, dx=distance)])
    assert calls == []


@pytest.mark.parametrize("bad", [0.0, -0.5, np.nan, np.inf, -np.inf, "fast", [0.1], True])
def test_speeds_accelerations_and_durations_must_be_finite_and_positive(bad, sent):
    r = make_robot()
    calls = sent(r)
    T = shifted(r.state().T_base_tcp, dz=0.01)
    for call in (
        lambda: r.move_linear(T, speed=bad),
        lambda: r.move_linear(T, accel=bad),
        lambda: r.move_joint(UR5.home, speed=bad),
        lambda: r.follow_path([T], accel=bad),
        lambda: r.speed_linear([0.01, 0, 0, 0, 0, 0], duration=bad),
        lambda: r.speed_linear([0.01, 0, 0, 0, 0, 0], accel=bad),
    ):
        with pytest.raises(SafetyError):
            call()
    assert calls == []


def test_negative_servo_duration_never_reaches_the_driver(sent):
    """The gate used to check max(duration, 0.05) while the driver integrated the raw (negative) value."""
    r = make_robot()
    calls = sent(r)
    for d in (-3.0, -0.008, 0.0):
        with pytest.raises(SafetyError, match="velocity command duration must be a finite positive"):
            r.speed_linear([0.0, 0.0, -0.2, 0.0, 0.0, 0.0], duration=d)
    assert calls == []


@pytest.mark.parametrize("blend", [np.nan, -0.001, np.inf, "5 mm"])
def test_invalid_blends_are_refused(blend, sent):
    r = make_robot()
    calls = sent(r)
    T0 = r.state().T_base_tcp
    with pytest.raises(SafetyError, match="blend radius"):
        r.follow_path([shifted(T0, dx=0.02), shifted(T0, dx=0.04)], blend=blend)
    assert calls == []


def test_path_blends_are_clipped_to_45_percent_of_the_shorter_neighbour():
    from weldcell.hal.safety import path_blends

    p = np.array([[0, 0, 0], [0.02, 0, 0], [0.024, 0, 0], [0.05, 0, 0]], dtype=float)
    np.testing.assert_allclose(path_blends(p, 0.005), [0.005, 0.45 * 0.004, 0.45 * 0.004, 0.0])


def test_rotation_only_servo_is_checked_on_the_arc_it_sweeps(sent):
    """0.74 rad/s for 3 s with a 20 cm torch: the flange twist is fixed at the start, so the torch tip
    swings round (the TCP speed grows to ~0.3 m/s and the arc leaves the box); refused."""
    r = make_robot(tcp_xyz=(0.0, 0.0, 0.2))
    calls = sent(r)
    with pytest.raises(SafetyError) as e:
        r.speed_linear([0.0, 0.0, 0.0, 0.74 / np.sqrt(2), 0.74 / np.sqrt(2), 0.0], duration=3.0)
    assert "velocity command" in e.value.message
    assert calls == []


def test_the_sim_driver_executes_the_servo_motion_the_gate_checked():
    from weldcell.hal.safety import servo_flange_pose

    r = make_robot(tcp_xyz=(0.0, 0.0, 0.15))
    st0 = r.state()
    tw = np.array([0.02, -0.01, 0.015, 0.2, -0.1, 0.3])
    r.speed_linear(tw, duration=0.5)
    ftw = tw.copy()
    ftw[:3] -= np.cross(tw[3:], st0.T_base_flange[:3, :3] @ r.T_flange_tcp[:3, 3])
    want = servo_flange_pose(st0.T_base_flange, ftw, 0.5)
    dp, dr = pose_error(r.state().T_base_flange, want)
    assert dp < 1e-9 and dr < 1e-9


def test_servo_refuses_joint_speeds_over_the_hardware_limits_near_the_wrist_singularity(sent):
    q = np.array(UR5.home)
    q[4] = 1e-3  # wrist singular: axes 4 and 6 (almost) aligned
    r = make_robot(q_start=q)
    calls = sent(r)
    J = UR5.jacobian(q)
    null = np.linalg.svd(J)[2][-1]  # the joint direction the flange barely moves in
    bad = J @ null  # a tiny twist that needs that direction fast: wrist joints spin
    tw = np.concatenate([np.zeros(3), bad[3:] / np.linalg.norm(bad[3:]) * 0.5])
    with pytest.raises(SafetyError, match=r"joint \d would turn at \d+ deg/s, over its limit"):
        r.speed_linear(tw, duration=0.2)
    assert calls == []


def test_linear_move_through_the_wrist_singularity_is_refused_for_its_joint_speed(sent):
    """0.25 mm of TCP path over which joint 4 must turn ~95 deg: 15 samples saw nothing; refused now."""
    q = np.array(UR5.home)
    q[4] = 2e-4
    r = make_robot(q_start=q)
    calls = sent(r)
    T0 = r.state().T_base_tcp
    Jinv = np.linalg.inv(UR5.jacobian(q))[:, :3]  # joint motion per TCP translation, orientation fixed
    dp = np.linalg.svd(Jinv)[2][0] * 2.5e-4  # the worst direction, 0.25 mm
    T1 = shifted(T0, *dp)
    q1 = UR5.ik(T1, q)
    assert np.degrees(np.max(np.abs(q1 - q))) > 30  # the wrist has to spin over a quarter of a millimetre
    with pytest.raises(SafetyError, match=r"joint \d would turn at \d+ deg/s|joints would jump"):
        r.move_linear(T1, speed=0.05)
    assert calls == []


def test_joint_sweep_leaving_the_box_between_samples_is_refused(sent):
    """The old gate's 25 samples all lay inside; the arc's apex is 0.1 mm outside: conservative now."""
    q0, q1 = np.array(UR5.home), np.array(UR5.home)
    q0[0] -= 1.0 + 1.0 / 48  # the apex (joint 1 at home) falls midway between two of the 25 samples
    q1[0] += 1.0 - 1.0 / 48
    s = np.linspace(0.0, 1.0, 2001)
    x = UR5.fk(q0[None] + s[:, None] * (q1 - q0)[None])[:, 0, 3]
    x25 = UR5.fk(q0[None] + np.linspace(0, 1, 25)[:, None] * (q1 - q0)[None])[:, 0, 3]
    x_max = x.max() - 1e-4
    assert x25.max() < x_max  # the old sampled check passed this sweep
    r = make_robot(SafetyLimits(workspace_min=(-1, -1, 0), workspace_max=(x_max, 1, 1)), q_start=q0)
    calls = sent(r)
    with pytest.raises(SafetyError, match=r"joint move at \d+% of the motion .* outside .*axis x"):
        r.move_joint(q1, speed=0.5)
    assert calls == []
    r2 = make_robot(SafetyLimits(workspace_min=(-1, -1, 0), workspace_max=(x.max() + 1e-3, 1, 1)), q_start=q0)
    r2.move_joint(q1, speed=0.5)  # 1 mm of margin: provably inside, accepted


def test_unexpected_errors_inside_the_gate_become_refusals(sent, monkeypatch):
    r = make_robot()
    calls = sent(r)

    def boom(*a, **k):
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(r.gate, "_newton", boom)
    with pytest.raises(SafetyError, match="could not be completed .*LinAlgError"):
        r.move_linear(shifted(r.state().T_base_tcp, dz=0.02), speed=0.05)
    assert calls == []


@pytest.mark.parametrize(
    "field, value",
    [
        ("workspace_min", (float("nan"), -1.0, 0.0)),
        ("workspace_max", (1.0, 1.0, float("inf"))),
        ("max_linear_speed", float("inf")),
        ("max_linear_speed", "1e400 m/s"),
        ("max_angular_speed", float("nan")),
        ("path_check_step", float("inf")),
        ("path_check_step", "0.001 mm"),
    ],
)
def test_non_finite_or_unbounded_limits_are_refused_by_the_profile(field, value):
    from pydantic import ValidationError

    with pytest.raises(ValidationError) as e:
        SafetyLimits(**{field: value})
    assert field in str(e.value)


def test_lever_bounds_cover_every_configuration():
    for name in ("ur5", "ur10e", "abb-irb2600", "franka-panda"):
        m = get_model(name)
        bound = m.joint_lever_bounds()
        rng = np.random.default_rng(3)
        q = m.joint_limits[:, 0] + (m.joint_limits[:, 1] - m.joint_limits[:, 0]) * rng.random((100, m.dof))
        for qi in q:
            F, J = m.fk_jacobian(qi)
            np.testing.assert_allclose(J, m.jacobian(qi), atol=1e-12)
            lever = np.linalg.norm(J[:3], axis=0)  # |z_i x (p - o_i)|: distance from axis i
            assert np.all(lever <= bound + 1e-12)
