"""The prior map of a second visit on a real robot (``revisit.prior_map``, §II-E): checked when the profile
is loaded (one clear error for a missing or bad map), fetched from a map server, and used by the job."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from weldcell.plugins.map_transfer.stage import MapTransfer, TransferSettings
from weldcell.plugins.mapping.prior_map import check_prior_map, resolve_prior_map
from weldcell.plugins.mapping.settings import MapJobSettings
from weldcell.sdk.jobs import run_job
from weldcell.sdk.profile import ProfileError, load_profile, validate_profile

PROFILE = Path(__file__).resolve().parents[2] / "profiles" / "cell4-map-sim.toml"


@pytest.fixture
def job_pm(map_pm):
    """The mapping job's plugins: mapping, the detector, and the map-transfer and relocalizer stages."""
    import weldcell.plugins.map_transfer as transfer_plugin
    import weldcell.plugins.relocalize as relocalize_plugin

    map_pm.register(transfer_plugin, "map_transfer", distribution="weldcell")
    map_pm.register(relocalize_plugin, "relocalize", distribution="weldcell")
    return map_pm


@pytest.fixture
def serve():
    from weldcell.plugins.map_transfer.server import MapServer

    started = []

    def start(root):
        started.append(MapServer(root, "tcp://127.0.0.1:*").start())
        return started[-1]

    yield start
    for srv in started:
        srv.stop()


def _map(root: Path, n_segments: int = 2) -> Path:
    w = MapTransfer(TransferSettings()).writer(root)
    rng = np.random.default_rng(0)
    for i in range(n_segments):
        T = np.eye(4)
        T[0, 3] = 4.0 * i
        extra = {"keyframe_poses": {str(i): np.eye(4).tolist()}}
        w.add(i, rng.uniform(0, 4, (2000, 3)), None, T, 4.0, [i], extra)
    w.finish()
    return root


def _problem(value) -> str:
    with pytest.raises(ValueError) as e:
        check_prior_map(str(value))
    return str(e.value)


def test_prior_map_setting_accepts_a_map_a_run_folder_or_an_address(tmp_path):
    m = _map(tmp_path / "run" / "map")
    assert MapJobSettings(revisit={"prior_map": str(m)}).revisit.prior_map == str(m)
    assert check_prior_map(str(tmp_path / "run")) == str(tmp_path / "run")  # a run folder: its map
    assert check_prior_map("tcp://192.168.1.20:5599") == "tcp://192.168.1.20:5599"
    assert MapJobSettings().revisit.prior_map is None


def test_a_missing_or_bad_prior_map_is_one_clear_error(tmp_path):
    assert "does not exist" in _problem(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    assert "no manifest.json" in _problem(tmp_path / "empty")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "manifest.json").write_text("{not json")
    assert "not readable JSON" in _problem(bad)
    (bad / "manifest.json").write_text(json.dumps({"schema": "weldcell/keyframes@1"}))
    assert "is not weldcell/map-segments@1" in _problem(bad)
    m = _map(tmp_path / "m")
    doc = json.loads((m / "manifest.json").read_text())
    (m / "manifest.json").write_text(json.dumps({**doc, "complete": False}))
    assert "not complete" in _problem(m)
    (m / "manifest.json").write_text(json.dumps(doc))
    f = m / doc["segments"][1]["file"]
    f.write_bytes(f.read_bytes()[:-7])  # a copy cut short
    assert "local map 1" in _problem(m) and "wrong size" in _problem(m)
    assert "tcp://HOST:PORT" in _problem("tcp://robot")


def test_profile_load_names_the_setting_of_a_missing_prior_map(tmp_path, job_pm):
    p = tmp_path / "revisit.toml"
    p.write_text(
        f'extends = "{PROFILE}"\n[job.settings]\n'
        f'revisit = {{ enabled = true, prior_map = "{tmp_path / "no-map"}" }}\n'
    )
    with pytest.raises(ProfileError) as e:
        validate_profile(load_profile(p), job_pm.registry, extra_checks=job_pm.check_profile)
    lines = [ln for ln in e.value.problems if "prior_map" in ln]
    assert len(lines) == 1 and "does not exist" in lines[0] and "RUN/map" in lines[0]


def test_prior_map_is_fetched_from_a_map_server(tmp_path, serve):
    robot = _map(tmp_path / "robot")
    srv = serve(robot)
    transfer = MapTransfer(TransferSettings(fetch_wait=5.0))
    ctx = SimpleNamespace(
        settings=MapJobSettings(revisit={"prior_map": srv.address}),
        path=lambda rel: tmp_path / "run" / rel,
        stage=lambda role: transfer,
    )
    folder = resolve_prior_map(ctx)
    assert folder == tmp_path / "run" / "prior_map"
    a, b = (json.loads((d / "manifest.json").read_text())["segments"] for d in (robot, folder))
    assert [e["sha256"] for e in a] == [e["sha256"] for e in b]
    # what the relocalization's priors read from a fetched map (local maps only): the key-frame poses
    from weldcell.plugins.mapping.visits import _prior_visit

    prior, heading = _prior_visit(folder)
    assert heading is None and len(prior.estimator.keyframes) == 2
    assert np.allclose(prior.estimator.keyframes[1].T_world_imu[:3, 3], [4.0, 0, 0])


@pytest.mark.slow
def test_a_later_run_relocalizes_on_the_prior_map_and_updates_it(job_pm, tmp_path):
    """Two runs of the job (as on a robot): the first maps the site; the second, with revisit.prior_map set
    to the first run's map folder, is relocalized on it and writes map v2 (unchanged local maps
    byte-identical to the prior map's)."""
    common = (
        "route = { length = 5.0, cruise_speed = 1.0 }\nmap = { tsdf = false }\n"
        "segmentation = { max_distance = 2.0, evaluate_ae = false }\n"
    )
    p1 = tmp_path / "first.toml"
    p1.write_text(f'extends = "{PROFILE}"\n[job.settings]\n{common}revisit = {{ enabled = false }}\n')
    run1, r1 = run_job(p1, job_pm, runs_dir=tmp_path / "runs")
    assert r1["status"] == "ok"
    before = {f.name: f.read_bytes() for f in (run1 / "map").iterdir() if f.is_file()}
    p2 = tmp_path / "second.toml"
    p2.write_text(
        f'extends = "{PROFILE}"\n[job.settings]\n{common}'
        f'revisit = {{ enabled = true, prior_map = "{run1}" }}\n'
    )
    run2, r2 = run_job(p2, job_pm, runs_dir=tmp_path / "runs")
    v2 = r2["figures"]["visit2"]
    assert v2["relocalization_status"] == "ok", v2
    assert "yaw" in v2["relocalization_priors"]  # the heading both runs recorded
    doc = json.loads((run2 / "visit2" / "relocalization.json").read_text())
    T = np.array(doc["T_prior_current"])
    assert np.linalg.norm(T[:3, 3]) < 0.3  # both runs start at the same place of the site
    index = json.loads((run2 / "map_versions" / "index.json").read_text())
    assert index["current"] == "v2"
    prior = {e["id"]: e for e in json.loads((run1 / "map" / "manifest.json").read_text())["segments"]}
    v2_doc = json.loads((run2 / "map_versions" / "v2" / "manifest.json").read_text())
    new = {e["id"]: e for e in v2_doc["segments"]}
    assert set(new) == set(prior)
    for i in v2["unchanged_segments"]:
        assert new[i]["sha256"] == prior[i]["sha256"]
    # the prior map itself is never written to
    assert {f.name: f.read_bytes() for f in (run1 / "map").iterdir() if f.is_file()} == before


def test_a_relative_prior_map_is_relative_to_the_profile_and_checked_before_driving(tmp_path):
    """As every path in a profile, `prior_map = "runs/x/map"` is relative to the profile that sets it, not
    to the shell's folder; a wrong one is refused when the job starts, before the robot drives."""
    from weldcell.plugins.mapping.prior_map import check_at_start, configured_folder
    from weldcell.sdk.errors import DataError

    m = _map(tmp_path / "cell" / "runs" / "first" / "map")
    profile = tmp_path / "cell" / "revisit.toml"

    def ctx(value):
        return SimpleNamespace(
            settings=MapJobSettings(revisit={"prior_map": value}),
            loaded=SimpleNamespace(source_of=lambda keypath: profile),
        )

    assert check_prior_map("runs/first") == "runs/first"  # not checked against the shell's folder
    assert configured_folder(ctx("runs/first")) == m
    check_at_start(ctx("runs/first"))
    with pytest.raises(DataError, match="does not exist"):
        check_at_start(ctx("runs/second"))
