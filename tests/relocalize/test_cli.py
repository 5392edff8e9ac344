"""``weldcell map relocalize``: exit 0 verified, 1 failed (result still written), 2 bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from weldcell.plugins.relocalize import synth
from weldcell.plugins.relocalize.inputs import parse_position, parse_yaw
from weldcell.sdk.cli import main
from weldcell.sdk.cloud import PointCloud, write_cloud

SIZE = (20.0, 16.0)
T_TRUE = synth.pose(1.5, -1.0, 0.0, math.radians(30))


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    d = tmp_path_factory.mktemp("reloc")
    site = synth.site_cloud(seed=2, size=SIZE)
    write_cloud(d / "prior.ply", PointCloud(site))
    write_cloud(d / "current.pcd", PointCloud(synth.visit(site, (10.0, 8.0), 6.0, T_TRUE, seed=1)))
    write_cloud(d / "other.ply", PointCloud(synth.site_cloud(seed=21, size=SIZE)))
    return d


def _run(*args):
    return CliRunner().invoke(main, ["map", "relocalize", *map(str, args)])


def test_cli_relocalizes_with_priors(clouds):
    out = clouds / "ok.json"
    r = _run(
        clouds / "prior.ply", clouds / "current.pcd", "-o", out, "--yaw", "33±5", "--position", "2.5,-2,0±2"
    )
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert doc["status"] == "ok" and doc["priors_used"] == ["yaw", "position"]
    assert np.allclose(np.array(doc["T_prior_current"]), T_TRUE, atol=0.05)


def test_cli_other_site_fails_with_exit_1_and_writes_the_reason(clouds):
    out = clouds / "fail.json"
    r = _run(clouds / "other.ply", clouds / "current.pcd", "-o", out, "--yaw", "30", "--position", "1.5,-1,0")
    assert r.exit_code == 1, r.output
    doc = json.loads(out.read_text())
    assert doc["status"] == "failed" and doc["reason"] and doc["confidence"] == 0.0


@pytest.mark.parametrize(
    "args",
    [
        ("missing.ply", "current.pcd"),
        ("prior.ply", "current.pcd", "--yaw", "north"),
        ("prior.ply", "current.pcd", "--position", "1,2"),
        ("prior.ply", "current.pcd", "--yaw", "30±-4"),
    ],
)
def test_cli_bad_input_exit_2(clouds, args):
    a, b, *rest = args
    r = _run(clouds / a, clouds / b, "-o", clouds / "x.json", *rest)
    assert r.exit_code == 2, r.output
    assert "error" in r.output


def test_cli_damaged_cloud_exit_2(clouds):
    bad = clouds / "bad.ply"
    bad.write_bytes((clouds / "prior.ply").read_bytes()[:400])
    r = _run(bad, clouds / "current.pcd", "-o", clouds / "x.json")
    assert r.exit_code == 2, r.output


def test_prior_option_parsing():
    assert parse_yaw("45±10") == pytest.approx((math.radians(45), math.radians(10)))
    assert parse_yaw("45 +- 10")[1] == pytest.approx(math.radians(10))
    p, s = parse_position("1,-2.5,0.3±0.5")
    assert np.allclose(p, [1, -2.5, 0.3]) and s == 0.5
    assert parse_yaw(None)[0] is None and parse_position(None)[0] is None


def test_map_folder_with_keyframe_store_is_read(tmp_path):
    from weldcell.plugins.relocalize.inputs import load_map, sample_keyframes

    site = synth.site_cloud(seed=2, size=(8.0, 6.0), spacing=0.2)
    write_cloud(tmp_path / "map.ply", PointCloud(site))
    path = np.column_stack([np.linspace(0, 30, 61), np.zeros(61), np.zeros(61)])  # 30 m straight, 0.5 m apart
    recs = []
    for i, p in enumerate(path):
        T = np.eye(4)
        T[:3, 3] = p
        recs.append({"index": i, "T_world_imu": T.tolist(), "T_world_cam": T.tolist()})
    doc = {"schema": "weldcell/keyframes@1", "keyframes": recs}
    (tmp_path / "keyframes.json").write_text(json.dumps(doc))
    m = load_map(tmp_path)
    assert len(m.points) == len(site) and np.allclose(m.keyframe_positions, path)
    # §II-E: key frames within twice the current travelled distance (5 m -> 10 m), one per 2 m cell
    kf = sample_keyframes(m.keyframe_positions, path[:11], spacing=2.0)
    assert kf[:, 0].max() <= 10.0 and len(kf) == 6
    (tmp_path / "keyframes.json").write_text(json.dumps({"schema": "other@1", "keyframes": recs}))
    r = CliRunner().invoke(
        main, ["map", "relocalize", str(tmp_path), str(tmp_path), "-o", str(tmp_path / "r.json")]
    )
    assert r.exit_code == 2 and "key-frame store" in r.output
