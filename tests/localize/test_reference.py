"""The as-built reference poses of the Table 1 pose error (plugins/localize/reference.py): ground truth only,
right on synthetic parts whose member offsets are known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import orthogonal_procrustes
from scipy.optimize import minimize
from shapely import distance, points
from shapely.geometry import Polygon
from weldcell.plugins.localize.pose import rot2
from weldcell.plugins.localize.reference import (
    asbuilt_pose_crossings,
    asbuilt_pose_outline,
    outline_samples,
    visible_crossings,
)
from weldcell.plugins.localize.synth import member_variations, zigzag_plan
from weldcell.plugins.localize.template import Member, Template
from weldcell.plugins.localize.workpieces import make_workpiece

PLACEMENT = np.array([0.011, -0.007, np.radians(12.0)])


def _rigid(theta: float, t, about) -> np.ndarray:
    G = np.eye(3)
    G[:2, :2] = rot2(theta)
    G[:2, 2] = np.asarray(about) + np.asarray(t) - rot2(theta) @ np.asarray(about)
    return G


def _pose_of(T: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.array([*(T[:2, :2] @ c + T[:2, 2] - c), np.arctan2(T[1, 0], T[0, 0])])


@pytest.fixture(scope="module")
def truss() -> Template:
    return make_workpiece("truss")


def test_every_member_moved_by_the_same_rigid_motion_gives_that_motion_after_the_placement(truss):
    c = truss.centroid
    G = _rigid(np.radians(0.3), [1.2e-3, -0.8e-3], c + [0.1, 0.05])  # about some other point
    expected = _pose_of(_rigid(PLACEMENT[2], PLACEMENT[:2], c) @ G, c)
    lines = zigzag_plan(truss, 0.02, 0.04)
    for ref in (
        asbuilt_pose_crossings(truss, PLACEMENT, [G] * len(truss.members), lines),
        asbuilt_pose_outline(truss, PLACEMENT, [G] * len(truss.members)),
    ):
        np.testing.assert_allclose(ref.pose, expected, atol=1e-9)
        assert ref.rms < 1e-9


def test_outline_reference_is_the_procrustes_solution_of_the_outlines(truss):
    var = member_variations(truss, np.random.default_rng(4), 2e-3)
    ref = asbuilt_pose_outline(truss, PLACEMENT, var, step=1e-3)
    P = _rigid(PLACEMENT[2], PLACEMENT[:2], truss.centroid)
    src = [outline_samples(m.outline, 1e-3) for m in truss.members]
    dst = np.concatenate([s @ (P @ V)[:2, :2].T + (P @ V)[:2, 2] for s, V in zip(src, var, strict=True)])
    src = np.concatenate(src)
    R, _ = orthogonal_procrustes(src - src.mean(axis=0), dst - dst.mean(axis=0))  # src @ R ~ dst
    T = np.eye(3)
    T[:2, :2] = R.T
    T[:2, 2] = dst.mean(axis=0) - R.T @ src.mean(axis=0)
    np.testing.assert_allclose(ref.pose, _pose_of(T, truss.centroid), atol=1e-9)
    # the members are really off: the part is no rigid copy of the CAD part, nor at the placement
    assert 0.1e-3 < ref.rms < 2e-3
    assert np.abs(ref.pose[:2] - PLACEMENT[:2]).max() > 20e-6


def test_crossing_reference_minimises_the_distances_of_the_crossings_to_the_moved_template(truss):
    """Random member offsets: the reference is the least-squares pose of the exact edge crossings against
    their CAD edges, checked by independent fits (Nelder-Mead): on the same point-to-edge-line distances,
    and on shapely's distances to the nearest outline (the same up to crossings near the members' corners)."""
    var = member_variations(truss, np.random.default_rng(7), 2e-3)
    lines = zigzag_plan(truss, 0.02, 0.04)
    ref = asbuilt_pose_crossings(truss, PLACEMENT, var, lines)
    pts, mem, seg = visible_crossings(truss, PLACEMENT, var, lines)
    assert ref.points == len(pts) > 100
    c = truss.centroid
    a = np.array([truss.members[k].outline[j] for k, j in zip(mem, seg, strict=True)])
    b = np.array([np.roll(truss.members[k].outline, -1, axis=0)[j] for k, j in zip(mem, seg, strict=True)])
    boundary = [Polygon(m.outline).exterior for m in truss.members]

    def to_template(p):
        return (pts - c - p[:2]) @ rot2(p[2]) + c

    def line_cost(p):
        q, d = to_template(p) - a, b - a
        return float((((q[:, 0] * d[:, 1] - q[:, 1] * d[:, 0]) ** 2) / (d**2).sum(axis=1)).sum()) * 1e6

    def nearest_cost(p):
        g = points(to_template(p))
        return float((np.min([distance(e, g) for e in boundary], axis=0) ** 2).sum()) * 1e6

    opts = {"xatol": 1e-9, "fatol": 1e-10}
    same = minimize(line_cost, PLACEMENT, method="Nelder-Mead", options=opts)
    np.testing.assert_allclose(ref.pose, same.x, atol=1e-7)
    assert line_cost(ref.pose) <= same.fun * (1 + 1e-9)
    simplex = PLACEMENT + np.vstack([np.zeros(3), np.diag([0.3e-3, 0.3e-3, 0.3e-3])])  # ~ the offsets' size
    near = minimize(
        nearest_cost, PLACEMENT, method="Nelder-Mead", options=opts | {"initial_simplex": simplex}
    )
    np.testing.assert_allclose(ref.pose, near.x, atol=30e-6)  # m, m, rad (0.0017 deg)
    assert np.abs(ref.pose[:2] - PLACEMENT[:2]).max() > 100e-6  # not the placement


def test_an_edge_hidden_under_a_higher_member_is_not_a_crossing():
    low = Member("plate", 0.01, np.array([[0, 0], [0.3, 0], [0.3, 0.2], [0, 0.2]]))
    high = Member("bar", 0.05, np.array([[0.2, -0.05], [0.4, -0.05], [0.4, 0.25], [0.2, 0.25]]))
    tpl = Template([low, high])
    eye = [np.eye(3), np.eye(3)]
    line = [np.array([[-0.05, 0.1], [0.45, 0.1]])]  # crosses x = 0, 0.2, 0.3 (under the bar), 0.4
    pts, mem, _ = visible_crossings(tpl, [0, 0, 0], eye, line)
    np.testing.assert_allclose(np.sort(pts[:, 0]), [0.0, 0.2, 0.4], atol=1e-12)
    assert sorted(mem.tolist()) == [0, 1, 1]


def test_too_few_crossings_cannot_fix_a_pose(truss):
    far = [np.array([[5.0, 5.0], [5.1, 5.0]])]
    with pytest.raises(ValueError, match="visible edge crossings"):
        asbuilt_pose_crossings(truss, PLACEMENT, [np.eye(3)] * len(truss.members), far)
