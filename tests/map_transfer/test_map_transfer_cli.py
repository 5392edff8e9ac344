"""``weldcell map segment | serve | fetch`` from the command line."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner
from map_transfer_data import corridor
from scipy.spatial.transform import Rotation
from weldcell.plugins.map_transfer.segments import read_manifest
from weldcell.sdk.cli import main
from weldcell.sdk.cloud import PointCloud, write_cloud


def _text(r) -> str:
    """The command's output with the console's line wrapping undone."""
    return " ".join(r.output.split())


def _inputs(tmp_path):
    pts, col, traj = corridor(20_000, length=35.0)
    write_cloud(tmp_path / "map.ply", PointCloud(pts, colors=col, frame="world"))
    q = Rotation.from_matrix(traj.T_world[:, :3, :3]).as_quat()
    rows = np.column_stack([np.arange(len(q)) * 0.1, traj.T_world[:, :3, 3], q])
    np.savetxt(tmp_path / "traj.tum", rows)
    return pts


def test_segment_then_fetch_with_a_token(tmp_path, serve, monkeypatch):
    _inputs(tmp_path)
    r = CliRunner().invoke(
        main,
        [
            "map",
            "segment",
            str(tmp_path / "map.ply"),
            "--trajectory",
            str(tmp_path / "traj.tum"),
            "-o",
            str(tmp_path / "robot"),
        ],
    )
    assert r.exit_code == 0, r.output
    m = read_manifest(tmp_path / "robot")
    assert len(m["segments"]) == 3 and m["complete"] and "error max" in _text(r)
    srv = serve(tmp_path / "robot", token="op-token-123")
    monkeypatch.setenv("WELDCELL_MAP_TOKEN", "op-token-123")
    r = CliRunner().invoke(
        main, ["map", "fetch", srv.address, "-o", str(tmp_path / "op"), "--timeout", "0.5"]
    )
    assert r.exit_code == 0, r.output
    assert "received 3 segments" in _text(r) and "op-token-123" not in _text(r)
    assert [e["sha256"] for e in read_manifest(tmp_path / "op")["segments"]] == [
        e["sha256"] for e in m["segments"]
    ]
    monkeypatch.setenv("WELDCELL_MAP_TOKEN", "wrong")
    r = CliRunner().invoke(
        main, ["map", "fetch", srv.address, "-o", str(tmp_path / "op2"), "--timeout", "0.5"]
    )
    assert r.exit_code == 2 and "refused" in _text(r) and "op-token-123" not in _text(r)


def test_bad_inputs_are_one_clear_error(tmp_path, monkeypatch):
    monkeypatch.delenv("WELDCELL_MAP_TOKEN", raising=False)
    r = CliRunner().invoke(main, ["map", "serve", str(tmp_path), "--seconds", "0.1"])
    assert r.exit_code == 2 and "no manifest.json" in _text(r) and "weldcell map segment" in _text(r)
    r = CliRunner().invoke(
        main,
        ["map", "fetch", "tcp://127.0.0.1:9", "-o", str(tmp_path / "o"), "--token-env", "NO_SUCH_TOKEN_VAR"],
    )
    assert r.exit_code == 2 and "NO_SUCH_TOKEN_VAR" in _text(r)
    (tmp_path / "c.ply").write_text("ply\n")
    r = CliRunner().invoke(main, ["map", "segment", str(tmp_path / "c.ply"), "-o", str(tmp_path / "x")])
    assert r.exit_code == 2 and "trajectory" in _text(r)


def test_segment_a_map_folder_of_the_mapping_job(tmp_path):
    """A map folder (map.ply + keyframes.json, weldcell/keyframes@1) is segmented with its key frames."""
    from weldcell.plugins.map_transfer.cli import segment_command

    pts, col, traj = corridor(8_000, length=20.0)
    folder = tmp_path / "map"
    write_cloud(folder / "map.ply", PointCloud(pts, colors=col, frame="world"))
    kfs = [{"index": 10 + i, "t": 0.5 * i, "T_world_cam": T.tolist()} for i, T in enumerate(traj.T_world)]
    (folder / "keyframes.json").write_text(json.dumps({"schema": "weldcell/keyframes@1", "keyframes": kfs}))
    r = CliRunner().invoke(segment_command, [str(folder), "-o", str(tmp_path / "seg"), "--encoding", "ply"])
    assert r.exit_code == 0, r.output
    m = read_manifest(tmp_path / "seg")
    assert len(m["segments"]) == 2 and m["segments"][1]["keyframes"][0] > 10
    assert sum(e["points"] for e in m["segments"]) == len(pts)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_command_in_its_own_process(tmp_path, small_map, monkeypatch):
    """`weldcell map serve` as the robot would run it; Ctrl-C (SIGINT) stops it."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from weldcell.plugins.map_transfer.client import FetchSettings, MapClient
    from weldcell.plugins.map_transfer.segments import SegmentSettings, write_segmented_map

    pts, col, traj = small_map
    write_segmented_map(tmp_path / "robot", pts, col, traj, SegmentSettings(encoding="ply"))
    address = f"tcp://127.0.0.1:{_free_port()}"
    env = dict(os.environ, WELDCELL_MAP_TOKEN="tok-42")
    cmd = [
        sys.executable,
        "-m",
        "weldcell.sdk.cli",
        "map",
        "serve",
        str(tmp_path / "robot"),
        "--bind",
        address,
    ]
    def as_from_a_terminal() -> None:
        # Ctrl-C reaches a command started from a shell; the pytest worker this test runs in may have
        # SIGINT ignored or blocked (both are inherited across exec), and a Python started with SIGINT
        # ignored never raises KeyboardInterrupt. Give the child what a terminal gives it.
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})

    proc = subprocess.Popen(
        cmd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=as_from_a_terminal,  # noqa: PLW1509 - no threads of ours start before exec
    )
    try:
        with MapClient(address, tmp_path / "op", "tok-42", FetchSettings(timeout=1.0, retries=20)) as c:
            rep = c.fetch()
        assert rep.complete and len(rep.segments) == 4
    finally:
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=15)
    assert proc.returncode == 130 and "token required" in err and "tok-42" not in err
    assert "served" in err
