"""Inspection plans (§III-C) and the check that a plan constrains the pose before anything moves (Fig. 10)."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.hal.kinematics import get_model
from weldcell.plugins.localize.plans import (
    PlanSettings,
    _crossings,
    check_constraints,
    major_edges,
    make_plan,
    plan_duration,
    principal_axes,
)
from weldcell.plugins.localize.pose import transform_template
from weldcell.plugins.localize.template import Member, Template
from weldcell.plugins.localize.workpieces import make_workpiece
from weldcell.sdk.errors import DataError


def bar(p, q, w=0.04):
    p, q = np.asarray(p, float), np.asarray(q, float)
    d = (q - p) / np.linalg.norm(q - p)
    n = np.array([-d[1], d[0]]) * w / 2
    return np.array([p - n, q - n, q + n, p + n])


@pytest.fixture
def ladder():
    return make_workpiece("ladder", center=(1.0, 0.0))


def test_local_zigzag_crosses_both_long_edges_of_every_member(ladder):
    s = PlanSettings(plan="local", spacing=0.03, span=0.04, check_offset=0.0, check_angle=0.0)
    plan = make_plan(ladder, s, z_sensor=0.21)
    report = check_constraints(plan, ladder, s)
    for m in ladder.members:
        counts = report["crossings"][m.id]
        assert len(counts) == 2  # the two long edges
        length = np.ptp(m.outline @ np.linalg.eigh(np.cov(m.outline.T))[1][:, -1])
        expect = int((length - 2 * s.end_margin) / s.spacing)  # one crossing per leg
        assert all(k >= expect for k in counts.values()), (m.id, counts, expect)
    # the legs of one member's zig-zag cross it at an angle: each leg goes from one side to the other
    legs = [ln for ln, k in zip(plan.lines, plan.kinds, strict=True) if k == "leg"]
    assert len(legs) > 40
    assert plan.kinds[:2] == ["latency-fwd", "latency-back"]
    np.testing.assert_allclose(plan.lines[0][::-1], plan.lines[1])  # the same line, back


def test_plan_that_cannot_constrain_is_refused_naming_member_and_edge(ladder):
    s = PlanSettings(plan="local", spacing=0.6, end_margin=0.0, check_offset=0.0, check_angle=0.0)
    plan = make_plan(ladder, s, z_sensor=0.21)
    with pytest.raises(DataError) as e:
        check_constraints(plan, ladder, s)
    assert "member 'rung-" in e.value.message and "edge" in e.value.message
    assert "1 times" in e.value.message or "0 times" in e.value.message
    assert "spacing" in e.value.fix


def test_parallel_members_leave_the_sliding_direction_free():
    # two parallel rails and nothing across them: every crossed edge is parallel (Fig. 10)
    tpl = Template(
        [Member("a", 0.05, bar((0.7, -0.1), (1.3, -0.1))), Member("b", 0.05, bar((0.7, 0.1), (1.3, 0.1)))]
    )
    s = PlanSettings(plan="local", spacing=0.03, check_offset=0.0, check_angle=0.0)
    with pytest.raises(DataError, match=r"sliding along \(\+?-?1\.00, [+-]0\.00\)"):
        check_constraints(make_plan(tpl, s, 0.21), tpl, s)


def test_a_span_too_small_for_the_placement_window_is_refused(ladder):
    # a part displaced by 100 mm leaves a narrow zig-zag: its end rungs are not crossed any more
    s = PlanSettings(plan="local", spacing=0.03, span=0.002, check_offset=0.1, check_angle=0.0)
    check_constraints(
        make_plan(ladder, s.model_copy(update={"check_offset": 0.0}), 0.21),
        ladder,
        s.model_copy(update={"check_offset": 0.0}),
    )  # at the planned position it is fine
    with pytest.raises(DataError, match="part displaced"):
        check_constraints(make_plan(ladder, s, 0.21), ladder, s)
    wide = s.model_copy(update={"span": 0.14})
    check_constraints(make_plan(ladder, wide, 0.21), ladder, wide)


def test_global_spiral_runs_along_the_principal_axes():
    tpl = transform_template(make_workpiece("truss", center=(1.0, 0.0)), (0.0, 0.0, np.radians(30)))
    s = PlanSettings(
        plan="global", spacing=0.025, span=0.04, check_offset=0.0, check_angle=0.0, spiral_core="none"
    )
    plan = make_plan(tpl, s, 0.21)
    c, A = principal_axes(tpl)
    assert abs(abs(A[:, 0] @ [np.cos(np.radians(30)), np.sin(np.radians(30))]) - 1) < 1e-3  # along the chords
    rings = [ln for ln, k in zip(plan.lines, plan.kinds, strict=True) if k == "ring"]
    d = np.array([ln[1] - ln[0] for ln in rings if np.linalg.norm(ln[1] - ln[0]) > 0.02])  # straight parts
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    assert np.all(np.max(np.abs(d @ A), axis=1) > 0.999)  # every straight run is along one of the axes
    # the paper's spiral crosses the chords (parallel to its major axis) only near its ends: refused
    with pytest.raises(DataError, match="member 'chord-"):
        check_constraints(plan, tpl, s)
    # turned by 45 deg, every ring crosses every member
    turned = s.model_copy(update={"spiral_angle": np.radians(45)})
    report = check_constraints(make_plan(tpl, turned, 0.21), tpl, turned)
    assert all(min(v.values()) >= 2 for v in report["crossings"].values())


@pytest.mark.parametrize("name", ["ladder", "truss", "spaceframe"])
def test_default_spiral_crosses_long_members_along_their_whole_length(name):
    """The default global plan (the paper's spiral + the serpentine core) crosses every major edge of every
    member often enough, over the placement window, and the members along the major axis also in their
    middle third (the paper's spiral alone crosses them only near its ends)."""
    tpl = make_workpiece(name, center=(1.0, 0.0))
    s = PlanSettings(plan="global", spacing=0.012, span=0.04)
    plan = make_plan(tpl, s, 0.21)
    report = check_constraints(plan, tpl, s)  # planned position and the four corners of the window
    assert all(min(v.values()) >= 2 for v in report["crossings"].values())
    c, A = principal_axes(tpl)
    paper = make_plan(tpl, s.model_copy(update={"spiral_core": "none"}), 0.21)
    for m in tpl.members:
        P = (m.outline - c) @ A
        if np.ptp(P[:, 0]) < 0.6 * np.ptp(np.vstack([x.outline for x in tpl.members]) @ A[:, 0]):
            continue  # only the members that run along the major axis
        segs = np.stack([m.outline, np.roll(m.outline, -1, axis=0)], axis=1)
        lo, hi = np.quantile(P[:, 0], [0.0, 1.0])
        middle = lo + (hi - lo) / 3, hi - (hi - lo) / 3

        def in_middle(p, segs=segs, middle=middle):
            hits, _ = _crossings(p.xy, segs)
            u = (hits - c) @ A[:, 0]
            return int(np.sum((u > middle[0]) & (u < middle[1])))

        assert in_middle(plan) >= 8, m.id
        assert in_middle(paper) < in_middle(plan) / 4, m.id


def test_corners_are_blended():
    tpl = make_workpiece("ladder", center=(1.0, 0.0))

    def max_turn(plan):
        """The sharpest turn between consecutive zig-zag legs (the extremes of Fig. 7)."""
        worst, run = 0.0, []
        for ln, k in [*zip(plan.lines, plan.kinds, strict=True), (None, "end")]:
            if k == "leg":
                run.append(ln if not run else ln[1:])
                continue
            if len(run) > 1:
                v = np.diff(np.vstack(run), axis=0)
                v = v[np.linalg.norm(v, axis=1) > 1e-9]
                v /= np.linalg.norm(v, axis=1, keepdims=True)
                worst = max(
                    worst, np.degrees(np.arccos(np.clip(np.sum(v[1:] * v[:-1], axis=1), -1, 1))).max()
                )
            run = []
        return worst

    sharp = make_plan(tpl, PlanSettings(blend=0.0), 0.21)
    smooth = make_plan(tpl, PlanSettings(blend=0.005), 0.21)
    assert max_turn(smooth) < 0.6 * max_turn(sharp)


def test_duration_comes_from_the_robots_motion_time_model():
    tpl = make_workpiece("ladder", center=(1.0, 0.0))
    plan = make_plan(tpl, PlanSettings(speed=0.1, accel=1.0), 0.21)
    T_fs = np.eye(4)
    T_fs[2, 3] = 0.3
    T_ft = np.eye(4)
    model = get_model("abb-irb2600")
    dur = plan_duration(plan, model, T_fs, T_ft)
    assert dur > plan.length / plan.speed  # every waypoint a rest-to-rest move: never faster than cruising
    assert plan_duration(plan, None, T_fs, T_ft) == pytest.approx(plan.length / plan.speed)


def test_crossings_and_major_edges():
    P = bar((0.0, 0.0), (1.0, 0.0))
    assert sorted(major_edges(P).tolist()) == [0, 2]
    segs = np.stack([P, np.roll(P, -1, axis=0)], axis=1)
    hits, j = _crossings(np.array([[0.5, -0.1], [0.5, 0.1], [0.6, -0.1]]), segs)
    assert sorted(j.tolist()) == [0, 0, 2, 2]
    np.testing.assert_allclose(np.sort(hits[:, 1]), [-0.02, -0.02, 0.02, 0.02])
