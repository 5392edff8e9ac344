"""Rigid transforms, rotations and poses: round trips, conventions and the errors users hit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from weldcell.sdk import geometry as g

RNG = np.random.default_rng(1234)


def random_T(rng=RNG) -> np.ndarray:
    return g.make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-1, 1, 3))


@pytest.fixture(params=range(5))
def T(request):
    return random_T(np.random.default_rng(request.param))


def test_make_T_and_conventions():
    R = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    T_a_b = g.make_T(R, [1.0, 2.0, 3.0])
    # p_a = T_a_b @ p_b: the x axis of b lies along y of a, offset by t
    np.testing.assert_allclose(g.transform_points(T_a_b, [[1.0, 0.0, 0.0]]), [[1.0, 3.0, 3.0]], atol=1e-12)
    np.testing.assert_allclose(g.transform_vectors(T_a_b, [[1.0, 0.0, 0.0]]), [[0.0, 1.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(g.make_T(), np.eye(4))
    np.testing.assert_allclose(g.make_T(t=(1, 2, 3))[:3, 3], [1, 2, 3])


def test_invert_is_exact(T):
    np.testing.assert_allclose(g.invert(T) @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(g.invert(T), np.linalg.inv(T), atol=1e-12)
    pts = RNG.normal(size=(10, 3))
    np.testing.assert_allclose(g.transform_points(g.invert(T), g.transform_points(T, pts)), pts, atol=1e-12)


def test_is_rigid_and_orthonormalize(T):
    assert g.is_rigid(T)
    bad = T.copy()
    bad[:3, :3] *= 1.01
    assert not g.is_rigid(bad)
    mirror = T.copy()
    mirror[:3, 0] *= -1
    assert not g.is_rigid(mirror)  # det -1
    assert not g.is_rigid(np.full((4, 4), np.nan)) and not g.is_rigid(np.eye(3))
    noisy = T[:3, :3] + RNG.normal(scale=1e-3, size=(3, 3))
    R = g.orthonormalize(noisy)
    assert g.is_rigid(g.make_T(R))
    assert g.rotation_angle(R.T @ T[:3, :3]) < 5e-3


def test_orthonormalize_never_returns_a_reflection():
    R = g.orthonormalize(-np.eye(3))
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_rpy_round_trip_and_order():
    rpy = np.array([0.3, -0.4, 1.2])
    T = g.T_from_rpy(rpy, [1, 2, 3])
    # extrinsic x-y-z: R = Rz(yaw) Ry(pitch) Rx(roll)
    Rz = Rotation.from_euler("z", 1.2).as_matrix()
    Ry = Rotation.from_euler("y", -0.4).as_matrix()
    Rx = Rotation.from_euler("x", 0.3).as_matrix()
    np.testing.assert_allclose(T[:3, :3], Rz @ Ry @ Rx, atol=1e-12)
    np.testing.assert_allclose(g.T_to_rpy(T), rpy, atol=1e-12)
    np.testing.assert_allclose(
        g.T_to_rpy(g.T_from_rpy([10, 20, 30], degrees=True), degrees=True), [10, 20, 30]
    )


def test_pose7_round_trip_with_positive_w(T):
    p = g.T_to_pose7(T)
    assert p.shape == (7,) and p[6] >= 0
    assert np.linalg.norm(p[3:]) == pytest.approx(1.0)
    np.testing.assert_allclose(g.T_from_pose7(p), T, atol=1e-12)
    q_neg = np.concatenate([p[:3], -p[3:]])  # the same rotation
    np.testing.assert_allclose(g.T_from_pose7(q_neg), T, atol=1e-12)


def test_quaternion_order_is_xyzw():
    T = g.T_from_quat([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])  # 90 deg about z
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_ur_pose_round_trip(T):
    ur = g.T_to_ur_pose(T)
    np.testing.assert_allclose(ur[:3], T[:3, 3])
    assert np.linalg.norm(ur[3:]) <= np.pi + 1e-9
    np.testing.assert_allclose(g.T_from_ur_pose(ur), T, atol=1e-12)


def test_ur_pose_known_value():
    # UR's own example convention: a rotation vector [0, pi, 0] flips the tool to point down
    T = g.T_from_ur_pose([0.4, -0.1, 0.3, 0.0, np.pi, 0.0])
    np.testing.assert_allclose(T[:3, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [0.4, -0.1, 0.3])


def test_rotation_angle_and_pose_error():
    T0 = g.T_from_rotvec([0, 0, 0.3], [1, 0, 0])
    T1 = g.T_from_rotvec([0, 0, 0.5], [1, 0.003, 0.004])
    assert g.rotation_angle(T1[:3, :3]) == pytest.approx(0.5)
    dt, dr = g.pose_error(T1, T0)
    assert dt == pytest.approx(0.005) and dr == pytest.approx(0.2)
    assert g.rotation_angle(g.T_from_rotvec([np.pi, 0, 0])[:3, :3]) == pytest.approx(np.pi)


def test_skew_is_the_cross_product():
    a, b = RNG.normal(size=3), RNG.normal(size=3)
    np.testing.assert_allclose(g.skew(a) @ b, np.cross(a, b), atol=1e-12)
    np.testing.assert_allclose(g.skew(a).T, -g.skew(a))


def test_slerp_and_interpolate_poses():
    T0 = g.T_from_rotvec([0, 0, 0], [0, 0, 0])
    T1 = g.T_from_rotvec([0, 0, 1.0], [1, 2, 0])
    Ts = g.interpolate_poses(T0, T1, [0.0, 0.25, 0.5, 1.0, 1.5])
    assert Ts.shape == (5, 4, 4)
    np.testing.assert_allclose(Ts[0], T0, atol=1e-12)
    np.testing.assert_allclose(Ts[3], T1, atol=1e-12)
    np.testing.assert_allclose(Ts[4], T1, atol=1e-12)  # clipped to [0, 1]
    np.testing.assert_allclose(Ts[2][:3, 3], [0.5, 1.0, 0.0])
    assert g.rotation_angle(Ts[1][:3, :3]) == pytest.approx(0.25)  # constant angular rate
    assert all(g.is_rigid(T) for T in Ts)
    Rs = g.slerp_rotations(T0, T1, 0.5)
    assert Rs.shape == (1, 3, 3) and g.rotation_angle(Rs[0]) == pytest.approx(0.5)


def test_frame_from_axes_is_a_right_handed_torch_frame():
    z = np.array([0.0, 0.0, -1.0])  # approach: down into the work
    x = np.array([1.0, 0.0, 0.3])  # travel, not quite perpendicular
    T = g.frame_from_axes(x, z, origin=[0.1, 0.2, 0.3])
    assert g.is_rigid(T)
    np.testing.assert_allclose(T[:3, 2], z)
    np.testing.assert_allclose(T[:3, 0], [1, 0, 0], atol=1e-12)  # x projected off z
    np.testing.assert_allclose(T[:3, 1], np.cross(z, T[:3, 0]))  # y = z x x
    np.testing.assert_allclose(T[:3, 3], [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="parallel"):
        g.frame_from_axes([0, 0, 2.0], z)
