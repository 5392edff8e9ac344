"""Relocalization (§II-E): priors, key-frame/grid hypotheses, global fallback, verification."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from weldcell.plugins.relocalize import synth
from weldcell.plugins.relocalize.relocalize import Priors, RelocalizeSettings, relocalize

SIZE = (24.0, 18.0)


@pytest.fixture(scope="module")
def site():
    return synth.site_cloud(seed=0, size=SIZE)


def _visit(site, T, seed=1):
    return synth.visit(site, (12.0, 9.0), 7.0, T, seed=seed)


def _err(T_true, T):
    E = np.linalg.inv(T_true) @ T
    return float(np.linalg.norm(E[:3, 3])), math.degrees(Rotation.from_matrix(E[:3, :3]).magnitude())


def _correct(res, T_true) -> bool:
    t, r = _err(T_true, res.T_prior_current)
    return t < 0.05 and r < 0.5


def test_gnss_and_imu_priors_with_2m_offset(site):
    T = synth.pose(2.0, -1.0, 0.1, math.radians(35))
    res = relocalize(
        site, _visit(site, T), Priors(math.radians(39), math.radians(5), T[:3, 3] + [1.4, -1.4, 0.2])
    )
    assert res.status == "ok" and _correct(res, T)
    assert res.priors_used == ["yaw", "position"] and res.confidence >= 0.5
    doc = json.loads(json.dumps(res.to_json(), allow_nan=False))
    assert doc["schema"] == "weldcell/relocalization@1" and len(doc["gamma"]) == 6
    assert np.allclose(doc["gamma"][:3], res.T_prior_current[:3, 3])
    assert doc["gamma"][5] == pytest.approx(math.radians(35), abs=0.01)


def test_imu_yaw_only_with_large_offset(site):
    T = synth.pose(-6.0, 4.0, 0.0, math.radians(-120))
    res = relocalize(site, _visit(site, T, seed=2), Priors(yaw=math.radians(-126), yaw_sigma=math.radians(8)))
    assert res.status == "ok" and _correct(res, T) and res.priors_used == ["yaw"]


def test_uncertain_yaw_searches_hypotheses(site):
    T = synth.pose(1.0, 2.0, 0.0, math.radians(100))
    pri = Priors(yaw=math.radians(40), yaw_sigma=math.radians(40), position=T[:3, 3] + [1.0, 1.0, 0.0])
    res = relocalize(site, _visit(site, T, seed=3), pri)
    assert res.status == "ok" and _correct(res, T) and "global" not in res.priors_used


def test_no_prior_uses_global_registration(site):
    T = synth.pose(5.0, 3.0, -0.2, math.radians(150))
    res = relocalize(site, _visit(site, T, seed=4))
    assert res.status == "ok" and _correct(res, T) and res.priors_used == ["global"]


def test_prior_map_of_another_site_fails(site):
    T = synth.pose(1.0, 1.0, 0.0, 0.3)
    cur = _visit(site, T, seed=5)
    other = synth.site_cloud(seed=11, size=SIZE)
    res = relocalize(other, cur, Priors(yaw=0.3, position=T[:3, 3]))
    assert res.status == "failed" and res.confidence == 0.0 and "fits" in res.reason
    json.dumps(res.to_json(), allow_nan=False)


def test_magnetometer_disturbed_by_steel_is_never_a_wrong_ok(site):
    """Yaw off by 90 deg with a stated 5 deg uncertainty: detected, answered by the map itself or failed."""
    T = synth.pose(2.0, 1.0, 0.0, math.radians(20))
    pri = Priors(yaw=math.radians(110), yaw_sigma=math.radians(5), position=T[:3, 3])
    res = relocalize(site, _visit(site, T, seed=6), pri)
    if res.status == "ok":
        assert _correct(res, T) and "yaw" not in res.priors_used
        assert any("yaw" in n and "inconsistent" in n for n in res.notes)
    else:
        assert res.reason


def test_imu_yaw_with_prior_keyframes_as_position_hypotheses(site):
    """§II-E without GNSS: the prior's key-frame poses are NDT's initial guesses for the current origin."""
    T = synth.pose(-3.0, 2.0, 0.0, math.radians(60))
    kf = np.array([[x, 2.0 + 0.3 * x, 0.0] for x in np.arange(-9.0, 9.0, 2.0)])  # a path passing near it
    pri = Priors(yaw=math.radians(64), keyframe_positions=kf)
    res = relocalize(site, _visit(site, T, seed=7), pri)
    assert res.status == "ok" and _correct(res, T) and res.priors_used == ["yaw", "keyframes"]


def test_gnss_jump_never_gives_a_wrong_answer(site):
    """A GNSS fix that jumped 15 m (multipath next to steel) with a stated 2 m: the pose from it does not
    verify; the answer is the right pose (global registration, the jump named as a rejected prior) or
    failed, never a wrong pose reported ok."""
    T = synth.pose(1.0, -2.0, 0.0, math.radians(50))
    pr = Priors(math.radians(52), math.radians(5), T[:3, 3] + [15.0, -6.0, 0.0], 2.0)
    res = relocalize(site, _visit(site, T, seed=5), pr, RelocalizeSettings(global_attempts=1))
    assert res.status == "failed" or _correct(res, T)
    if res.status == "ok":
        assert "position" not in res.priors_used and any("rejected" in n for n in res.notes)


def test_prepared_prior_map_gives_the_same_answer(site):
    from weldcell.plugins.relocalize.relocalize import PriorMap

    T = synth.pose(2.0, 1.0, 0.0, math.radians(-20))
    cur = _visit(site, T, seed=6)
    pr = Priors(math.radians(-18), math.radians(5), T[:3, 3] + [0.5, 0.5, 0.0])
    pm = PriorMap(site).warm()
    a, b = relocalize(pm, cur, pr), relocalize(site, cur, pr)
    assert a.status == b.status == "ok" and _correct(a, T)
    assert np.allclose(a.T_prior_current, b.T_prior_current, atol=1e-6)
