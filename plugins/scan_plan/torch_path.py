"""6-DOF torch path along a weld seam (paper 000, section II-F, eqs. 18-19) and the
``weldcell/weld-path@1`` JSON format.

* torch point: the seam point moved back along the torch axis by the stand-off ``d`` (the paper's
  ``p_w = p_e + d n_pe`` with ``n`` the outward surface normal, i.e. minus our approach direction);
* frames: z = approach (towards the work), x = travel direction -- the paper's averaged moving vector
  ``m_i = (sum_{i-m/2}^{i+m/2} v_m) / m`` -- made orthogonal to z, y = z x x (the paper's
  ``o_i = m_i x n_i``); then the work angle (about x) and the travel angle (about y) are applied;
* interpolation: ``rho`` points between consecutive frames, positions linear (eq. 18), rotations by
  spherical-linear interpolation of unit quaternions (eq. 19).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.weldpath import SeamPath, WeldPath

from .seams import SeamPolyline


@dataclass
class TorchPath:
    """Interpolated torch poses ``poses`` (K, 4, 4) in the seam's frame (T_frame_torch), the matching
    torch points ``points`` (K, 3) and the seam points they aim at ``targets`` (K, 3)."""

    seam_id: int
    poses: np.ndarray
    targets: np.ndarray
    closed: bool

    @property
    def points(self) -> np.ndarray:
        """Torch (TCP) positions (K, 3)."""
        return self.poses[:, :3, 3]

    def to_pose7(self) -> list[list[float]]:
        """Poses as ``[x, y, z, qx, qy, qz, qw]`` lists."""
        q = Rotation.from_matrix(self.poses[:, :3, :3]).as_quat()
        return np.hstack([self.points, q]).tolist()


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-12)


def travel_directions(points: np.ndarray, average: int, closed: bool) -> np.ndarray:
    """Unit moving directions: the vectors between consecutive points averaged over ``average``
    neighbours (the paper's m nearest moving vectors), wrapping around for closed seams."""
    if closed:
        V = (np.roll(points, -1, axis=0) - np.roll(points, 1, axis=0)) / 2.0
    else:
        V = np.gradient(points, axis=0)  # mean of the two adjacent moving vectors, one-sided at the ends
    V = _unit(V)
    if average > 1:
        V = uniform_filter1d(V, size=int(average), axis=0, mode="wrap" if closed else "nearest")
    return _unit(V)


def torch_frames(
    seam_points: np.ndarray,
    approach: np.ndarray,
    travel: np.ndarray,
    *,
    standoff: float,
    work_angle: float = 0.0,
    travel_angle: float = 0.0,
) -> np.ndarray:
    """Torch poses (K, 4, 4): z = approach, x = travel (orthogonalised), y = z x x, rotated by the work
    angle about x and the travel angle about y (positive = push: the torch leans towards travel),
    positioned ``standoff`` back from the seam along the (tilted) torch axis."""
    z = _unit(approach)
    x = travel - np.einsum("ij,ij->i", travel, z)[:, None] * z
    bad = np.linalg.norm(x, axis=1) < 1e-6
    if bad.any():
        raise DataError(
            "the travel direction is parallel to the approach direction at some seam points",
            "check the seam normals (approach) or smooth the seam",
        )
    x = _unit(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=2)
    # intrinsic X then Y: R_x(work) @ R_y(travel), so that both angles are exactly what they are set to
    # (extrinsic "xy" leaned the torch asin(sin(travel) cos(work)) in travel: 6.58° for 7° at 20° work)
    tilt = Rotation.from_euler("XY", [work_angle, travel_angle]).as_matrix()
    R = R @ tilt
    T = np.tile(np.eye(4), (len(seam_points), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = seam_points - standoff * R[:, :, 2]
    return T


def slerp_quaternions(q0: np.ndarray, q1: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Eq. 19 on unit quaternions: ``(sin((1-a) th) q0 + sin(a th) q1) / sin th`` with
    ``th = arccos(q0 . q1)`` (shorter arc; linear blend when th ~ 0). Shapes (S, 4), (S, 4), (S, J)."""
    dot = np.einsum("ij,ij->i", q0, q1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    dot = np.abs(dot)
    th = np.arccos(np.clip(dot, -1.0, 1.0))[:, None]
    a = alpha
    small = th < 1e-6
    s = np.sin(th)
    w0 = np.where(small, 1.0 - a, np.sin((1.0 - a) * th) / np.where(small, 1.0, s))
    w1 = np.where(small, a, np.sin(a * th) / np.where(small, 1.0, s))
    q = w0[..., None] * q0[:, None, :] + w1[..., None] * q1[:, None, :]
    return _unit(q)


def interpolate_frames(T: np.ndarray, rho: int, closed: bool) -> np.ndarray:
    """Insert ``rho`` poses between consecutive frames: positions by eq. 18, rotations by eq. 19.

    The paper indexes ``p_j = p_i + j (p_{i+1} - p_i) / rho``; here the ``rho`` inserted poses are
    strictly between the two frames, at fractions ``j / (rho + 1)``, j = 1..rho.
    """
    if rho <= 0 or len(T) < 2:
        return T
    A = T if not closed else np.concatenate([T, T[:1]])
    S = len(A) - 1
    alpha = np.tile(np.arange(0, rho + 1) / (rho + 1.0), (S, 1))  # frame i itself, then rho new ones
    q = Rotation.from_matrix(A[:, :3, :3]).as_quat()
    Qs = slerp_quaternions(q[:-1], q[1:], alpha)  # (S, rho+1, 4)
    p = A[:, :3, 3]
    Ps = p[:-1, None, :] + alpha[..., None] * (p[1:] - p[:-1])[:, None, :]
    Qs, Ps = Qs.reshape(-1, 4), Ps.reshape(-1, 3)
    if not closed:
        Qs = np.vstack([Qs, q[-1:]])
        Ps = np.vstack([Ps, p[-1:]])
    out = np.tile(np.eye(4), (len(Ps), 1, 1))
    out[:, :3, :3] = Rotation.from_quat(Qs).as_matrix()
    out[:, :3, 3] = Ps
    return out


def plan_torch_path(
    seam: SeamPolyline,
    *,
    standoff: float = 0.015,
    work_angle: float = 0.0,
    travel_angle: float = 0.0,
    travel_average: int = 5,
    rho: int = 3,
) -> TorchPath:
    """Torch path along ``seam`` (eqs. 18-19).

    Args:
        standoff: contact-tip-to-work distance d (m), along the torch axis.
        work_angle: rotation about the travel axis x (rad). travel_angle: rotation about y (rad),
            positive = push (torch leaning forward), negative = drag.
        travel_average: m of the paper: number of moving vectors averaged for the travel direction.
        rho: poses inserted between consecutive seam frames (linear + slerp).
    """
    P = np.asarray(seam.points, dtype=float)
    A = np.asarray(seam.normals, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 2:
        raise DataError(
            f"seam {seam.id} needs at least 2 points (K, 3), got shape {P.shape}",
            "extract the seam again with a smaller spacing or min_seam_length",
        )
    if A.shape != P.shape or not (np.all(np.isfinite(P)) and np.all(np.isfinite(A))):
        raise DataError(
            f"seam {seam.id} has non-finite points or approach vectors of the wrong shape",
            "pass a SeamPolyline from extract_seams",
        )
    if not np.isfinite(standoff) or standoff < 0:
        raise DataError(f"standoff must be >= 0 m, got {standoff}", "use e.g. standoff=0.015 (15 mm)")
    if int(rho) < 0 or int(travel_average) < 1:
        raise DataError(
            f"rho must be >= 0 and travel_average >= 1, got {rho}, {travel_average}",
            "use rho=3, travel_average=5",
        )
    travel = travel_directions(P, int(travel_average), bool(seam.closed))
    T = torch_frames(
        P, A, travel, standoff=float(standoff), work_angle=float(work_angle), travel_angle=float(travel_angle)
    )
    poses = interpolate_frames(T, int(rho), bool(seam.closed))
    targets = poses[:, :3, 3] + float(standoff) * poses[:, :3, 2]  # where each torch axis meets the seam
    return TorchPath(seam.id, poses, targets, bool(seam.closed))


# ----------------------------------------------------------------------------- weld path


def weld_path(
    seams: list[SeamPolyline], paths: list[TorchPath], frame: str = "base", metrics: dict | None = None
) -> WeldPath:
    """The :class:`~weldcell.sdk.weldpath.WeldPath` of seams and their torch paths (one path per seam).

    Each seam keeps its estimated approach directions under ``"approach"`` (used for evaluation).
    ``WeldPath.to_json()`` gives the ``weldcell/weld-path@1`` document, ``WeldPath.from_json`` reads one.
    """
    if len(seams) != len(paths):
        raise DataError(f"{len(seams)} seams but {len(paths)} paths", "plan one torch path per seam")
    out = [
        SeamPath(
            id=f"s{s.id}",
            joint=s.joint_class,
            points=np.asarray(s.points, dtype=float),
            poses=p.poses,
            closed=bool(s.closed),
            extra={"approach": np.round(np.asarray(s.normals, dtype=float), 6).tolist()},
        )
        for s, p in zip(seams, paths, strict=True)
    ]
    return WeldPath(out, frame=frame, metrics=dict(metrics or {}))
