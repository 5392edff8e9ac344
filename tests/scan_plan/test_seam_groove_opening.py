"""Groove seams at the root opening when nothing shows through it (issue 16): an X-groove seen from one
face shows its near root's opening with the land's faces below it and nothing else within reach (the far
groove opens away from the scanner), so the slot test of ``refinement._root_opening`` (surface behind a
wall plane next to the planes' intersection) has little to see. The seam was left at the bevel planes'
intersection, ``g/2 / tan(bevel)`` below the shown root and within a few tenths of a millimetre of the
hidden far root, and was scored against that one with the approach reversed (evaluation cases 12, 45,
111). An empty root line -- no point on the planes' intersection line while the walls beside it are
sampled -- is an opening too."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from weldcell.plugins.scan_plan.seams.refinement import _mostly_straight, _root_opening

SPACING = 0.0012  # mean point spacing (m): the evaluation set's structured-light and RGB-D clouds
NOISE = 1e-4
LENGTH = 0.06
BEVEL = np.deg2rad(30.0)


def _strip(rng, a, b, normal, n_per_m2: float):
    """Points spread at random over the strip x in [-LENGTH/2, LENGTH/2] x the profile segment a -> b
    ((y, z) pairs), with the segment's normal ``normal`` ((y, z), towards the air)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    width = float(np.linalg.norm(b - a))
    n = rng.poisson(n_per_m2 * LENGTH * width)
    x = rng.uniform(-LENGTH / 2, LENGTH / 2, n)
    f = rng.uniform(0.0, 1.0, n)
    yz = a[None] + f[:, None] * (b - a)[None]
    P = np.column_stack([x, yz])
    N = np.tile([0.0, *normal], (n, 1))
    return P, N


def _groove(gap: float, land: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """The near half of an X-groove (``land`` > 0: its land's faces below the root, nothing else) or a
    closed V (``gap`` = 0): root at the origin, seam along x, air at z > 0 (the approach is -z)."""
    g2, height, density = gap / 2, 0.006, 1.0 / SPACING**2
    top = g2 + height * np.tan(BEVEL)
    c, s = np.cos(BEVEL), np.sin(BEVEL)
    parts = [
        _strip(rng, (-g2, 0.0), (-top, height), (c, s), density),  # left bevel wall
        _strip(rng, (g2, 0.0), (top, height), (-c, s), density),  # right bevel wall
        _strip(rng, (-0.03, height), (-top, height), (0.0, 1.0), density),  # plate tops
        _strip(rng, (top, height), (0.03, height), (0.0, 1.0), density),
    ]
    if land > 0:  # the land's faces, seen through the opening at a grazing angle: sparser
        parts += [
            _strip(rng, (-g2, -land), (-g2, 0.0), (1.0, 0.0), 0.3 * density),
            _strip(rng, (g2, -land), (g2, 0.0), (-1.0, 0.0), 0.3 * density),
        ]
    P = np.vstack([p for p, _ in parts])
    N = np.vstack([n for _, n in parts])
    return P + rng.normal(0.0, NOISE, P.shape), N


def _turned(P, N, X, rot):
    T = np.array([0.3, -0.2, 0.5])
    return rot.apply(P) + T, rot.apply(N), rot.apply(X) + T, T


NODES_X = np.linspace(-0.02, 0.02, 21)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_open_root_with_nothing_below_it_is_found_at_its_opening(seed):
    """1.4 mm gap, 30 deg bevel, 1.5 mm land, no surface within reach below: the bevel planes meet
    g/2 / tan(bevel) = 1.21 mm below the root. The nodes (given at that intersection) move to the root
    opening's centre; before, the slot test saw no surface behind the walls and they stayed 1.21 mm
    deep -- nearer the hidden far root than the shown one."""
    rng = np.random.default_rng(seed)
    gap = 0.0014
    P, N = _groove(gap, 0.0015, rng)
    depth = gap / 2 / np.tan(BEVEL)
    X = np.column_stack([NODES_X, np.zeros_like(NODES_X), np.full_like(NODES_X, -depth)])
    rot = Rotation.random(random_state=seed)
    P, N, X, T = _turned(P, N, X, rot)
    out = _root_opening(P, N, cKDTree(P), X, 0.006)
    local = rot.inv().apply(out - T)
    err = np.hypot(local[:, 1], local[:, 2])  # off the true root line (the x axis)
    assert np.median(err) < 0.3e-3, np.round(local[:, 1:] * 1e3, 2)
    assert np.all(err < 0.6e-3), np.round(local[:, 1:] * 1e3, 2)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_closed_groove_stays_at_its_crease(seed):
    """No gap: the walls meet on the line, its points are there; the nodes do not move."""
    rng = np.random.default_rng(seed)
    P, N = _groove(0.0, 0.0, rng)
    X = np.column_stack([NODES_X, np.zeros_like(NODES_X), np.zeros_like(NODES_X)])
    rot = Rotation.random(random_state=10 + seed)
    P, N, X, _ = _turned(P, N, X, rot)
    out = _root_opening(P, N, cKDTree(P), X, 0.006)
    assert np.abs(out - X).max() < 1e-9


def test_a_straight_groove_with_a_few_stray_nodes_is_straight():
    """95 % of the nodes decide (``_mostly_straight``): a stray end node 3 mm off a 200 mm line does not
    make the seam curved; a quarter circle is curved."""
    x = np.linspace(0.0, 0.2, 101)
    X = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    X[-2:, 1] = 0.003
    assert _mostly_straight(X)
    t = np.linspace(0.0, np.pi / 2, 101)
    assert not _mostly_straight(np.column_stack([np.cos(t), np.sin(t), np.zeros_like(t)]) * 0.1)


@pytest.mark.slow
def test_x_groove_on_a_table_is_found_at_its_shown_root():
    """Evaluation case 45 (X-groove resting on a table, structured light, 1.42 mm gap, 25.7 deg bevel)
    through the default denoise + seam stages: before, the seam lay at the bevel planes' intersection,
    nearer the hidden far root, and scored F1 0.51 with the approach 143 deg off; now at the shown root."""
    from weldcell.plugins.scan_plan.stages import (
        BilateralDenoiser,
        BilateralSettings,
        EdgeSeamExtractor,
        EdgeSeamSettings,
    )
    from weldcell.sdk.cloud import PointCloud
    from weldcell.testing.seam_cases import make_case, score_case

    case = make_case(45, 0)
    assert case.joint == "x-groove" and case.params["root_gap"] > 0.0012
    cloud = PointCloud(case.points, frame="base", viewpoints=case.viewpoints)
    ex = EdgeSeamExtractor(EdgeSeamSettings())(BilateralDenoiser(BilateralSettings())(cloud))
    sc = score_case(case, [(s.points, s.normals, s.closed) for s in ex.seams])
    assert sc.f1 > 0.95, sc.f1
    assert np.degrees(sc.approach) < 3.0, np.degrees(sc.approach)
    assert sc.rmse < 0.6e-3, sc.rmse
