"""Quasi-static contact model of the SRM soft finger tip against a seam's side wall (paper 003 §2.2.1).

Documented simplifications (the real metamaterial finger of ref. [35] is non-linear):

* The finger is a linear spring per tool axis, ``K = diag(k_x, k_y, k_z)`` in the tool frame, acting on a
  spherical tip of radius ``tip_radius`` whose rest centre is the TCP (``P_r`` of eq. 14-15).
* The wall is a rigid vertical ribbon of height ``wall_height`` standing on the seam polyline, with a
  horizontal outward normal on the free side. Its ends are vertical edges (the tip rolls round them, so
  contact fades out over one tip radius at the end of the seam instead of vanishing in one step).
* Contact is frictional (Coulomb, coefficient ``friction``) while the tip slides along the wall: the
  friction force opposes the sliding velocity and bends the finger backwards, giving the tangential δ
  that eq. 15 corrects for.
* Equilibrium: deflection ``u = K⁻¹ λ (n + μ s)`` with the normal force ``λ`` fixed by the contact
  constraint ``n·u = p`` (penetration p of the undeformed tip into the wall), i.e. the tip ends on the wall.
* The tag, glued inside the finger, translates by ``tag_gain`` times the tip's lateral deflection,
  ``tag_axial_gain`` times its axial one, and tilts by ``tag_tilt_gain`` rad per metre of bending.

Sign convention: ``deflection`` u is the tip's displacement from rest (pushed out of the wall);
the paper's δ (eq. 15, P_r = P_s + δ) is ``-u`` projected into the working plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import make_T

from .paths import Polyline, vertex_normals


@dataclass(frozen=True)
class SRMParams:
    """Mechanical parameters of the soft finger (SI)."""

    tip_radius: float = 0.002
    stiffness: tuple[float, float, float] = (400.0, 400.0, 2000.0)  # N/m along tool x, y, z
    friction: float = 0.15
    max_deflection: float = 0.006
    wall_height: float = 0.015
    tag_gain: float = 0.85
    tag_axial_gain: float = 0.6
    tag_tilt_gain: float = 15.0  # rad per metre of lateral tip deflection

    def __post_init__(self) -> None:
        if self.tip_radius <= 0 or min(self.stiffness) <= 0 or self.max_deflection <= 0:
            raise DataError(
                "SRM parameters: tip radius, stiffnesses and max deflection must be > 0",
                "give the finger's measured stiffness (N/m) and tip radius (m)",
            )
        if self.tag_gain <= 0 or self.tag_axial_gain <= 0 or self.friction < 0:
            raise DataError(
                "SRM parameters: tag gains must be > 0 and friction >= 0",
                "calibrate the tag-to-tip gains by pressing the tip a known amount",
            )


def tip_deflection_from_tag(tag_displacement_tool: np.ndarray, params: SRMParams) -> np.ndarray:
    """Invert the tag model: tool-frame tip deflection u (3,) from the measured tag displacement."""
    d = np.asarray(tag_displacement_tool, dtype=float)
    return np.array([d[0] / params.tag_gain, d[1] / params.tag_gain, d[2] / params.tag_axial_gain])


def tag_pose(
    deflection_tool: np.ndarray,
    params: SRMParams,
    T_cam_tag_rest: np.ndarray,
    T_tool_cam: np.ndarray | None = None,
) -> np.ndarray:
    """Pose of the tag in the camera frame for a tip deflection u (tool frame)."""
    T_tool_cam = np.eye(4) if T_tool_cam is None else T_tool_cam
    u = np.asarray(deflection_tool, dtype=float)
    move_tool = np.array([params.tag_gain * u[0], params.tag_gain * u[1], params.tag_axial_gain * u[2]])
    tilt_tool = params.tag_tilt_gain * np.cross([0.0, 0.0, 1.0], np.array([u[0], u[1], 0.0]))
    R_ct = T_tool_cam[:3, :3].T
    R = Rotation.from_rotvec(R_ct @ tilt_tool).as_matrix() @ T_cam_tag_rest[:3, :3]
    return make_T(R, T_cam_tag_rest[:3, 3] + R_ct @ move_tool)


@dataclass(frozen=True)
class ContactState:
    """Result of :func:`contact`: everything in the base frame except ``deflection_tool``."""

    in_contact: bool
    penetration: float  # of the undeformed tip into the wall (m); <= 0 when free
    deflection_tool: np.ndarray  # tip displacement from rest, tool frame (3,)
    tip_position: np.ndarray  # actual tip centre (3,)
    contact_point: np.ndarray  # on the wall (3,), NaN when free
    wall_normal: np.ndarray  # outward (3,), NaN when free
    normal_force: float  # N
    overload: bool  # deflection beyond the finger's range
    at_seam_end: bool  # the tip is past an end of the seam (touching the end edge or free)
    s: float  # arc length of the nearest seam point


class Workpiece:
    """A seam polyline (N, 3) with a vertical side wall; ``wall_normals`` point out of the wall.

    Give ``wall_normals`` (N, 3) or say on which ``side`` of travel the free space is ('left'/'right');
    normals are made horizontal and unit length.
    """

    def __init__(
        self,
        seam_points: np.ndarray,
        wall_normals: np.ndarray | None = None,
        free_side: str = "right",
        wall_height: float | None = None,
    ) -> None:
        self.seam = Polyline(np.asarray(seam_points, dtype=float), "seam")
        if self.seam.points.shape[1] != 3:
            raise DataError("workpiece seam: expected (N, 3) points", "give [x, y, z] seam points in metres")
        if wall_normals is None:
            n = vertex_normals(self.seam.points, free_side)
        else:
            n = np.asarray(wall_normals, dtype=float).copy()
            if n.shape != np.asarray(seam_points).shape:
                raise DataError(
                    f"wall normals shape {n.shape} does not match seam points {np.shape(seam_points)}",
                    "give one normal per seam point",
                )
            if len(n) != len(self.seam.points):
                raise DataError("wall normals: seam has repeated points", "remove duplicate seam points")
            n[:, 2] = 0.0
            nn = np.linalg.norm(n, axis=1, keepdims=True)
            if np.any(nn < 1e-9):
                raise DataError("wall normals: a normal is vertical or zero", "normals must be horizontal")
            n = n / nn
        self.vertex_normals = n
        seg_n = np.column_stack([-self.seam.seg_dir[:, 1], self.seam.seg_dir[:, 0]])
        # segment normals on the same side as the given vertex normals
        side = np.sign(np.einsum("ij,ij->i", seg_n, 0.5 * (n[:-1, :2] + n[1:, :2])))
        side[side == 0] = 1.0
        self.segment_normals = np.column_stack([seg_n * side[:, None], np.zeros(len(seg_n))])
        self.wall_height = wall_height


def contact(
    T_base_tool: np.ndarray,
    workpiece: Workpiece,
    params: SRMParams,
    sliding_velocity: np.ndarray | None = None,
) -> ContactState:
    """Tip deflection of the finger whose undeformed tip centre is the TCP of ``T_base_tool``.

    ``sliding_velocity`` (3,) is the TCP velocity in the base frame; its component along the wall sets
    the direction of the friction force (none when omitted or zero).
    """
    T = np.asarray(T_base_tool, dtype=float)
    x = T[:3, 3]
    R = T[:3, :3]
    seam = workpiece.seam
    pr = seam.project(x)
    rho = params.tip_radius
    foot = pr.point
    height = workpiece.wall_height if workpiece.wall_height is not None else params.wall_height
    dz = x[2] - foot[2]
    free = ContactState(
        False,
        0.0,
        np.zeros(3),
        x.copy(),
        np.full(3, np.nan),
        np.full(3, np.nan),
        0.0,
        False,
        pr.before_start or pr.past_end,
        pr.s,
    )
    if dz < -rho or dz > height + rho:
        return free
    seg = pr.segment
    on_segment_interior = not (pr.before_start or pr.past_end)
    d_xy = x[:2] - foot[:2]
    if on_segment_interior:
        n = workpiece.segment_normals[seg]
        h = float(d_xy @ n[:2])
    if not on_segment_interior:
        # beyond an end: the wall's end is a vertical edge through the end point
        dist = float(np.linalg.norm(d_xy))
        end_n = workpiece.vertex_normals[0 if pr.before_start else -1]
        if dist < 1e-12 or float(d_xy @ end_n[:2]) < -1e-9:
            return free
        n = np.array([d_xy[0] / dist, d_xy[1] / dist, 0.0])
        h = dist
    p = rho - h
    if p <= 0.0:
        return free
    n_tool = R.T @ n
    Kinv = 1.0 / np.asarray(params.stiffness, dtype=float)
    s_tool = np.zeros(3)
    if sliding_velocity is not None and params.friction > 0:
        v = np.asarray(sliding_velocity, dtype=float)
        v_t = v - (v @ n) * n
        v_t[2] = 0.0
        nv = np.linalg.norm(v_t)
        if nv > 1e-6:
            s_tool = R.T @ (-v_t / nv)  # friction on the tip opposes its sliding
    direction = Kinv * (n_tool + params.friction * s_tool)
    lam = p / float(n_tool @ direction)
    u = lam * direction
    tip = x + R @ u
    return ContactState(
        True,
        p,
        u,
        tip,
        tip - rho * n,
        n,
        lam,
        bool(np.linalg.norm(u) > params.max_deflection),
        pr.before_start or pr.past_end,
        pr.s,
    )
