"""The seam evaluation set (weldcell.testing.seam_cases): its scanners, its visibility and its scores, and
a fast subset of it run through the seam stage (benchmarks/seam_eval.py runs all of it)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan.stages import (
    BilateralDenoiser,
    BilateralSettings,
    EdgeSeamExtractor,
    EdgeSeamSettings,
)
from weldcell.sdk.cloud import PointCloud
from weldcell.testing.seam_cases import JOINT_KINDS, SCANNERS, make_case, score_case

#: index of the first line-laser case (joints cycle fastest, then scanners)
LASER = 2 * len(JOINT_KINDS)


@pytest.fixture(scope="module")
def laser_case():
    return make_case(LASER)  # a V-groove swept by the line profiler


def test_cases_are_seeded_and_cover_every_joint_and_scanner():
    a, b = make_case(3, seed=1), make_case(3, seed=1)
    assert np.array_equal(a.points, b.points) and a.name == b.name
    assert not np.array_equal(make_case(3, seed=2).points[:10], a.points[:10])
    joints = {JOINT_KINDS[i % len(JOINT_KINDS)] for i in range(3 * len(JOINT_KINDS))}
    assert joints == set(JOINT_KINDS) and len(SCANNERS) == 3


def test_line_laser_scan_is_anisotropic_and_records_no_viewpoint(laser_case):
    c = laser_case
    assert c.scanner == "line-laser" and c.viewpoints is None
    d = cKDTree(c.points).query(c.points, k=7)[0]
    along = float(np.median(d[:, 1]))
    assert 0.5e-3 < along < 1.6e-3  # ~1 mm between the points of a line
    # the 6th neighbour is still on the same line (lines 5-7 mm apart): 3 x the along-line spacing; an
    # isotropic cloud has its 6th neighbour at ~1.4 x its spacing
    assert np.median(d[:, 6]) > 2.5 * along


def test_shown_part_is_what_the_scan_covers(laser_case):
    c = laser_case
    (truth,), (shown,) = c.truth, c.shown
    assert 0.02 <= c.shown_length <= truth.length + 1e-3
    # shown points have scan points near them; the scan was swept over the whole seam plus 20 mm
    P = np.linspace(truth.points[0], truth.points[-1], len(shown))
    d = cKDTree(c.points).query(P[shown], k=1)[0]
    assert np.all(d < 0.6 * SCANNERS["line-laser"].line_gap[1] + 1e-9)


def _truth_as_found(case, shift=np.zeros(3), flip=False):
    out = []
    for s, m in zip(case.truth, case.shown, strict=True):
        from weldcell.testing.seam_cases import resample

        P, A = resample(s.points, s.approach, s.closed)
        out.append((P[m] + shift, -A[m] if flip else A[m], False))
    return out


def test_scores_of_a_perfect_a_shifted_and_a_flipped_result(laser_case):
    c = laser_case
    perfect = score_case(c, _truth_as_found(c))
    assert perfect.f1 == pytest.approx(1.0) and perfect.rmse < 1e-6 and perfect.approach < 1e-6
    a = c.truth[0].approach[0]
    off = np.cross(a, c.truth[0].travel[0])  # 1 mm across the seam
    one = score_case(c, _truth_as_found(c, shift=1e-3 * off))
    assert one.f1 == pytest.approx(1.0) and one.rmse == pytest.approx(1e-3, rel=0.05)
    assert score_case(c, _truth_as_found(c, shift=2e-3 * off)).f1 == 0.0  # beyond the 1.5 mm tolerance
    assert math.degrees(score_case(c, _truth_as_found(c, flip=True)).approach) == pytest.approx(180, abs=1)
    assert score_case(c, []).f1 == 0.0


#: a fast subset (RGB-D, structured light, line laser; flat, vertical, turned frames) and the F1 today's
#: stage reached on each (benchmarks/seam_eval.py after issue 16's second session, docs/benchmarks.md; the
#: baseline before it: 0.991 0.998 0.992 0.999 1.000 0.822 0.997 0.943 0.992 0.992): the stage must not
#: do worse. 22 (line laser) and 44 (structured light, no viewpoint) need the scan-side orientation and the
#: anisotropic neighbourhoods.
SUBSET = {
    0: 0.985,
    3: 0.998,
    5: 0.992,
    7: 0.999,
    17: 1.000,
    22: 0.957,
    40: 0.996,
    44: 0.966,
    46: 0.997,
    49: 0.992,
}


@pytest.mark.slow
@pytest.mark.parametrize("index", sorted(SUBSET))
def test_fast_subset_does_not_regress(index):
    case = make_case(index)
    cloud = PointCloud(case.points, frame="base", viewpoints=case.viewpoints)
    clean = BilateralDenoiser(BilateralSettings())(cloud)
    ex = EdgeSeamExtractor(EdgeSeamSettings())(clean)
    sc = score_case(case, [(s.points, s.normals, s.closed) for s in ex.seams])
    assert sc.f1 >= SUBSET[index] - 0.03, (case.name, sc)
