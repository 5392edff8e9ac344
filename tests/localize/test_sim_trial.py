"""``localize-and-weld`` with ``scope = "localize"`` (the localization part alone, simulated cell) and the
Table 1 protocol through ``weldcell study`` (profiles/cell3-localize-table1-sim.toml)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from weldcell.sdk.errors import JobError
from weldcell.sdk.jobs import run_job
from weldcell.sdk.plugins import get_plugin_manager
from weldcell.sdk.scale.cluster import ClusterOptions
from weldcell.sdk.scale.study import run_study

BASE = Path(__file__).resolve().parents[2] / "profiles" / "cell3-localize-table1-sim.toml"


def _profile(tmp_path: Path, extra: str) -> Path:
    p = tmp_path / "profile.toml"
    p.write_text(f"extends = {json.dumps(str(BASE))}\ncell.seed = 11\n{extra}\n", encoding="utf-8")
    return p


def test_localize_scope_finds_the_placement_and_reports_errors_against_the_truth(tmp_path):
    extra = (
        '[job.settings.worker]\nplacement_x = "9 mm"\nplacement_y = "-12 mm"\nplacement_theta = "15 deg"\n'
    )
    run_dir, result = run_job(_profile(tmp_path, extra), get_plugin_manager(), runs_dir=tmp_path / "runs")
    f = result["figures"]
    assert f["true_placement"]["x"] == pytest.approx(0.009) and f["true_placement"]["y"] == pytest.approx(
        -0.012
    )
    loc = f["localization"]
    assert loc["status"] == "ok", loc["message"]
    err = loc["error_vs_truth"]  # members are off CAD by up to 2 mm: the rigid pose within about 1 mm
    assert abs(err["x_mm"]) < 1.5 and abs(err["y_mm"]) < 1.5 and abs(err["theta_deg"]) < 0.2
    # against the pose a perfect measurement of the as-built part would return: the localization's own error
    ref = f["asbuilt_reference"]
    assert ref["n_crossings"] > 100 and 0.0 < ref["rms_mm"] < 2.0
    built = loc["pose_error_vs_asbuilt"]
    assert abs(built["x_mm"]) < 0.3 and abs(built["y_mm"]) < 0.3 and abs(built["theta_deg"]) < 0.05
    assert set(loc["pose_error_vs_asbuilt_outline"]) == {"x_mm", "y_mm", "theta_deg"}
    w = f["welds_vs_truth"]  # the welds re-planned from their members: well under the members' deviation
    assert w["points"] > 0 and w["wrong"] == 0 and w["max_claimed_mm"] < 1.0
    assert w["rms_x_mm"] < f["welds_rigid_vs_truth"]["rms_x_mm"] + 0.05
    assert not (run_dir / "weld_path.json").exists() and not (run_dir / "programs").exists()  # no weld


def test_localize_scope_fails_a_placement_beyond_the_inspected_envelope(tmp_path):
    extra = '[job.settings.worker]\nplacement_x = "90 mm"\nplacement_y = "0 mm"\nplacement_theta = "0 deg"\n'
    with pytest.raises(JobError, match="weld this workpiece by hand|by hand"):
        run_job(_profile(tmp_path, extra), get_plugin_manager(), runs_dir=tmp_path / "runs")


def test_table1_protocol_runs_through_weldcell_study(tmp_path):
    """Two trials in this process: the drawn placement reaches the job, and the study's statistics hold the
    figures Table 1 reports (pose error X/Y/theta, weld errors, uncertain share, wrong answers)."""
    vary = [
        "job.settings.worker.placement_x=uniform(-15 mm, 15 mm)",
        "job.settings.worker.placement_y=uniform(-15 mm, 15 mm)",
        "job.settings.worker.placement_theta=uniform(-20 deg, 20 deg)",
        "job.settings.template=choice(truss)",
    ]
    study = run_study(BASE, 2, vary, tmp_path / "study", ClusterOptions(workers=0), seed=3)
    assert study["counts"]["ok"] == 2 and study["failure_rate"] == 0.0
    for t in study["trials"].values():
        drawn = t["values"]["job.settings.worker.placement_x"]
        assert t["figures"]["true_placement.x"] == pytest.approx(drawn)
    st = study["statistics"]
    for k in (
        "localization.error_vs_truth.x_mm",
        "localization.error_vs_truth.y_mm",
        "localization.error_vs_truth.theta_deg",
        "welds_vs_truth.rms_x_mm",
        "welds_vs_truth.uncertain_fraction",
        "welds_vs_truth.wrong",
    ):
        assert st[k]["n"] == 2, k
    assert st["welds_vs_truth.wrong"]["max"] == 0
