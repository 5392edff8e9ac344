"""Kinematic robot models of the simulated cell: FK against published values, IK, limits, motion times."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from weldcell.hal.kinematics import MODELS, get_model, trapezoid_time
from weldcell.sdk.errors import DataError, SafetyError, UsageError
from weldcell.sdk.geometry import make_T, pose_error

ANALYTIC = ["ur5", "ur10e", "aubo-i5", "abb-irb2600"]
ALL = [*ANALYTIC, "franka-panda"]


def _random_q(model, n: int, seed: int) -> np.ndarray:
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    return lo + (hi - lo) * np.random.default_rng(seed).random((n, model.dof))


# ------------------------------------------------------------------ FK against the published DH tables
def _std_dh(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    """One standard-DH link transform, written out element by element (independent of the implementation)."""
    ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


# UR's published UR5 table: d1, a2, a3, d4, d5, d6 and alpha
UR5_D = [0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823]
UR5_A = [0.0, -0.425, -0.39225, 0.0, 0.0, 0.0]
UR5_ALPHA = [math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0]


def _ur5_reference(q: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    for i in range(6):
        T = T @ _std_dh(q[i], UR5_D[i], UR5_A[i], UR5_ALPHA[i])
    return T


def test_ur5_zero_pose_matches_published_geometry() -> None:
    T = get_model("ur5").fk(np.zeros(6))
    # Written-out DH product at q = 0: x = a2 + a3, y = -(d4 + d6), z = d1 - d5, flange z along -y base.
    assert T[:3, 3] == pytest.approx([-0.81725, -0.19145, 0.089159 - 0.09465], abs=1e-9)
    assert T[:3, :3] == pytest.approx(np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]), abs=1e-12)
    assert T == pytest.approx(_ur5_reference(np.zeros(6)), abs=1e-12)


def test_ur5_fk_matches_independent_dh_product() -> None:
    m = get_model("ur5")
    # The "upright" configuration: upper arm and forearm vertical, tool sideways.
    q_up = np.array([0.0, -math.pi / 2, 0.0, -math.pi / 2, 0.0, 0.0])
    T_up = m.fk(q_up)
    # by hand: links 2-3 and d5 stack up along z (d1 + |a2| + |a3| + d5); d4 and d6 point along -y
    assert T_up[:3, 3] == pytest.approx(
        [0.0, -(0.10915 + 0.0823), 0.089159 + 0.425 + 0.39225 + 0.09465], abs=1e-9
    )
    for q in _random_q(m, 20, seed=3):
        assert m.fk(q) == pytest.approx(_ur5_reference(q), abs=1e-12)
    # batched FK agrees with single FK
    Q = _random_q(m, 5, seed=4)
    assert m.fk(Q) == pytest.approx(np.stack([m.fk(q) for q in Q]), abs=1e-14)


@pytest.mark.parametrize(
    ("name", "position", "z_axis"),
    [
        # UR10e table: a2 + a3, -(d4 + d6), d1 - d5
        ("ur10e", [-1.18425, -0.2907, 0.1807 - 0.11985], [0, -1, 0]),
        # Panda modified DH: a7 = 0.088 forward, 0.333 + 0.316 + 0.384 - 0.107 up, flange pointing down
        ("franka-panda", [0.088, 0.0, 0.926], [0, 0, -1]),
        # AUBO i5: arm straight up, d1 + a2 + a3 + d5 high, d2 + d6 sideways
        ("aubo-i5", [0.0, -(0.1215 + 0.094), 0.122 + 0.408 + 0.376 + 0.1025], [0, -1, 0]),
        # ABB IRB 2600-12/1.65 calibration position: 150 + 795 + 85 mm forward, 445 + 700 + 115 mm up,
        # tool0 z along base x (RAPID tool0 orientation [0.7071, 0, 0.7071, 0])
        ("abb-irb2600", [1.030, 0.0, 1.260], [1, 0, 0]),
    ],
)
def test_zero_pose_of_every_model_matches_its_published_dimensions(name, position, z_axis) -> None:
    T = get_model(name).fk(np.zeros(get_model(name).dof))
    assert T[:3, 3] == pytest.approx(position, abs=1e-9)
    assert T[:3, 2] == pytest.approx(z_axis, abs=1e-12)


def test_fk_all_chains_to_the_flange() -> None:
    for name in ALL:
        m = get_model(name)
        q = _random_q(m, 1, seed=8)[0]
        F = m.fk_all(q)
        assert F.shape == (m.dof + 2, 4, 4)
        assert F[0] == pytest.approx(np.eye(4))
        assert F[-1] == pytest.approx(m.fk(q), abs=1e-14)


# ------------------------------------------------------------------ IK
@pytest.mark.parametrize("name", ALL)
def test_ik_round_trip_200_random_configurations(name: str) -> None:
    m = get_model(name)
    tol = 1e-5 if name == "franka-panda" else 1e-6
    worst_p = worst_r = 0.0
    for q in _random_q(m, 200, seed=11):
        T = m.fk(q)
        qs = m.ik(T)
        assert m.within_limits(qs)
        dp, dr = pose_error(m.fk(qs), T)
        worst_p, worst_r = max(worst_p, dp), max(worst_r, dr)
    assert worst_p < tol
    assert worst_r < tol


def test_ur5_ik_all_returns_eight_distinct_solutions_reproducing_the_pose() -> None:
    m = get_model("ur5")
    q = np.array([0.3, -1.2, 1.4, -0.9, 1.1, 0.4])
    T = m.fk(q)
    sols = m.ik_all(T)
    assert len(sols) == 8
    for s in sols:
        dp, dr = pose_error(m.fk(s), T)
        assert dp < 1e-9 and dr < 1e-7
    wrapped = (sols + math.pi) % (2 * math.pi) - math.pi
    for i in range(8):
        for j in range(i + 1, 8):
            assert np.max(np.abs(wrapped[i] - wrapped[j])) > 1e-3
    # the configuration we started from is one of them (modulo 2 pi)
    d = (sols - q + math.pi) % (2 * math.pi) - math.pi
    assert np.min(np.max(np.abs(d), axis=1)) < 1e-8


@pytest.mark.parametrize("name", ANALYTIC)
def test_ik_all_solutions_all_reproduce_the_pose(name: str) -> None:
    m = get_model(name)
    counts = []
    for q in _random_q(m, 20, seed=21):
        T = m.fk(q)
        sols = m.ik_all(T, within_limits_only=False)
        counts.append(len(sols))
        assert 1 <= len(sols) <= 8
        for s in sols:
            assert max(pose_error(m.fk(s), T)) < 1e-7
    assert max(counts) == 8  # generic poses have the full set of closed-form branches


def test_ik_returns_the_solution_nearest_the_seed() -> None:
    m = get_model("ur5")
    q = np.array([0.3, -1.2, 1.4, -0.9, 1.1, 0.4])
    T = m.fk(q)
    assert m.ik(T, q + 0.05) == pytest.approx(q, abs=1e-9)
    sols = m.ik_all(T)
    for s in sols:  # seeded at any branch, IK stays on that branch
        assert m.ik(T, s + 0.01) == pytest.approx(s, abs=1e-9)


def test_panda_ik_stays_near_the_seed() -> None:
    m = get_model("franka-panda")
    q = m.home + np.array([0.1, 0.1, -0.1, 0.2, 0.1, -0.1, 0.2])
    qs = m.ik(m.fk(q), q + 0.01)
    assert np.max(np.abs(qs - q)) < 0.1
    assert max(pose_error(m.fk(qs), m.fk(q))) < 1e-6


@pytest.mark.parametrize("name", ALL)
def test_out_of_reach_target_raises_safety_error(name: str) -> None:
    m = get_model(name)
    T = make_T(np.diag([1.0, -1.0, -1.0]), [2.5 * m.reach, 0.3, 0.4])
    assert not m.in_reach(T[:3, 3])
    with pytest.raises(SafetyError, match="reach") as err:
        m.ik(T)
    assert f"{np.linalg.norm(T[:3, 3]):.3f} m from the base" in err.value.message
    assert m.in_reach(m.fk(m.home)[:3, 3])


def test_joint_limit_violation_detected() -> None:
    m = get_model("abb-irb2600")
    q = np.radians([10.0, 20.0, -30.0, 0.0, 125.0, 0.0])  # axis 5 is limited to +-120 deg
    assert not m.within_limits(q)
    assert m.within_limits(np.radians([10.0, 20.0, -30.0, 0.0, 115.0, 0.0]))
    (msg,) = m.limit_violations(q)
    assert "joint 5" in msg and "125.0" in msg
    with pytest.raises(SafetyError, match="joint 5"):
        m.check_limits(q)
    # A pose only reachable with axis 5 beyond its limit: IK says so (not "out of reach").
    T = m.fk(q)
    assert len(m.ik_all(T, within_limits_only=False)) > 0
    assert len(m.ik_all(T)) == 0
    with pytest.raises(SafetyError, match="within joint limits"):
        m.ik(T)
    panda = get_model("panda")
    assert not panda.within_limits(np.array([0, 0, 0, 0.1, 0, 1.0, 0]))  # joint 4 must stay below -0.0698


def test_bad_inputs_are_reported() -> None:
    m = get_model("ur5")
    with pytest.raises(UsageError):
        m.fk(np.zeros(5))
    with pytest.raises(UsageError):
        m.fk([0, 0, np.nan, 0, 0, 0])
    with pytest.raises(UsageError, match="orthonormal"):
        m.ik(np.diag([2.0, 1.0, 1.0, 1.0]))


# ------------------------------------------------------------------ Jacobian
def _log_so3(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_rotvec()


@pytest.mark.parametrize("name", ALL)
def test_jacobian_matches_finite_differences(name: str) -> None:
    m = get_model(name)
    h = 1e-6
    for q in _random_q(m, 5, seed=31):
        J = m.jacobian(q)
        T = m.fk(q)
        Jn = np.zeros((6, m.dof))
        for i in range(m.dof):
            dq = np.zeros(m.dof)
            dq[i] = h
            Tp, Tm = m.fk(q + dq), m.fk(q - dq)
            Jn[:3, i] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            Jn[3:, i] = (_log_so3(Tp[:3, :3] @ T[:3, :3].T) - _log_so3(Tm[:3, :3] @ T[:3, :3].T)) / (2 * h)
        assert J == pytest.approx(Jn, abs=1e-6)


# ------------------------------------------------------------------ motion times
@pytest.mark.parametrize("name", ALL)
def test_joint_move_time_positive_monotone_and_within_speed_limits(name: str) -> None:
    m = get_model(name)
    direction = np.linspace(1.0, -0.5, m.dof)
    times = [m.joint_move_time(m.home, m.home + s * direction * 0.1) for s in (0.01, 0.1, 0.5, 1.0, 2.0)]
    assert times[0] > 0
    assert all(b > a for a, b in zip(times, times[1:], strict=False))
    assert m.joint_move_time(m.home, m.home) == 0.0
    q1 = m.home + 0.2 * direction
    t = m.joint_move_time(m.home, q1)
    # never faster than the slowest joint at its top speed
    assert t >= np.max(np.abs(q1 - m.home) / m.joint_speed_limits) - 1e-12
    # speed scaling stretches time exactly
    assert m.joint_move_time(m.home, q1, speed_scale=0.5) == pytest.approx(2 * t)
    # the sampled profile respects every joint's speed and acceleration limit and ends at the target
    ts, Q = m.sample_joint_move(m.home, q1, dt=0.002)
    assert ts[-1] == pytest.approx(t)
    assert Q[-1] == pytest.approx(q1)
    v = np.diff(Q, axis=0) / np.diff(ts)[:, None]
    assert np.all(np.abs(v) <= m.joint_speed_limits * (1 + 1e-6))
    # one joint alone for a long move reaches exactly its top speed: D / v + v / a
    q2 = m.home.copy()
    q2[0] += 1.0
    v0, a0 = m.joint_speed_limits[0], m.joint_accel_limits[0]
    assert m.joint_move_time(m.home, q2) == pytest.approx(1.0 / v0 + v0 / a0)
    with pytest.raises(UsageError):
        m.joint_move_time(m.home, q1, speed_scale=1.5)


def test_linear_move_time_trapezoid() -> None:
    m = get_model("ur10e")
    T0 = m.fk(m.home)
    T1 = T0.copy()
    T1[0, 3] += 0.5
    assert m.linear_move_time(T0, T1, 0.25, 1.0) == pytest.approx(0.5 / 0.25 + 0.25 / 1.0)
    T2 = T0.copy()
    T2[0, 3] += 0.01
    assert m.linear_move_time(T0, T2, 0.25, 1.0) == pytest.approx(2 * math.sqrt(0.01 / 1.0))
    times = [
        m.linear_move_time(T0, make_T(T0[:3, :3], T0[:3, 3] + [d, 0, 0]), 0.5, 1.0) for d in (0.01, 0.1, 0.4)
    ]
    assert 0 < times[0] < times[1] < times[2]
    # a pure rotation is limited by the rotation speed
    T3 = T0 @ make_T(Rotation.from_rotvec([0, 0, 1.0]).as_matrix())
    assert m.linear_move_time(T0, T3, 0.5, 1.0, rot_speed=0.5, rot_accel=5.0) == pytest.approx(
        float(trapezoid_time(1.0, 0.5, 5.0))
    )
    with pytest.raises(SafetyError, match="exceeds"):
        m.linear_move_time(T0, T1, 2.0, 1.0)


# ------------------------------------------------------------------ straight-line paths
def test_linear_path_joints_follows_the_line() -> None:
    for name in ("ur5", "franka-panda", "abb-irb2600"):
        m = get_model(name)
        T0 = m.fk(m.home)
        T1 = T0 @ make_T(Rotation.from_rotvec([0, 0, 0.3]).as_matrix(), [0.1, -0.05, 0.05])
        Q = m.linear_path_joints(T0, T1, m.home)
        assert len(Q) == math.ceil(np.linalg.norm(T1[:3, 3] - T0[:3, 3]) / 0.005) + 1  # 5 mm steps
        assert np.max(np.abs(np.diff(Q, axis=0))) < 0.05
        F = m.fk(Q)
        p0, p1 = T0[:3, 3], T1[:3, 3]
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        off = (F[:, :3, 3] - p0) - ((F[:, :3, 3] - p0) @ u)[:, None] * u
        assert np.max(np.linalg.norm(off, axis=1)) < 1e-6
        assert max(pose_error(F[-1], T1)) < 1e-6


def test_linear_path_through_unreachable_region_is_refused() -> None:
    m = get_model("ur5")
    down = np.diag([1.0, -1.0, -1.0])
    T0 = make_T(down, [0.4, 0.2, 0.3])
    T1 = make_T(down, [-0.4, -0.2, 0.3])  # the straight line passes over the base, where the wrist cannot go
    m.ik(T0)
    m.ik(T1)
    with pytest.raises(SafetyError, match=r"fails at \d+% of the way") as err:
        m.linear_path_joints(T0, T1, m.ik(T0))
    pct = int(err.value.message.split("fails at ")[1].split("%")[0])
    assert 20 <= pct <= 50


def test_linear_path_through_wrist_singularity_is_refused() -> None:
    m = get_model("abb-irb2600")
    # tool pointing along the forearm (axis 5 = 0) midway: the wrist flips axes 4 and 6 by ~180 deg
    q0 = np.radians([0.0, 10.0, 10.0, 60.0, 10.0, 0.0])
    q1 = np.radians([0.0, 10.0, 10.0, 60.0, -10.0, 0.0])
    T0, T1 = m.fk(q0), m.fk(q1)
    with pytest.raises(SafetyError, match="jumps"):
        m.linear_path_joints(T0, T1, q0)


# ------------------------------------------------------------------ registry
def test_models_registry_and_aliases() -> None:
    assert set(MODELS) == {"ur5", "ur10e", "franka-panda", "aubo-i5", "abb-irb2600"}
    assert get_model("panda") is get_model("franka") is MODELS["franka-panda"]
    assert get_model("UR10e").dof == 6 and get_model("franka-panda").dof == 7
    with pytest.raises(DataError, match="available") as err:
        get_model("ur-5")
    assert "ur5" in (err.value.fix or "")


@pytest.mark.parametrize("name", ALL)
def test_home_is_a_safe_ready_pose_over_a_table_in_front(name: str) -> None:
    m = get_model(name)
    T = m.fk(m.home)
    assert m.within_limits(m.home, margin=np.radians(5))
    assert T[:3, 2] == pytest.approx([0, 0, -1], abs=1e-9)  # tool pointing straight down
    assert T[0, 3] > 0.25 and T[2, 3] > 0.3  # in front (+x) and above the base
    assert np.linalg.matrix_rank(m.jacobian(m.home), tol=1e-3) == 6  # away from singularities
