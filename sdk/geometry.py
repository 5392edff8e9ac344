"""Rigid transforms, rotations and poses.

Conventions (see docs/architecture.md):

* ``T_a_b`` is a 4x4 homogeneous matrix that maps frame *b* into frame *a*: ``p_a = T_a_b @ p_b``.
* Quaternions are ``[x, y, z, w]`` (scipy order).
* A *pose7* is ``[x, y, z, qx, qy, qz, qw]``; a *UR pose* is ``[x, y, z, rx, ry, rz]`` with a rotation vector.
* Everything is SI: metres and radians.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

ArrayLike = Sequence[float] | np.ndarray


def make_T(R: np.ndarray | None = None, t: ArrayLike | None = None) -> np.ndarray:
    """Build a 4x4 transform from a 3x3 rotation and a translation (either may be omitted)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = np.asarray(R, dtype=float)
    if t is not None:
        T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (exact, without a general matrix inverse)."""
    T = np.asarray(T, dtype=float)
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``T`` to an (N, 3) array of points."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    return P @ T[:3, :3].T + T[:3, 3]


def transform_vectors(T: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Rotate an (N, 3) array of direction vectors by ``T`` (no translation)."""
    V = np.asarray(vectors, dtype=float).reshape(-1, 3)
    return V @ T[:3, :3].T


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def is_rigid(T: np.ndarray, tol: float = 1e-6) -> bool:
    """True when ``T`` is a proper rigid transform (orthonormal rotation, det +1, last row 0 0 0 1)."""
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return False
    R = T[:3, :3]
    # the tests of np.allclose(..., atol=tol) (its rtol 1e-5 applies where the reference is 1), written
    # out: this runs on every ICP call and allclose costs ~20 us
    eye = np.eye(3)
    return bool(
        (np.abs(R.T @ R - eye) <= tol + 1e-5 * eye).all()
        and abs(np.linalg.det(R) - 1.0) < tol
        and (np.abs(T[3] - _LAST_ROW) <= tol + 1e-5 * _LAST_ROW).all()
    )


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """Nearest rotation matrix (SVD projection onto SO(3))."""
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=float))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def T_from_rotvec(rotvec: ArrayLike, t: ArrayLike | None = None) -> np.ndarray:
    """Transform from a rotation vector (axis * angle, rad) and a translation."""
    return make_T(Rotation.from_rotvec(np.asarray(rotvec, dtype=float)).as_matrix(), t)


def T_from_quat(quat_xyzw: ArrayLike, t: ArrayLike | None = None) -> np.ndarray:
    """Transform from a quaternion ``[x, y, z, w]`` and a translation."""
    return make_T(Rotation.from_quat(np.asarray(quat_xyzw, dtype=float)).as_matrix(), t)


def T_from_rpy(rpy: ArrayLike, t: ArrayLike | None = None, degrees: bool = False) -> np.ndarray:
    """Transform from roll, pitch, yaw (extrinsic x-y-z, i.e. ``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""
    return make_T(Rotation.from_euler("xyz", np.asarray(rpy, dtype=float), degrees=degrees).as_matrix(), t)


def T_to_rpy(T: np.ndarray, degrees: bool = False) -> np.ndarray:
    """Roll, pitch, yaw of a transform's rotation (inverse of :func:`T_from_rpy`)."""
    return Rotation.from_matrix(np.asarray(T)[:3, :3]).as_euler("xyz", degrees=degrees)


def T_from_pose7(pose: ArrayLike) -> np.ndarray:
    """Transform from ``[x, y, z, qx, qy, qz, qw]``."""
    p = np.asarray(pose, dtype=float).reshape(7)
    return T_from_quat(p[3:], p[:3])


def T_to_pose7(T: np.ndarray) -> np.ndarray:
    """``[x, y, z, qx, qy, qz, qw]`` of a transform, with ``qw >= 0``."""
    q = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return np.concatenate([np.asarray(T)[:3, 3], q])


def T_from_ur_pose(pose: ArrayLike) -> np.ndarray:
    """Transform from a UR pose ``[x, y, z, rx, ry, rz]`` (metres, rotation vector in rad)."""
    p = np.asarray(pose, dtype=float).reshape(6)
    return T_from_rotvec(p[3:], p[:3])


def T_to_ur_pose(T: np.ndarray) -> np.ndarray:
    """UR pose ``[x, y, z, rx, ry, rz]`` of a transform."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def rotation_angle(R: np.ndarray) -> float:
    """Rotation angle (rad, in [0, pi]) of a 3x3 rotation matrix."""
    c = (np.trace(np.asarray(R)[:3, :3]) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def pose_error(T_est: np.ndarray, T_ref: np.ndarray) -> tuple[float, float]:
    """Translation error (m) and rotation error (rad) between two transforms."""
    dT = invert(T_ref) @ np.asarray(T_est)
    return float(np.linalg.norm(np.asarray(T_est)[:3, 3] - np.asarray(T_ref)[:3, 3])), rotation_angle(dT)


def skew(v: ArrayLike) -> np.ndarray:
    """Skew-symmetric cross-product matrix ``[v]x``."""
    x, y, z = np.asarray(v, dtype=float).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def slerp_rotations(R0: np.ndarray, R1: np.ndarray, s: ArrayLike) -> np.ndarray:
    """Spherical linear interpolation between two rotations at fractions ``s`` (K,) -> (K, 3, 3)."""
    key = Rotation.from_matrix(np.stack([np.asarray(R0)[:3, :3], np.asarray(R1)[:3, :3]]))
    return Slerp([0.0, 1.0], key)(np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, 1.0)).as_matrix()


def interpolate_poses(T0: np.ndarray, T1: np.ndarray, s: ArrayLike) -> np.ndarray:
    """Linear translation + slerp rotation between two transforms at fractions ``s`` -> (K, 4, 4)."""
    s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, 1.0)
    Rs = slerp_rotations(T0, T1, s)
    out = np.tile(np.eye(4), (len(s), 1, 1))
    out[:, :3, :3] = Rs
    out[:, :3, 3] = (1.0 - s)[:, None] * np.asarray(T0)[:3, 3] + s[:, None] * np.asarray(T1)[:3, 3]
    return out


def frame_from_axes(x: ArrayLike, z: ArrayLike, origin: ArrayLike | None = None) -> np.ndarray:
    """Right-handed frame with the given z axis and x as close as possible to ``x`` (y = z × x)."""
    z = np.asarray(z, dtype=float)
    z = z / np.linalg.norm(z)
    x = np.asarray(x, dtype=float)
    x = x - np.dot(x, z) * z
    n = np.linalg.norm(x)
    if n < 1e-9:
        raise ValueError(
            "frame_from_axes: x is parallel to z; give a travel direction not along the approach"
        )
    x = x / n
    y = np.cross(z, x)
    return make_T(np.column_stack([x, y, z]), origin)
