"""Validation of motion-command inputs and the motion models the safety gate checks.

Used by :mod:`weldcell.hal.safety` (and re-exported there): every value a command carries is checked
here before any math (finite numbers, rigid 4x4 transforms, joint vectors, twists, blends), and the
closed-form motion of a servo command (:func:`servo_flange_pose`) is defined here, once, for the gate
and the simulated driver.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from weldcell.sdk.errors import SafetyError

ROW_TOL = 1e-9  # the last row of a transform must be [0, 0, 0, 1] within this
ORTHO_TOL = 1e-6  # max |R^T R - I| entry and |det R - 1| of a rotation
BLEND_FRACTION = 0.45  # a blend radius is at most this fraction of the shorter neighbouring segment


# ------------------------------------------------------------------------------------------ validation
def as_number(x: Any, what: str, *, unit: str, positive: bool = True) -> float:
    """``x`` as a finite float, > 0 (``positive``) or >= 0; else SafetyError."""
    kind = "positive" if positive else "non-negative"
    fix = f"give {what} as a finite number {'> 0' if positive else '>= 0'} in {unit}"
    if isinstance(x, bool | str | bytes):
        raise SafetyError(f"{what} must be a {kind} number in {unit}, got {x!r}", fix)
    try:
        v = float(x)
    except (TypeError, ValueError, OverflowError):
        raise SafetyError(
            f"{what} must be a {kind} number in {unit}, got a {type(x).__name__}", fix
        ) from None
    if not math.isfinite(v) or v < 0 or (positive and v == 0):
        raise SafetyError(f"{what} must be a finite {kind} number in {unit}, got {v}", fix)
    return v


def as_pose(T: Any, what: str = "target") -> np.ndarray:
    """``T`` as a float copy of a rigid 4x4 transform; SafetyError saying what is wrong otherwise.

    Refused: not numeric, not 4x4 (a 3x4 ``[R|t]`` too), NaN/inf anywhere, a last row other than
    ``[0, 0, 0, 1]``, a rotation part that is not orthonormal with determinant +1 (scaled, sheared or
    mirrored). Nothing is corrected silently.
    """
    try:
        A = np.array(T, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise SafetyError(
            f"{what} is not a 4x4 array of numbers", "pass a 4x4 homogeneous transform (metres)"
        ) from None
    if A.shape != (4, 4):
        fix = "pass a 4x4 homogeneous transform"
        if A.shape == (3, 4):
            fix += " (append the row [0, 0, 0, 1] to a 3x4 [R|t])"
        raise SafetyError(f"{what} has shape {A.shape}, not (4, 4)", fix)
    if not np.all(np.isfinite(A)):
        raise SafetyError(f"{what} contains NaN or infinite values", "check where the pose was computed")
    if np.max(np.abs(A[3] - (0.0, 0.0, 0.0, 1.0))) > ROW_TOL:
        raise SafetyError(
            f"{what} has last row {np.round(A[3], 6).tolist()}, not [0, 0, 0, 1]",
            "pass a homogeneous rigid transform",
        )
    R = A[:3, :3]
    with np.errstate(all="ignore"):
        ortho = float(np.max(np.abs(R.T @ R - np.eye(3))))
        det = float(np.linalg.det(R)) if ortho < 1.0 else float("nan")
    if not ortho <= ORTHO_TOL:
        raise SafetyError(
            f"{what} has a rotation that is not orthonormal (|R^T R - I| = {ortho:.3g}: scaled or sheared); "
            "a controller would read it as a different pose",
            "build rotations from quaternions/rotation vectors (weldcell.sdk.geometry), or orthonormalize "
            "them where they are made: the gate does not correct them",
        )
    if not abs(det - 1.0) <= 3 * ORTHO_TOL:
        raise SafetyError(
            f"{what} has a mirrored rotation (det R = {det:.3g})", "use a right-handed rotation (det +1)"
        )
    return A


def as_joints(q: Any, dof: int | None, what: str = "joint target") -> np.ndarray:
    """``q`` as a finite float vector of ``dof`` values (rad); SafetyError otherwise."""
    try:
        v = np.array(q, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise SafetyError(
            f"{what} is not a vector of numbers", "give one angle per joint, in radians"
        ) from None
    if v.ndim != 1 or (dof is not None and v.shape != (dof,)):
        want = f"{dof} joint values" if dof is not None else "a 1-D vector"
        raise SafetyError(
            f"{what} has shape {v.shape}; expected {want}", "give one angle per joint, in radians"
        )
    if not np.all(np.isfinite(v)):
        raise SafetyError(f"{what} contains NaN or infinite values", "give finite joint angles in radians")
    return v


def as_twist(twist: Any) -> np.ndarray:
    """A velocity command as a finite 6-vector ``[vx, vy, vz, wx, wy, wz]``; SafetyError otherwise."""
    try:
        tw = np.array(twist, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise SafetyError(
            "velocity command is not 6 numbers", "pass [vx, vy, vz, wx, wy, wz] (m/s, rad/s)"
        ) from None
    if tw.size != 6 or tw.ndim > 2:
        raise SafetyError(
            f"velocity command has shape {tw.shape}, not 6 values",
            "pass [vx, vy, vz, wx, wy, wz] (m/s, rad/s)",
        )
    tw = tw.reshape(6)
    if not np.all(np.isfinite(tw)):
        raise SafetyError("velocity command has NaN or infinite values", "check the servo's inputs")
    return tw


def path_blends(positions: np.ndarray, blend: float) -> np.ndarray:
    """Per-waypoint blend radii of a path through ``positions`` (K, 3): ``blend`` clipped to 45 % of the
    shorter neighbouring segment, 0 at the last waypoint (the path ends there). Adapters send these."""
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    out = np.full(len(p), float(blend))
    if len(p) > 1:
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        out = np.minimum(out, BLEND_FRACTION * np.minimum(np.append(seg, np.inf), np.insert(seg, 0, np.inf)))
    out[-1] = 0.0
    return np.maximum(out, 0.0)


def _rodrigues(w: np.ndarray, t: float) -> np.ndarray:
    """exp([w] t) for an angular velocity ``w`` (rad/s)."""
    th = float(np.linalg.norm(w)) * t
    if th < 1e-15:
        return np.eye(3)
    k = w / np.linalg.norm(w)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(th) * K + (1.0 - math.cos(th)) * (K @ K)


def _log_rot(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (robust near 0 and pi)."""
    c = min(1.0, max(-1.0, (float(np.trace(R)) - 1.0) / 2.0))
    th = math.acos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-7:
        return 0.5 * v
    if math.pi - th < 1e-4:  # near pi: axis from the symmetric part
        B = (R + np.eye(3)) / 2.0
        k = B[int(np.argmax(np.diag(B)))]
        k = k / np.linalg.norm(k)
        if k @ v < 0:
            k = -k
        return k * th
    return v * (th / (2.0 * math.sin(th)))


def servo_flange_pose(T0_flange: np.ndarray, flange_twist: np.ndarray, t: float) -> np.ndarray:
    """Flange pose after holding the flange twist ``[v, w]`` (base frame) for ``t`` s: the flange origin
    moves on a straight line at ``v`` while the orientation turns at ``w`` (``R = exp([w] t) R0``).

    This is what a controller's ``speedl``-style command and :class:`~weldcell.hal.sim.devices.SimRobot`
    execute; the gate checks exactly this motion.
    """
    out = np.array(T0_flange, dtype=float)
    out[:3, :3] = _rodrigues(flange_twist[3:], t) @ out[:3, :3]
    out[:3, 3] = out[:3, 3] + flange_twist[:3] * t
    return out
