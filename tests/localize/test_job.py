"""The job ``localize-and-weld`` end to end in the simulated cell, on a small frame (fast variant of
profiles/cell3-localize-sim.toml): guided placement, inspection, localization, re-planned and executed
weld; the failure path (a placement beyond the search window stops before any weld); a laser that drops
mid-inspection and the ``--resume`` that continues it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from weldcell.plugins.localize import acquisition as acq
from weldcell.plugins.localize.cad import derive_welds
from weldcell.plugins.localize.scan_io import read_laser_scan
from weldcell.plugins.localize.template import Member, Template
from weldcell.sdk.artifacts import read_json
from weldcell.sdk.errors import DeviceError, JobError
from weldcell.sdk.jobs import run_job
from weldcell.sdk.plugins import get_plugin_manager
from weldcell.sdk.weldpath import WeldPath

PROFILE = """
schema = "weldcell/profile@1"
name = "cell3-test"
[job]
name = "localize-and-weld"
[job.settings]
template = "frame.json"
calibrate_projector = false
weld_speed = "20 mm/s"
approach_distance = "30 mm"
[job.settings.guidance]
envelope_step = "150 mm"
{guide}
[job.settings.plan]
span = "35 mm"
spacing = "{spacing}"
end_margin = "10 mm"
speed = "200 mm/s"
accel = "2 m/s^2"
check_angle = "10 deg"
[job.settings.worker]
{worker}
[cell]
seed = 5
[cell.safety]
workspace_min = [0.2, -1.0, -0.05]
workspace_max = [1.8, 1.0, 1.5]
max_linear_speed = "250 mm/s"
max_linear_accel = "2.5 m/s^2"
path_check_step = "15 mm"
[devices.robot]
plugin = "robot.sim"
settings = {{ model = "abb-irb2600", start_xyz = [1.0, 0.0, 0.6], tcp_xyz = [0.0, 0.0, "350 mm"] }}
[devices.laser]
plugin = "displacement.sim"
mount = {{ parent = "robot.flange", xyz = ["80 mm", "0 mm", "300 mm"] }}
settings = {{ latency = "3 ms" {laser} }}
[devices.projector]
plugin = "projector.sim"
mount = {{ parent = "robot.flange", xyz = ["-80 mm", "0 mm", "50 mm"] }}
[stages.edges.settings]
spot_size = "2.5 mm"
[stages.path.settings]
standoff = "15 mm"
[output]
exporters = ["export.abb-rapid", "export.csv"]
{output}
"""


FIXED = "enabled = false\ncentre_in_envelope = false"  # no projector, the template where it is drawn


def rect(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def write_profile(
    folder: Path,
    worker: str = 'placement_offset = "15 mm"',
    laser: str = "",
    output: str = "",
    guide: str = "",
    spacing: str = "20 mm",
) -> Path:
    """A 240 x 360 mm frame: two rails, two rungs at uneven places (no symmetry)."""
    members = [
        Member("rail-a", 0.05, rect(0.88, -0.18, 0.92, 0.18)),
        Member("rail-b", 0.05, rect(1.08, -0.18, 1.12, 0.18)),
        Member("rung-1", 0.04, rect(0.92, -0.16, 1.08, -0.12)),
        Member("rung-2", 0.04, rect(0.92, 0.06, 1.08, 0.10)),
    ]
    Template(members, derive_welds(members, 0.0)).save(folder / "frame.json")
    p = folder / "cell3-test.toml"
    p.write_text(PROFILE.format(worker=worker, laser=laser, output=output, guide=guide, spacing=spacing))
    return p


@pytest.fixture(scope="module")
def good_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cell3")
    return run_job(write_profile(folder), get_plugin_manager(), runs_dir=folder / "runs")


def test_the_job_localizes_the_placed_frame_and_welds_the_true_seams(good_run):
    run, result = good_run
    f = result["figures"]
    assert result["status"] == "ok", result.get("error")
    loc = f["localization"]
    assert loc["status"] == "ok" and loc["fit_error_mean"] < 2.5e-3
    truth = f["true_placement"]
    assert max(abs(truth["x"]), abs(truth["y"])) > 1e-3  # the worker's error was real ...
    err = loc["error_vs_truth"]
    assert abs(err["x_mm"]) < 0.5 and abs(err["y_mm"]) < 0.5 and abs(err["theta_deg"]) < 0.1  # ... and found
    assert f["acquisition"]["latency"]["estimated"]
    assert f["acquisition"]["latency_s"] == pytest.approx(0.003, abs=0.0012)  # 3 ms; coupling drift ±1 ms
    path = WeldPath.from_json(run / "weld_path.json")
    assert len(path.seams) == 4
    assert path.metrics["max_mm"] < 2.5  # members vary by ±2 mm from CAD; the re-planned seams follow them
    assert f["execute"]["status"] == "done"
    state = read_json(run / "state.json")
    assert (
        state["steps"]["weld"]["status"] == "done" and state["steps"]["guided placement"]["status"] == "done"
    )
    assert "MoveL" in (run / "programs" / "weld_path.mod").read_text()
    for name in ("localization.png", "inspection.png", "scan.png", "members.png", "summary.txt"):
        assert (run / name).stat().st_size > 500, name
    summary = (run / "summary.txt").read_text()
    assert "theta" in summary and "covariance" in summary and "status: ok" in summary
    assert read_json(run / "localization.json")["schema"] == "weldcell/localization@1"


def test_the_raw_recording_re_synchronises_offline_to_the_same_scan(good_run):
    run, result = good_run
    rec = acq.load_recording(run)
    plan = read_json(run / "inspection" / "plan.json")
    assert [ln.index for ln in rec.lines] == list(range(len(plan["lines"])))
    assert rec.T_flange_sensor[2, 3] == pytest.approx(0.30)
    assert rec.latency == pytest.approx(result["figures"]["acquisition"]["latency_s"])
    offline = acq.scan_from_run(run)  # what `weldcell localize TEMPLATE RUN_DIR` reads
    scan = read_laser_scan(run / "scan.csv")
    assert len(offline) == len(scan)
    np.testing.assert_allclose(scan.xyz[:, :2], offline.xyz[:, :2], atol=1e-6)
    gaps = np.isnan(scan.xyz[:, 2])
    assert 0 < gaps.mean() < 0.2  # out-of-range readings and edge dropouts stay gaps, never zeros


def test_a_placement_beyond_the_search_window_fails_before_any_weld(tmp_path):
    profile = write_profile(
        tmp_path, worker='placement = ["150 mm", "60 mm", "30 deg"]', guide=FIXED, spacing="40 mm"
    )
    with pytest.raises(JobError) as e:
        run_job(profile, get_plugin_manager(), runs_dir=tmp_path / "runs")
    assert "by hand" in e.value.message + e.value.fix
    run = next((tmp_path / "runs").iterdir())
    result = read_json(run / "result.json")
    assert result["status"] == "failed"
    assert result["figures"]["localization"]["status"] in ("failed", "ambiguous")
    steps = read_json(run / "state.json")["steps"]
    assert (
        "weld" not in steps and "check weld motions (safety gate)" not in steps
    )  # nothing reached the robot
    assert not (run / "weld_path.json").exists()
    assert "FAILED" in (run / "summary.txt").read_text()


def test_a_laser_that_drops_mid_inspection_keeps_its_lines_and_resume_continues(good_run, tmp_path):
    good, _ = good_run
    lines = acq.load_recording(good).lines
    drop = 0.5 * (lines[0].t_start + lines[-1].t_end)  # simulated time in the middle of the inspection
    profile = write_profile(tmp_path, laser=f", stop_after = {drop}", output="report = false", guide=FIXED)
    with pytest.raises(DeviceError) as e:
        run_job(profile, get_plugin_manager(), runs_dir=tmp_path / "runs")
    assert "--resume" in e.value.fix
    run = next((tmp_path / "runs").iterdir())
    state = read_json(run / "state.json")
    kept = [c for c in state["captures"] if c["kind"] == "inspection-line"]
    assert 0 < len(kept) < len(lines)
    assert state["notes"]["partial_lines"]  # the line that was cut is kept too
    before = {c["file"]: (run / c["file"]).read_bytes() for c in kept}

    # the operator reconnects the sensor (the profile without the simulated cable pull) and resumes
    write_profile(tmp_path, output="report = false", guide=FIXED)
    run2, result = run_job(profile, get_plugin_manager(), run_dir=run)
    assert run2 == run and result["status"] == "ok", result.get("error")
    state = read_json(run / "state.json")
    files = [c["file"] for c in state["captures"] if c["kind"] == "inspection-line"]
    assert len(files) == len(lines) and len(set(files)) == len(files)  # each line once, none rescanned
    assert all((run / f).read_bytes() == b for f, b in before.items())
    assert abs(result["figures"]["localization"]["error_vs_truth"]["x_mm"]) < 0.5


def test_weldcell_localize_on_the_run_folder_finds_the_jobs_pose(good_run, tmp_path):
    from click.testing import CliRunner
    from weldcell.sdk.cli import main

    run, _ = good_run
    out = tmp_path / "offline.json"
    args = ["localize", str(run / "template_planned.json"), str(run), "-o", str(out)]  # as the job placed it
    r = CliRunner().invoke(main, [*args, "--set", "edges.spot_size=2.5 mm"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    offline, job = read_json(out), read_json(run / "localization.json")
    assert offline["status"] == "ok"
    assert abs(offline["x"] - job["x"]) < 1e-4 and abs(offline["y"] - job["y"]) < 1e-4
    assert abs(offline["theta"] - job["theta"]) < np.radians(0.01)
