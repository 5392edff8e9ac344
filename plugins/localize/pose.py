"""Planar poses of the localization: (x, y, theta) about the template's centroid c.

``P_found = M @ P_planned`` with ``M = T(c + t) R_z(theta) T(-c)`` (the paper's eq. 2, M = [R][T], written
about the centroid so that x, y and theta are decoupled); z is unchanged.
"""

from __future__ import annotations

import copy

import numpy as np

from .template import Template


def rot2(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def pose_matrix(pose, center) -> np.ndarray:
    """4x4 homogeneous M of pose (x, y, theta) about ``center`` (2,)."""
    x, y, th = (float(v) for v in pose)
    c = np.asarray(center, dtype=float)
    R = rot2(th)
    M = np.eye(4)
    M[:2, :2] = R
    M[:2, 3] = c + np.array([x, y]) - R @ c
    return M


def apply_xy(pose, center, xy: np.ndarray) -> np.ndarray:
    """Planned XY (N, 2) -> found XY under pose about center."""
    c = np.asarray(center, dtype=float)
    return (np.asarray(xy) - c) @ rot2(pose[2]).T + c + np.asarray(pose[:2])


def inverse_xy(pose, center, xy: np.ndarray) -> np.ndarray:
    """Found XY (N, 2) -> planned frame under pose about center (the inverse of :func:`apply_xy`)."""
    c = np.asarray(center, dtype=float)
    return (np.asarray(xy) - c - np.asarray(pose[:2])) @ rot2(pose[2]) + c


def transform_template(tpl: Template, pose, center=None) -> Template:
    """A copy of ``tpl`` moved by pose (about ``center``, default its centroid)."""
    c = tpl.centroid if center is None else np.asarray(center)
    out = copy.deepcopy(tpl)
    M = pose_matrix(pose, c)
    for m in out.members:
        m.outline = apply_xy(pose, c, m.outline)
    for w in out.welds:
        w.points = w.points @ M[:3, :3].T + M[:3, 3]
    return out


def wrap(theta):
    return (np.asarray(theta) + np.pi) % (2 * np.pi) - np.pi
