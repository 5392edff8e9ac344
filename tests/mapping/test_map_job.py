"""The ``map`` job end to end in the simulated site, and ``--resume`` from the last key frame."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from weldcell.sdk.jobs import run_job

PROFILE = Path(__file__).resolve().parents[2] / "profiles" / "cell4-map-sim.toml"


def _profile(tmp_path, text: str, name: str = "short.toml") -> Path:
    p = tmp_path / name
    p.write_text(f'extends = "{PROFILE}"\n{text}')
    return p


@pytest.fixture
def job_pm(map_pm):
    """The mapping job's plugins: mapping, the detector, and the map-transfer and relocalizer stages."""
    import weldcell.plugins.map_transfer as transfer_plugin
    import weldcell.plugins.relocalize as relocalize_plugin

    map_pm.register(transfer_plugin, "map_transfer", distribution="weldcell")
    map_pm.register(relocalize_plugin, "relocalize", distribution="weldcell")
    return map_pm


NO_REVISIT = "revisit = { enabled = false }\nsegmentation = { max_distance = 2.0, evaluate_ae = false }\n"


def test_map_job_then_resume_from_the_last_keyframe(job_pm, tmp_path):
    """A 5 m route: interrupted after 30 camera frames, resumed to the end; the run's result carries
    ate_rmse_m and the map folder holds the key-frame store (nothing captured twice)."""
    short = _profile(
        tmp_path,
        "[job.settings]\nroute = { length = 5.0, cruise_speed = 1.0 }\nmax_frames = 30\n" + NO_REVISIT,
    )
    run, first = run_job(short, job_pm, runs_dir=tmp_path / "runs")
    assert first["status"] == "ok"
    n_first = first["figures"]["keyframes"]
    assert n_first >= 3
    full = _profile(tmp_path, "[job.settings]\nroute = { length = 5.0, cruise_speed = 1.0 }\n" + NO_REVISIT)
    _, result = run_job(full, job_pm, run_dir=run)
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
    # §II-D: local maps cut every 2 m; after the resume they are cut again from the stored key frames
    # (same cuts, every key frame in exactly one local map, served and fetched on loopback unchanged)
    seg = json.loads((run / "map" / "manifest.json").read_text())
    assert seg["schema"] == "weldcell/map-segments@1" and seg["complete"] and f["segments"] >= 2
    kfs = [k for e in seg["segments"] for k in e["keyframes"]]
    assert sorted(kfs) == idx and len(seg["segments"]) == f["segments"]
    assert all(e["handover"]["method"] in ("verified", "orb-ndt", "orb", "vio") for e in seg["segments"][1:])
    assert f["fetch_ok"] and f["fetch_segments"] == f["segments"]
    assert abs(f["ate_segmentation_change_pct"]) < 1.0  # Table III target: within +-1 %


def test_job_refuses_a_camera_without_colour(job_pm, tmp_path):
    p = _profile(tmp_path, "[job.settings]\nmax_frames = 12\n[devices.camera.settings]\ncolor = false\n")
    from weldcell.sdk.errors import DataError

    with pytest.raises(DataError, match="colour"):
        run_job(p, job_pm, runs_dir=tmp_path / "runs")


@pytest.mark.slow
def test_second_visit_relocalizes_and_updates_the_map(job_pm, tmp_path):
    """The whole cell-4 job on a short route: map (local maps served and fetched), then a second visit from
    another start with a box added and a column removed: relocalized on the map (magnetometer heading +
    prior key frames), map v2 written with the unchanged local maps byte-identical, both visits reported."""
    p = _profile(
        tmp_path,
        "[job.settings]\nroute = { length = 8.0, cruise_speed = 1.0 }\n"
        "segmentation = { max_distance = 3.0, evaluate_ae = false }\n"
        "revisit = { enabled = true, length = 4.0 }\nmap = { tsdf = false }\n",
    )
    run, result = run_job(p, job_pm, runs_dir=tmp_path / "runs")
    f = result["figures"]
    v2 = f["visit2"]
    assert v2["relocalization_status"] == "ok", v2
    # vs the ground truth through both visits' ATE alignments (a 4 m visit aligns its heading to a few deg)
    assert v2["relocalization_error_m"] < 0.3 and v2["relocalization_error_deg"] < 6.0
    doc = json.loads((run / "visit2" / "relocalization.json").read_text())
    assert doc["schema"] == "weldcell/relocalization@1" and "yaw" in doc["priors_used"]
    index = json.loads((run / "map_versions" / "index.json").read_text())
    assert index["current"] == "v2"
    m1 = {
        e["id"]: e
        for e in json.loads((run / "map_versions" / "v1" / "manifest.json").read_text())["segments"]
    }
    m2 = {
        e["id"]: e
        for e in json.loads((run / "map_versions" / "v2" / "manifest.json").read_text())["segments"]
    }
    assert set(m1) == set(m2)
    for i in v2["unchanged_segments"]:  # bit-identical
        assert (run / "map_versions" / "v2" / m2[i]["file"]).read_bytes() == (
            run / "map" / m1[i]["file"]
        ).read_bytes()
    assert all(m2[i]["sha256"] != m1[i]["sha256"] for i in v2["changed_segments"])
    report = (run / "report" / "report.md").read_text()
    assert "Second visit" in report and (run / "report" / "visits.png").is_file()
