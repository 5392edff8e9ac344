"""Calibration poses planned inside the robot's reach and the cell's workspace box (plugins/handeye/
pose_plan.py): cell 2's calibrate-and-track box with the tactile finger's 180 mm TCP reaches past the
workspace box, so some grid nodes are replaced up front instead of being refused during the run."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.hal.kinematics import get_model
from weldcell.hal.safety import SafetyGate
from weldcell.plugins.handeye.job import plan_poses, reachable_plan
from weldcell.plugins.handeye.pose_plan import PoseCheck
from weldcell.sdk.calibration import CalibrateSettings
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import JobError
from weldcell.sdk.geometry import T_from_rpy

CAMERA = np.array([1.45, 0.0, 0.55])  # cell 2's PhoXi on its stand, base frame
SETTINGS = CalibrateSettings(
    box_min=[0.70, -0.15, 0.50], box_max=[0.90, 0.15, 0.68], n_poses=16, max_tilt=0.26, max_spin=0.35
)


def _check(tcp_z: float = 0.18) -> PoseCheck:
    gate = SafetyGate(
        SafetyLimits(workspace_min=[-0.4, -0.9, 0.2], workspace_max=[1.0, 0.9, 1.2]), get_model("ur10e")
    )
    return PoseCheck(gate, T_from_rpy((0, 0, 0), (0, 0, tcp_z)))


def _plan(s: CalibrateSettings = SETTINGS, seed: int = 11):
    return plan_poses(s.box_min, s.box_max, s.n_poses, CAMERA, s.max_tilt, s.max_spin, seed)[0]


def test_unreachable_poses_are_replaced_inside_the_box_and_the_rest_kept():
    check = _check()
    planned = _plan()
    refused = [i for i, T in enumerate(planned) if check.why_not(T) is not None]
    assert len(refused) >= 3  # the finger's tip passes x = 1.0 m from the box's far side
    assert all("outside the cell's workspace box" in check.why_not(planned[i]) for i in refused)
    poses, replaced = reachable_plan(SETTINGS, planned, CAMERA, check, seed=11)
    swapped = [r.index for r in replaced]
    # every pose the gate refuses alone, and those whose joint move from the previous pose would sweep the
    # tool out of the box
    assert set(refused) < set(swapped) and len(poses) == len(planned)
    assert any("joint move" in r.reason for r in replaced if r.index not in refused)
    q = None
    for T in poses:  # a normal run refuses none: every move, in order, as the job makes it
        why, q = check.reach(T, q)
        assert why is None, why
    kept = [i for i in range(len(planned)) if i not in swapped]
    np.testing.assert_array_equal(poses[kept], planned[kept])
    centre = (np.array(SETTINGS.box_min) + np.array(SETTINGS.box_max)) / 2
    lo, hi = np.array(SETTINGS.box_min), np.array(SETTINGS.box_max)
    for r in replaced:
        p, p0 = poses[r.index][:3, 3], planned[r.index][:3, 3]
        assert np.all(p >= lo - 1e-9) and np.all(p <= hi + 1e-9)
        assert np.linalg.norm(p - centre) < np.linalg.norm(p0 - centre)  # toward the centre ...
        d0, d = (p0 - centre) / np.linalg.norm(p0 - centre), (p - centre) / np.linalg.norm(p - centre)
        assert d0 @ d > 0.999  # ... along the node's own direction, keeping the plan's spread
        z = poses[r.index][:3, 2]
        to_cam = (CAMERA - p) / np.linalg.norm(CAMERA - p)
        assert np.degrees(np.arccos(np.clip(z @ to_cam, -1, 1))) <= np.degrees(np.hypot(0.26, 0.26)) + 0.5
    again, _ = reachable_plan(SETTINGS, planned, CAMERA, check, seed=11)
    np.testing.assert_array_equal(again, poses)  # deterministic: a resumed run plans the same poses


def test_a_box_the_robot_cannot_reach_at_all_is_refused_with_a_fix():
    s = SETTINGS.model_copy(update={"box_min": [1.6, -0.1, 0.5], "box_max": [1.8, 0.1, 0.6]})
    with pytest.raises(JobError, match="cannot be reached") as e:
        reachable_plan(s, _plan(s), CAMERA + [1.0, 0, 0], _check(), seed=1)
    assert "box_min/box_max" in e.value.fix


def test_without_a_check_the_plan_is_unchanged():
    planned = _plan()
    poses, replaced = reachable_plan(SETTINGS, planned, CAMERA, None, seed=11)
    assert replaced == [] and poses is planned


def test_the_job_replaces_the_poses_a_tight_workspace_cuts_off_and_refuses_none(
    he_pm, tmp_path, extend_profile
):
    """The workspace box cuts the top of the pose box (the same cell as test_handeye_job.py's refusal
    test): the job plans replacements before it moves, so no pose is refused and none leaves the box."""
    import json
    from pathlib import Path

    from weldcell.sdk.jobs import run_job

    profile = Path(__file__).resolve().parents[2] / "profiles" / "cell2-calibrate-sim.toml"
    p = extend_profile(
        profile,
        "tight.toml",
        "[cell.safety]\nworkspace_max = [1.0, 0.9, 0.62]\n"
        "[job.settings]\nstop_at_target = false\nn_poses = 8\nmin_poses = 4\n",
    )
    run, result = run_job(p, he_pm, runs_dir=tmp_path)
    state = json.loads((run / "state.json").read_text())
    caps = state["captures"]
    assert not [c for c in caps if c.get("status") == "refused"]
    assert sum(c.get("kind") == "pose" for c in caps) == 8  # every planned pose visited
    sent = np.array([c["T_base_flange"] for c in caps if "T_base_flange" in c])
    assert sent[:, 2, 3].max() <= 0.62 + 1e-9
    assert state["notes"]["replanned"]  # what was replaced, and why, is kept with the run
    assert "0 refused by the safety gate" in (run / "summary.txt").read_text()
