"""The shipped fillet T-joint profile (profiles/cell1-fillet-sim.toml) end to end in the simulated cell:
the "survey-sides" hand looks at each side of the web from an angle, and the job finds, plans and
executes both fillet seams within 1.5 mm / 3 deg of the ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from weldcell.hal.sim.hands import load_script
from weldcell.sdk.artifacts import read_json
from weldcell.sdk.jobs import run_job
from weldcell.sdk.plugins import get_plugin_manager
from weldcell.sdk.weldpath import WeldPath

SHIPPED = Path(__file__).resolve().parents[2] / "profiles" / "cell1-fillet-sim.toml"


@pytest.fixture(scope="module")
def fillet_run(tmp_path_factory) -> tuple[Path, dict]:
    """One run of the shipped profile as a user runs it (decimation 2, executing the weld paths)."""
    runs = tmp_path_factory.mktemp("fillet") / "runs"
    return run_job(SHIPPED, get_plugin_manager(), runs_dir=runs)


def test_both_fillet_seams_are_found_near_the_ground_truth(fillet_run):
    run_dir, result = fillet_run
    assert result["status"] == "ok"
    m = result["figures"]["metrics"]
    assert m["seams_found"] == 2 and m["seams_true"] == 2
    per = m["per_seam"]
    assert sorted(p["truth"] for p in per) == ["0:fillet-t/fillet-1", "0:fillet-t/fillet-2"]
    for p in per:  # eq. 22 per seam, against the seam each was matched to
        assert p["translation_m"] < 1.5e-3, p
        assert np.degrees(p["rotation_rad"]) < 3.0, p
        assert np.degrees(p["approach_rad"]) < 3.0, p
    assert m["f1"]["f1"] > 0.95  # eq. 21
    path = WeldPath.from_json(run_dir / "weld_path.json")
    for seam in path.seams:  # the 300 mm seams, found over (nearly) their whole length, at the web's foot
        assert seam.length > 0.28
        y = np.median(seam.points[:, 1])
        assert abs(abs(y) - 0.005) < 1.5e-3 and abs(np.median(seam.points[:, 2]) - 0.010) < 1.5e-3
        approach = np.mean(np.asarray(seam.extra["approach"], dtype=float), axis=0)
        # into the corner: down and toward the web, bisecting the plate and the web face
        assert np.dot(approach / np.linalg.norm(approach), [0, -np.sign(y), -1] / np.sqrt(2)) > np.cos(
            np.radians(5)
        )


def test_the_scan_looks_at_each_side_of_the_web_from_an_angle_within_reach(fillet_run):
    run_dir, result = fillet_run
    scan = result["figures"]["scan"]
    assert scan["captures"] == 3 and scan["refused_targets"] == 0
    state = read_json(run_dir / "state.json")
    T_fc = np.asarray(state["notes"]["hand_eye"]["T_flange_camera"])
    cams = [np.asarray(c["T_base_flange"]) @ T_fc for c in state["captures"]]
    tilts = [np.degrees(np.arccos(-T[2, 2])) for T in cams]  # camera axis against straight down
    top, sides = tilts[0], tilts[1:]
    assert top < 5.0
    ys = sorted(T[1, 3] for T in cams[1:])
    assert ys[0] < -0.2 and ys[1] > 0.2  # one view from each side of the web (web along x at y = 0)
    for T, tilt in zip(cams[1:], sides, strict=True):
        assert 30.0 <= tilt <= 40.0
        assert np.sign(T[1, 2]) == -np.sign(T[1, 3])  # tilted toward the web, not away from it
        # the camera axis passes within 5 cm of the seam on its side (x = 0.42, y = 0, z = 0.01)
        c, a = T[:3, 3], T[:3, 2]
        seam = np.array([0.42, np.sign(T[1, 3]) * 0.005, 0.01])
        assert np.linalg.norm(np.cross(seam - c, a)) < 0.05


def test_the_weld_paths_are_executed_and_exported(fillet_run):
    run_dir, result = fillet_run
    assert result["figures"]["execute"]["status"] == "done"
    for name in ("programs/weld_path.script", "programs/weld_path.mod", "programs/weld_path.csv"):
        assert (run_dir / name).stat().st_size > 0
    assert (run_dir / "report" / "seams.png").stat().st_size > 0
    summary = (run_dir / "summary.txt").read_text()
    assert "seams found     2 of 2 true" in summary


def test_survey_sides_is_a_valid_builtin_script_ending_in_a_fist():
    steps = load_script("survey-sides")
    assert sum(bool(s.get("ok")) for s in steps) == 3
    assert steps[-1].get("fist")
