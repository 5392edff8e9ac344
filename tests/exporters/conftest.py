"""Weld paths for the exporter tests: a straight fillet seam and a closed saddle-like circle, placed where
the UR5 (near the base) or the IRB 2600 (further out) reach them, with planned poses as dense as the
demo's (0.33 mm and 1.6 mm apart)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from weldcell.sdk.geometry import frame_from_axes
from weldcell.sdk.weldpath import SeamPath, WeldPath

WIDE = {"workspace_min": [-2.0, -2.0, -0.5], "workspace_max": [2.0, 2.0, 2.0]}  # the IRB 2600's cell


def torch_poses(points: np.ndarray, approach) -> np.ndarray:
    travel = np.gradient(points, axis=0)
    return np.stack([frame_from_axes(t, approach, p) for t, p in zip(travel, points, strict=True)])


def weld_path(x0: float, z0: float, n_line: int = 600, n_circle: int = 199) -> WeldPath:
    p0 = np.column_stack([np.full(n_line, x0), np.linspace(-0.1, 0.1, n_line), np.full(n_line, z0)])
    s0 = SeamPath("s0", "fillet", p0, torch_poses(p0, [0.0, 1.0, -1.0]), extra={"weld_speed": 0.008})
    a = np.linspace(0, 2 * np.pi, n_circle + 1)[:-1]
    wave = z0 + 0.02 + 0.01 * np.sin(2 * a)
    p1 = np.column_stack([x0 - 0.15 + 0.05 * np.cos(a), 0.2 + 0.05 * np.sin(a), wave])
    s1 = SeamPath("s1", "saddle", p1, torch_poses(p1, [0.3, -0.2, -1.0]), closed=True)
    return WeldPath([s0, s1], frame="base")


@pytest.fixture(scope="session")
def ur_path() -> WeldPath:
    return weld_path(0.45, 0.1)


@pytest.fixture(scope="session")
def abb_path() -> WeldPath:
    return weld_path(1.0, 0.4)


@pytest.fixture(scope="session")
def ur_doc(ur_path) -> dict:
    """The UR path's JSON document (made once; copy it before changing it)."""
    return ur_path.to_json()


@pytest.fixture(scope="session")
def abb_doc(abb_path) -> dict:
    return abb_path.to_json()


def dense(poses: np.ndarray, step: float) -> tuple[np.ndarray, Rotation]:
    """A path of straight lines + slerp between ``poses`` sampled at most ``step`` metres apart."""
    P = np.asarray(poses)
    L = np.linalg.norm(np.diff(P[:, :3, 3], axis=0), axis=1)
    n = np.maximum(2, np.ceil(L / step).astype(int) + 1)
    seg = np.repeat(np.arange(len(L)), n)
    s = np.concatenate([np.linspace(0.0, 1.0, k) for k in n])
    R = Rotation.from_matrix(P[:, :3, :3])
    turn = (R[:-1].inv() * R[1:]).as_rotvec()  # the short way round, as a slerp turns
    pos = P[seg, :3, 3] + s[:, None] * (P[seg + 1, :3, 3] - P[seg, :3, 3])
    return pos, R[seg] * Rotation.from_rotvec(turn[seg] * s[:, None])


def path_gap(planned: np.ndarray, executed: np.ndarray, step: float = 2e-5) -> tuple[float, float]:
    """Largest distance (m) and torch angle (rad) between two interpolated paths, both ways: every dense
    sample of one matched to the nearest dense sample of the other."""
    pa, ra = dense(planned, step)
    pb, rb = dense(executed, step)
    worst_d, worst_a = 0.0, 0.0
    for (p, r), (q, s) in (((pa, ra), (pb, rb)), ((pb, rb), (pa, ra))):
        d, idx = cKDTree(q).query(p)
        worst_d = max(worst_d, float(d.max()))
        worst_a = max(worst_a, float((r.inv() * s[idx]).magnitude().max()))
    return worst_d, worst_a
