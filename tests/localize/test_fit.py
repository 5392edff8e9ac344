"""Localization (paper 002, §IV) and its robust extensions, on synthetic inspections of Fig. 12-like parts."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from weldcell.plugins.localize import search
from weldcell.plugins.localize.cost import Eq3, Eq3Near, Segments, distances, field_for
from weldcell.plugins.localize.edges import extract_edges
from weldcell.plugins.localize.fit import LocalizeSettings, localize
from weldcell.plugins.localize.pose import apply_xy, pose_matrix, transform_template
from weldcell.plugins.localize.synth import SensorModel, scan_lines, spiral_plan, vary_members, zigzag_plan
from weldcell.plugins.localize.template import Member, Template
from weldcell.plugins.localize.workpieces import ladder_frame, warren_truss

FAST = SensorModel(speed=0.4)  # 0.27 mm along-line spacing keeps the tests quick


def _inspect(tpl, truth_pose, plan="zigzag", seed=0, truth=None, extra=()):
    rng = np.random.default_rng(seed)
    placed = transform_template(truth or tpl, truth_pose, tpl.centroid)
    placed.members += list(extra)
    lines = zigzag_plan(tpl, 0.03, 0.19) if plan == "zigzag" else spiral_plan(tpl, pitch=0.012)
    return extract_edges(scan_lines(placed, lines, rng, FAST), tpl)


@pytest.mark.parametrize(
    ("make", "plan", "pose"),
    [
        (ladder_frame, "zigzag", (0.012, -0.009, math.radians(14.0))),
        (warren_truss, "spiral", (-0.014, 0.006, math.radians(-18.0))),
    ],
)
def test_recovers_placement(make, plan, pose):
    tpl = make()
    edges = _inspect(tpl, pose, plan)
    loc = localize(tpl, edges)
    assert loc.status == "ok", loc.message
    err = loc.pose - np.array(pose)
    assert abs(err[0]) < 0.25e-3 and abs(err[1]) < 0.25e-3
    assert abs(math.degrees(err[2])) < 0.05
    # M maps planned points onto found ones; the covariance is small and positive
    M = loc.M
    p = tpl.members[0].outline[0]
    assert np.allclose((M @ [p[0], p[1], 0.0, 1.0])[:2], apply_xy(loc.pose, tpl.centroid, p[None])[0])
    assert np.allclose(M, pose_matrix(loc.pose, tpl.centroid))
    sd = np.sqrt(np.diag(loc.covariance))
    assert np.all(sd > 0) and sd[0] < 0.2e-3 and sd[2] < math.radians(0.05)
    doc = json.loads(json.dumps(loc.to_json(), allow_nan=False))
    assert doc["schema"] == "weldcell/localization@1" and doc["status"] == "ok"
    assert len(doc["welds"]) == len(tpl.welds) and all(m["status"] == "ok" for m in doc["members"])


def test_paper_method_powell_from_seven_seeds():
    tpl = ladder_frame()
    pose = (0.01, 0.004, math.radians(-9.0))
    loc = localize(tpl, _inspect(tpl, pose, seed=4), LocalizeSettings(method="paper", parallel="never"))
    assert loc.status == "ok", loc.message
    assert np.allclose(loc.pose[:2], pose[:2], atol=0.5e-3) and abs(math.degrees(loc.pose[2] - pose[2])) < 0.1
    assert loc.fit_error_mean < 1e-3 and loc.parallel.startswith("serial")


def test_fast_eq3_has_the_value_of_the_paper_cost():
    """The optimiser's eq. (3) (Voronoi labels of the distance field) equals the all-pairs sum of
    point-to-segment distances; points off the grid fall back to all pairs; exact=True is that sum itself."""
    tpl = warren_truss()
    segs = Segments.of(tpl)
    fld = field_for(segs.array, 1e-3, 0.052, 0.032)
    xy = _inspect(tpl, (0.01, -0.004, math.radians(7.0)), seed=2).xy
    fast, exact = Eq3(xy, segs, fld), Eq3(xy, segs, fld, exact=True)
    for pose in [(0.01, -0.004, math.radians(7.0)), (0.0, 0.0, 0.0), (0.03, 0.02, math.radians(-15.0))]:
        ref = float(distances(pose, xy, segs).sum())
        assert exact(pose) == pytest.approx(ref, rel=1e-12)
        # a label can be the runner-up segment only near a medial axis: within a cell per point, rarely
        assert ref <= fast(pose) + 1e-12 and fast(pose) == pytest.approx(ref, rel=2e-3)
    far = np.vstack([xy, [[5.0, 5.0]]])  # a point far off the template's grid
    ref = distances((0, 0, 0), far, segs).sum()
    assert Eq3(far, segs, fld)((0.0, 0.0, 0.0)) == pytest.approx(ref, rel=1e-12)


def test_polish_cost_near_a_pose_is_the_all_pairs_eq3():
    """The polish's eq. (3) on each point's candidate segments equals the all-pairs sum near its start
    pose (within its margin the candidates provably hold the nearest segment) and falls back beyond."""
    tpl = warren_truss()
    segs = Segments.of(tpl)
    p0 = np.array([0.01, -0.004, math.radians(7.0)])
    xy = _inspect(tpl, tuple(p0), seed=2).xy
    near, exact = Eq3Near(xy, segs, p0, margin=1e-3), Eq3(xy, segs, None, exact=True)
    assert near.a.shape[1] < len(segs.a) / 4  # a few candidates per point, not every segment
    rng = np.random.default_rng(0)
    for _ in range(20):  # inside the margin (<= 0.5 mm of motion) and beyond it (fallback)
        for scale in (0.3e-3, 20e-3):
            p = p0 + rng.uniform(-1, 1, 3) * np.array([scale, scale, scale / tpl.radius])
            assert near(p) == pytest.approx(exact(p), rel=1e-12)


def test_seeds_that_join_a_known_basin_stop_and_the_answer_is_unchanged(monkeypatch):
    """A seed whose best point reaches a minimum already found stops there (fewer evaluations); the
    paper's answer stays within 0.01 mm / 0.005 deg of running every seed to its end."""
    tpl = ladder_frame()
    edges = _inspect(tpl, (-0.006, 0.011, math.radians(12.0)), seed=3)
    s = LocalizeSettings(method="paper", parallel="never")
    counted = []
    run = search.SeedRunner.run

    def spy(self, tasks):
        out = run(self, tasks)
        counted.append(out)
        return out

    monkeypatch.setattr(search.SeedRunner, "run", spy)
    merged = localize(tpl, edges, s)
    monkeypatch.setattr(search, "MERGE_DISTANCE", -1.0)  # never merge: every seed runs to its end
    full = localize(tpl, edges, s)
    assert any(r.merged for r in counted[0]) and not any(r.merged for r in counted[1])
    assert sum(r.nfev for r in counted[0]) < 0.85 * sum(r.nfev for r in counted[1])
    assert np.abs(merged.pose[:2] - full.pose[:2]).max() < 1e-5
    assert abs(math.degrees(merged.pose[2] - full.pose[2])) < 0.005


def test_paper_method_ends_at_a_minimum_of_the_exact_eq3():
    tpl = ladder_frame()
    edges = _inspect(tpl, (-0.006, 0.011, math.radians(12.0)), seed=3)
    loc = localize(tpl, edges, LocalizeSettings(method="paper", parallel="never"))
    assert loc.status == "ok", loc.message
    eq3 = Eq3(edges.xy, Segments.of(tpl), None, exact=True)
    e0 = eq3(loc.pose)
    for k, h in ((0, 0.05e-3), (1, 0.05e-3), (2, math.radians(0.01))):  # no better pose a step away
        for sgn in (-1, 1):
            p = loc.pose.copy()
            p[k] += sgn * h
            assert eq3(p) >= e0 - 1e-9


def test_placement_outside_the_window_fails_instead_of_answering():
    tpl = ladder_frame()
    pose = (0.09, -0.02, math.radians(5.0))  # 90 mm off: beyond the +-50 mm window around the plan
    edges = _inspect(tpl, pose, seed=5)
    loc = localize(tpl, edges, LocalizeSettings(window_center="planned"))
    assert loc.status == "failed"
    assert "outside the search window" in loc.message or "edge points fit" in loc.message
    # the second window, around the edges' own centre and orientation (the paper's seed centre), finds it
    both = localize(tpl, edges)
    assert both.status == "ok" and np.allclose(both.pose[:2], pose[:2], atol=0.3e-3)
    assert "by hand" in loc.message
    doc = loc.to_json()
    assert doc["status"] == "failed"
    json.dumps(doc, allow_nan=False)


def test_symmetric_part_is_ambiguous():
    """A square frame of four equal tubes looks the same turned by 90 deg: with a window that holds both
    turns the result must say so."""
    members = [
        Member("s", 0.04, [[0.8, -0.2], [1.2, -0.2], [1.2, -0.16], [0.8, -0.16]]),
        Member("e", 0.04, [[1.16, -0.16], [1.2, -0.16], [1.2, 0.2], [1.16, 0.2]]),
        Member("n", 0.04, [[0.8, 0.16], [1.16, 0.16], [1.16, 0.2], [0.8, 0.2]]),
        Member("w", 0.04, [[0.8, -0.16], [0.84, -0.16], [0.84, 0.16], [0.8, 0.16]]),
    ]
    members[2].outline[2, 0] = 1.2  # keep the outline closed at the corner
    tpl = Template(members)
    edges = _inspect(tpl, (0.005, 0.0, math.radians(40.0)), plan="spiral", seed=6)
    loc = localize(tpl, edges, LocalizeSettings(window_theta=math.radians(60)))
    assert loc.status == "ambiguous", loc.message
    turns = sorted([loc.pose[2], loc.alternatives[0]["theta"]])
    assert math.degrees(turns[0]) == pytest.approx(-50.0, abs=0.5)
    assert math.degrees(turns[1]) == pytest.approx(40.0, abs=0.5)


def test_missing_member_and_clutter_do_not_drag_the_fit():
    tpl = ladder_frame()
    pose = (-0.008, 0.011, math.radians(7.0))
    truth = Template([m for m in tpl.members if m.id != "rung-2"], [], tpl.table_z)
    clutter = Member("offcut", 0.04, [[0.7, 0.28], [1.3, 0.31], [1.3, 0.36], [0.7, 0.33]])  # beside rail-b
    edges = _inspect(tpl, pose, seed=7, truth=truth, extra=[clutter])
    loc = localize(tpl, edges)
    assert loc.status == "ok", loc.message
    assert (
        np.allclose(loc.pose[:2], pose[:2], atol=0.3e-3) and abs(math.degrees(loc.pose[2] - pose[2])) < 0.05
    )
    assert "rung-2" in loc.message
    assert {m.id: m.status for m in loc.members}["rung-2"] == "not_observed"
    # the clutter's edges are there, and left out as outliers
    assert loc.inlier_fraction < 0.9 and loc.fit_error_mean_all > 3 * loc.fit_error_mean


def test_member_off_cad_is_named_and_its_welds_follow_it():
    tpl = warren_truss()
    truth = vary_members(tpl, np.random.default_rng(8), amount=0.0)
    k = [m.id for m in tpl.members].index("diag-2")
    truth.members[k].outline = truth.members[k].outline + np.array([0.004, 0.0])  # 4 mm off CAD
    pose = (0.006, -0.004, math.radians(3.0))
    loc = localize(tpl, _inspect(tpl, pose, plan="spiral", seed=9, truth=truth))
    assert loc.status == "ok", loc.message
    status = {m.id: m.status for m in loc.members}
    assert status["diag-2"] == "outside_tolerance" and "diag-2" in loc.message
    assert all(v == "ok" for k2, v in status.items() if k2 != "diag-2")
    welds = [w for w in loc.welds if "diag-2" in w["members"]]
    assert welds
    for w in welds:  # re-planned: along the chord's edge the weld follows diag-2 (4 mm), across it the chord
        pts, rigid = np.asarray(w["points"]), np.asarray(w["points_rigid"])
        assert np.allclose(pts[:, :2] - rigid[:, :2], [0.004, 0.0], atol=0.6e-3)


def test_too_few_edge_points_fail_and_no_weld_is_replanned_when_failed():
    tpl = ladder_frame()
    loc = localize(tpl, np.array([[1.0, 0.0], [1.1, 0.1]]))
    assert loc.status == "failed" and "2 edge points" in loc.message
    far = localize(  # beyond the 25 deg window
        tpl, _inspect(tpl, (0.0, 0.0, math.radians(40.0)), seed=10), LocalizeSettings(window_center="planned")
    )
    assert far.status == "failed" and far.welds == [] and far.to_json()["welds"] == []
