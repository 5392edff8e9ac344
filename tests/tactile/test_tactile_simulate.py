"""End to end with rendered in-finger images going through the real detector (no shortcut)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from weldcell.plugins.tactile.paths import curved_seam, planned_path_with_error
from weldcell.plugins.tactile.servo import ServoSettings
from weldcell.plugins.tactile.simulate import SCHEMA, track_seam
from weldcell.sdk.errors import DataError

pytest.importorskip("cv2")


def test_rendered_closed_loop_on_a_curved_seam() -> None:
    seam = curved_seam(radius=0.06, angle=0.6, lead_in=0.01)
    plan = planned_path_with_error(seam, offset=0.002, drift=0.01, side="right", seed=4)
    S = ServoSettings(speed=0.01)
    r = track_seam(seam, plan, settings=S, render=True, rate_hz=40.0, seed=4)
    m = r.metrics
    assert m["marker_lost_frames"] == 0
    assert m["delta_n_meas_err_rms_mm"] < 0.05  # image -> δ, against the model's true deformation
    assert m["refined_seam_rms_mm"] <= 0.3 and m["plan_rms_mm"] > 1.5
    assert r.stop_reason == "contact lost"
    doc = json.loads(json.dumps(r.to_dict()))
    assert doc["schema"] == SCHEMA and len(doc["seam_estimate"]) == len(r.refined_path)


def test_simulation_input_errors() -> None:
    seam = curved_seam()
    with pytest.raises(DataError):
        track_seam(seam, seam, rate_hz=0.0, render=False)
    with pytest.raises(DataError):
        track_seam(seam, np.zeros((1, 3)), render=False)


def test_options_object_and_keywords_run_the_same_simulation() -> None:
    from weldcell.plugins.tactile.simulate import SimulationOptions, simulate_tracking

    seam = curved_seam(radius=0.06, angle=0.4, lead_in=0.01)
    plan = planned_path_with_error(seam, offset=0.002, drift=0.01, side="right", seed=2)
    a = track_seam(seam, plan, render=False, seed=2, tag_gain_error=0.03, max_time=3.0)
    b = simulate_tracking(
        seam, plan, SimulationOptions(render=False, seed=2, tag_gain_error=0.03, max_time=3.0)
    )
    assert np.array_equal(a.refined_path, b.refined_path) and np.array_equal(a.twist, b.twist)
    assert a.metrics == b.metrics and a.stop_reason == b.stop_reason
    assert a.t[-1] <= 3.0 + 1e-9
