"""The ``map`` job end to end in the simulated site, and ``--resume`` from the last key frame."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from weldcell.sdk.jobs import run_job

PROFILE = Path(__file__).resolve().parents[2] / "profiles" / "cell4-map-sim.toml"


def _profile(tmp_path, text: str) -> Path:
    p = tmp_path / "short.toml"
    p.write_text(f'extends = "{PROFILE}"\n{text}')
    return p


def test_map_job_then_resume_from_the_last_keyframe(map_pm, tmp_path):
    """A 5 m route: interrupted after 30 camera frames, resumed to the end; the run's result carries
    ate_rmse_m and the map folder holds the key-frame store (nothing captured twice)."""
    short = _profile(
        tmp_path, "[job.settings]\nroute = { length = 5.0, cruise_speed = 1.0 }\nmax_frames = 30\n"
    )
    run, first = run_job(short, map_pm, runs_dir=tmp_path / "runs")
    assert first["status"] == "ok"
    n_first = first["figures"]["keyframes"]
    assert n_first >= 3
    full = _profile(tmp_path, "[job.settings]\nroute = { length = 5.0, cruise_speed = 1.0 }\n")
    _, result = run_job(full, map_pm, run_dir=run)
    f = result["figures"]
    assert result["status"] == "ok" and f["keyframes"] > n_first
    assert 0 < f["ate_rmse_m"] < 0.3
    assert "ate_frames_slerp_m" in f and "ate_frames_linear_m" in f
    store = json.loads((run / "map" / "keyframes.json").read_text())
    idx = [k["index"] for k in store["keyframes"]]
    assert idx == list(range(len(idx))) and len(idx) == f["keyframes"]
    caps = json.loads((run / "state.json").read_text())["captures"]
    assert [c["keyframe"] for c in caps] == idx  # each key frame recorded once, across the resume
    assert all("detections" in c for c in caps)  # the detector's output is kept with its key frame
    assert all((run / "map" / k["file"]).is_file() for k in store["keyframes"])
    assert (run / "map" / "map.ply").is_file() and (run / "trajectory_keyframes.tum").is_file()
    events = json.loads((run / "events.json").read_text())["events"]
    assert any(e["kind"] == "recovered" and "resumed" in e["message"] for e in events)
    regions = json.loads((run / "regions.json").read_text())
    assert regions["schema"] == "weldcell/weld-regions@1"
    assert (run / "report" / "trajectory.png").is_file() and (run / "report" / "map.png").is_file()


def test_job_refuses_a_camera_without_colour(map_pm, tmp_path):
    p = _profile(tmp_path, "[job.settings]\nmax_frames = 12\n[devices.camera.settings]\ncolor = false\n")
    from weldcell.sdk.errors import DataError

    with pytest.raises(DataError, match="colour"):
        run_job(p, map_pm, runs_dir=tmp_path / "runs")
