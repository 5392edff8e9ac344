"""Thin lap joints (issue 16): the upper plate's 2-3 mm edge face leaves its top face, a third surface
parallel to the lower plate, within the side fits' radius. The convex-lip rule of the refinement (a pipe
end's rim is no joint) must not take that face for a convex edge (``refinement._convex_share``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan.seams.model import CONVEX_DROPPED
from weldcell.plugins.scan_plan.seams.refinement import _refine_on_sides
from weldcell.plugins.scan_plan.stages import (
    BilateralDenoiser,
    BilateralSettings,
    EdgeSeamExtractor,
    EdgeSeamSettings,
)
from weldcell.sdk.cloud import PointCloud
from weldcell.testing.seam_cases import make_case, score_case

H = 0.0008  # point spacing (m)
XS = np.arange(-0.03, 0.03 + 1e-9, H)


def _face(u: np.ndarray, fixed: int, value: float, other: int, v: np.ndarray) -> np.ndarray:
    """Grid points with x in XS, coordinate ``other`` over ``v`` and coordinate ``fixed`` = ``value``."""
    X, V = np.meshgrid(XS, v, indexing="ij")
    P = np.zeros((X.size, 3))
    P[:, 0], P[:, other], P[:, fixed] = X.ravel(), V.ravel(), value
    return P


def _cloud(parts: list[tuple[np.ndarray, list[float]]]) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    P = np.vstack([p for p, _ in parts])
    N = np.vstack([np.tile(n, (len(p), 1)) for p, n in parts])
    return P + rng.normal(0.0, 1e-4, P.shape), N


def _lap(t: float) -> tuple[np.ndarray, np.ndarray]:
    """Lower plate's top (z = 0, y > 0), the upper plate's edge face (y = 0, 0 < z < t) and its top
    (z = t, y < 0): the seam is the x axis, the air at y > 0, z > 0."""
    lower = _face(XS, 2, 0.0, 1, np.arange(H / 2, 0.03, H))
    edge = _face(XS, 1, 0.0, 2, np.arange(H / 2, t, H))
    top = _face(XS, 2, t, 1, np.arange(-0.03, 0.0 + 1e-9, H))
    return _cloud([(lower, [0, 0, 1.0]), (edge, [0, 1.0, 0]), (top, [0, 0, 1.0])])


def _convex_edge() -> tuple[np.ndarray, np.ndarray]:
    """A block's edge along x: top face (z = 0, y < 0) and side face (y = 0, z < 0)."""
    top = _face(XS, 2, 0.0, 1, np.arange(-0.03, 0.0 + 1e-9, H))
    side = _face(XS, 1, 0.0, 2, np.arange(-0.03, -H / 2, H))
    return _cloud([(top, [0, 0, 1.0]), (side, [0, 1.0, 0])])


NODES = np.column_stack([np.linspace(-0.01, 0.01, 5), np.zeros(5), np.zeros(5)])


@pytest.mark.parametrize("t", [0.0025, 0.003, 0.006])
def test_a_thin_lap_plate_is_no_convex_edge(t):
    """The lap plate's top lies *in front of* the lower plate's plane by its thickness: left out of the
    plane fits, but no sign of a convex edge. Before: at 2.5-3 mm 20-30 % of the points were left out,
    and the rule (a share above ``CONVEX_DROPPED``) dropped the thin lap of evaluation case 6."""
    P, N = _lap(t)
    out = _refine_on_sides(P, N, cKDTree(P), NODES, 0.006, np.deg2rad(35.0), convex_share=True)
    assert out[2].all()  # a concave crease with two side planes at every node
    assert (out[5] < CONVEX_DROPPED).all(), out[5]


@pytest.mark.parametrize("t", [0.0025, 0.006])
def test_thin_lap_side_planes_start_from_the_majority_layer(t):
    """On the seam line (the x axis), approach the bisector (0, -1, -1)/sqrt 2. Before the side fits
    started from each side's majority layer (step rows, ``sides._step_layer``), a 2.5 mm plate's top
    tilted the lower plate's plane by 30-45 deg: the node sat 1.0-1.4 mm up the edge face, approach
    10-15 deg off. (At 3 mm the top lies at the core's edge, fewer than ``STEP_SHARE`` of the core
    points: the gate misses it and the approach is still ~6 deg off -- seams doc, sixth session.)"""
    P, N = _lap(t)
    X, A, ok = _refine_on_sides(P, N, cKDTree(P), NODES, 0.006, np.deg2rad(35.0))[:3]
    assert ok.all()
    assert np.abs(X[:, 1:]).max() < 3e-4, X
    cos = A @ np.array([0.0, -1.0, -1.0]) / np.sqrt(2.0)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 2.0, A


def test_a_convex_edge_is_still_recognised():
    """Beyond a convex edge each side runs on behind the other side's plane: the share stays above
    ``CONVEX_DROPPED`` (the rule's purpose: a pipe end's rim is no joint)."""
    P, N = _convex_edge()
    out = _refine_on_sides(P, N, cKDTree(P), NODES, 0.006, np.deg2rad(35.0), convex_share=True)
    assert (out[5] > CONVEX_DROPPED).all(), out[5]


@pytest.mark.slow
def test_thin_lap_case_6_is_found():
    """Evaluation case 6: a 2.7 mm lap joint resting on a table, RGB-D, through the default stages. Before
    the convex share told the lap plate's top from a convex edge, no seam was found."""
    case = make_case(6, 0)
    assert case.joint == "lap-thin"
    clean = BilateralDenoiser(BilateralSettings())(
        PointCloud(case.points, frame="base", viewpoints=case.viewpoints)
    )
    ex = EdgeSeamExtractor(EdgeSeamSettings())(clean)
    sc = score_case(case, [(s.points, s.normals, s.closed) for s in ex.seams])
    assert sc.f1 > 0.95, sc
