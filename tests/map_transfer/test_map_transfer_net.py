"""Segment-wise map transmission over ZeroMQ on loopback: identity, growing maps, resume, damage, tokens."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from map_transfer_data import corridor, segments_of
from weldcell.plugins.map_transfer.client import FetchSettings, MapClient
from weldcell.plugins.map_transfer.segments import (
    SegmentSettings,
    SegmentWriter,
    read_manifest,
    write_segmented_map,
)
from weldcell.sdk.artifacts import sha256_file
from weldcell.sdk.errors import DataError, DeviceError, UsageError

FAST = FetchSettings(chunk_size=64 << 10, timeout=0.5, retries=4, wait=5.0, checkpoint_bytes=64 << 10)


def _same_map(server_dir: Path, client_dir: Path) -> None:
    ms, mc = read_manifest(server_dir), read_manifest(client_dir)
    assert mc["complete"] and [e["id"] for e in mc["segments"]] == [e["id"] for e in ms["segments"]]
    for e in ms["segments"]:
        assert sha256_file(client_dir / e["file"]) == e["sha256"]
    assert not list((client_dir / ".partial").iterdir())  # nothing half-done left behind


@pytest.fixture
def map_dir(tmp_path, small_map):
    pts, col, traj = small_map
    write_segmented_map(
        tmp_path / "robot", pts, col, traj, SegmentSettings(max_points=20_000, encoding="ply")
    )
    return tmp_path / "robot"


def test_served_map_is_fetched_identical(map_dir, tmp_path, serve):
    srv = serve(map_dir)
    with MapClient(srv.address, tmp_path / "op", settings=FAST) as c:
        rep = c.fetch()
    assert rep.complete and rep.segments == [0, 1, 2, 3] and rep.bad_chunks == 0
    _same_map(map_dir, tmp_path / "op")
    with MapClient(srv.address, tmp_path / "op", settings=FAST) as c:  # fetching again: nothing new
        again = c.fetch()
    assert again.segments == [] and again.skipped == [0, 1, 2, 3] and again.bytes == 0
    (tmp_path / "op" / read_manifest(map_dir)["segments"][2]["file"]).unlink()  # lost on the operator's side
    with MapClient(srv.address, tmp_path / "op", settings=FAST) as c:
        assert c.fetch().segments == [2]
    _same_map(map_dir, tmp_path / "op")


def test_map_with_one_segment(tmp_path, serve):
    pts, col, traj = corridor(5_000, length=5.0)
    m = write_segmented_map(tmp_path / "robot", pts, col, traj, SegmentSettings(encoding="draco"))
    assert len(m["segments"]) == 1
    srv = serve(tmp_path / "robot")
    with MapClient(srv.address, tmp_path / "op", settings=FAST) as c:
        assert c.fetch().segments == [0]
    _same_map(tmp_path / "robot", tmp_path / "op")


def test_first_segment_arrives_before_the_map_is_finished(tmp_path, small_map, serve):
    pts, col, traj = small_map
    segs = segments_of(pts, col, traj, max_points=20_000, encoding="ply")
    w = SegmentWriter(tmp_path / "robot", SegmentSettings(max_points=20_000, encoding="ply"))
    w.add(segs[0])
    srv = serve(tmp_path / "robot")
    got_first = threading.Event()
    seen: list[int] = []

    def on_segment(e):
        seen.append(e["id"])
        got_first.set()

    result = {}
    c = MapClient(srv.address, tmp_path / "op", settings=FAST)
    t = threading.Thread(target=lambda: result.setdefault("rep", c.fetch(on_segment=on_segment)))
    t.start()
    try:
        # the mapper writes the next segment only once the operator holds the first one
        assert got_first.wait(10.0), "the first segment did not arrive while the map was growing"
        assert not read_manifest(tmp_path / "robot")["complete"] and seen == [0]
        for s in segs[1:]:
            w.add(s)
        w.finish()
    finally:
        t.join(15.0)
        c.close()
    assert not t.is_alive()
    assert result["rep"].segments == [0, 1, 2, 3] and result["rep"].complete
    _same_map(tmp_path / "robot", tmp_path / "op")


def test_damaged_and_truncated_chunks_are_fetched_again(map_dir, tmp_path, serve):
    damaged = {"n": 0}

    def wire(seg, off, data):  # the first three chunks of segment 1 are damaged on the wire
        if seg == 1 and damaged["n"] < 3:
            damaged["n"] += 1
            return data[:-7] if damaged["n"] == 2 else bytes([data[0] ^ 0xFF]) + data[1:]
        return data

    srv = serve(map_dir, chunk_filter=wire)
    with MapClient(srv.address, tmp_path / "op", settings=FAST) as c:
        rep = c.fetch()
    assert rep.bad_chunks == 3 and rep.complete
    _same_map(map_dir, tmp_path / "op")


def test_token_is_required_and_never_echoed(map_dir, tmp_path, serve):
    srv = serve(map_dir, token="s3cret-weld-token")
    for wrong in (None, "guess"):
        with MapClient(srv.address, tmp_path / "op", token=wrong, settings=FAST) as c:
            with pytest.raises(UsageError, match="refused") as e:
                c.fetch()
        assert "s3cret" not in str(e.value) and "WELDCELL_MAP_TOKEN" in e.value.fix
    assert srv.stats["refused"] == 2 and srv.stats["chunks"] == 0
    assert not any(p.suffix == ".ply" for p in (tmp_path / "op").iterdir())
    with MapClient(srv.address, tmp_path / "op", token="s3cret-weld-token", settings=FAST) as c:
        assert c.fetch().complete
    _same_map(map_dir, tmp_path / "op")


def test_segment_damaged_on_the_robot_is_refused_and_earlier_ones_kept(map_dir, tmp_path, serve):
    m = read_manifest(map_dir)
    f = map_dir / m["segments"][1]["file"]
    raw = bytearray(f.read_bytes())
    raw[len(raw) // 2] ^= 0x01
    f.write_bytes(bytes(raw))
    srv = serve(map_dir)
    with MapClient(srv.address, tmp_path / "op", settings=FAST) as c:
        with pytest.raises(DataError, match="segment 1 .* fails its sha256 on the robot") as e:
            c.fetch()
    assert "re-run the segmentation" in e.value.fix
    local = read_manifest(tmp_path / "op")
    assert [x["id"] for x in local["segments"]] == [0] and not local["complete"]


def test_server_needs_a_manifest(tmp_path):
    from weldcell.plugins.map_transfer.server import MapServer

    with pytest.raises(DataError, match="no manifest.json"):
        MapServer(tmp_path, "tcp://127.0.0.1:*")


def test_silent_server_is_a_clear_error(tmp_path):
    quick = FetchSettings(timeout=0.1, retries=1)
    with MapClient("tcp://127.0.0.1:9", tmp_path / "op", settings=quick) as c:
        with pytest.raises(DeviceError, match="does not answer"):
            c.fetch()


def test_connection_dropped_mid_segment_resumes(map_dir, tmp_path, serve):
    """The server goes away in the middle of a segment and comes back on the same port."""
    slow = {"n": 0}

    def wire(seg, off, data):  # after 6 chunks the link crawls, so the server stops mid-map
        slow["n"] += 1
        time.sleep(0.2 if slow["n"] > 6 else 0.0)
        return data

    srv = serve(map_dir, chunk_filter=wire)
    address = srv.address
    result: dict = {}
    c = MapClient(address, tmp_path / "op", settings=FAST)
    t = threading.Thread(target=lambda: result.setdefault("rep", c.fetch()))
    t.start()
    try:
        deadline = time.monotonic() + 10
        while slow["n"] < 6 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert srv.stop()
        time.sleep(0.3)
        serve(map_dir, bind=address)
    finally:
        t.join(20.0)
        c.close()
    assert not t.is_alive()
    rep = result["rep"]
    assert rep.complete and rep.resends > 0 and rep.segments == [0, 1, 2, 3]
    _same_map(map_dir, tmp_path / "op")


_CLIENT = """
import sys
from weldcell.plugins.map_transfer.client import FetchSettings, MapClient
s = FetchSettings(chunk_size=16384, timeout=1.0, checkpoint_bytes=16384)
MapClient(sys.argv[1], sys.argv[2], settings=s).fetch()
"""


def test_client_killed_mid_transfer_resumes_without_loss_or_duplicates(map_dir, tmp_path, serve):
    throttle = {"on": True}

    def wire(seg, off, data):  # segment 1 slows down after its 5th chunk: the kill lands mid-segment
        time.sleep(0.2 if throttle["on"] and seg == 1 and off >= 5 * 16384 else 0.0)
        return data

    srv = serve(map_dir, chunk_filter=wire)
    out = tmp_path / "op"
    proc = subprocess.Popen([sys.executable, "-c", _CLIENT, srv.address, str(out)], env=dict(os.environ))
    state = out / ".partial" / "seg_000001.ply.state.json"
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and proc.poll() is None:
            if state.is_file() and len(json.loads(state.read_text() or "{}").get("received", [])) >= 5:
                break
            time.sleep(0.01)
        assert proc.poll() is None, "the client finished before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(10)
    throttle["on"] = False
    held = set(json.loads(state.read_text())["received"])
    e1 = read_manifest(map_dir)["segments"][1]
    total = len(range(0, e1["bytes"], 16384))
    assert 5 <= len(held) < total
    assert [x["id"] for x in read_manifest(out)["segments"]] == [0]  # segment 0 done, segment 1 partial
    with MapClient(srv.address, out, settings=FAST) as c:
        rep = c.fetch()
    assert rep.segments == [1, 2, 3] and rep.skipped == [0]
    later = sum(len(range(0, e["bytes"], FAST.chunk_size)) for e in read_manifest(map_dir)["segments"][2:])
    seg1_chunks = rep.chunks - later
    assert seg1_chunks <= total - len(held)  # only the missing part of segment 1 travelled again
    _same_map(map_dir, out)
    ids = [x["id"] for x in read_manifest(out)["segments"]]
    assert ids == sorted(set(ids))


def test_fetched_map_joins_into_the_world_cloud(map_dir, tmp_path, serve, small_map):
    from weldcell.plugins.map_transfer.segments import load_world_cloud

    srv = serve(map_dir)
    with MapClient(srv.address, tmp_path / "op", settings=FAST) as c:
        c.fetch()
    pts, _ = load_world_cloud(tmp_path / "op")
    ref = small_map[0]
    from scipy.spatial import cKDTree

    assert len(pts) == len(ref)
    assert cKDTree(ref).query(pts)[0].max() < 1e-5 and cKDTree(pts).query(ref)[0].max() < 1e-5  # float32 PLY


def test_partial_that_fails_its_sha256_is_discarded_and_fetched_again(map_dir, tmp_path, serve):
    """A partial download damaged on the operator's disk: every offset claimed, the bytes wrong."""
    e = read_manifest(map_dir)["segments"][0]
    part = tmp_path / "op" / ".partial"
    part.mkdir(parents=True)
    (part / (e["file"] + ".part")).write_bytes(b"\0" * e["bytes"])
    received = list(range(0, e["bytes"], FAST.chunk_size))
    state = {"sha256": e["sha256"], "bytes": e["bytes"], "chunk": FAST.chunk_size, "received": received}
    (part / (e["file"] + ".state.json")).write_text(json.dumps(state))
    srv = serve(map_dir)
    with MapClient(srv.address, tmp_path / "op", settings=FAST) as c:
        rep = c.fetch()
    assert rep.refetched_segments == 1 and rep.complete
    _same_map(map_dir, tmp_path / "op")


def test_server_sends_only_what_is_asked_for(map_dir, serve):
    """Credit-based flow control: a client that asks for one chunk and stops reading gets one chunk,
    however large the map; the server never pushes the rest."""
    import zmq

    srv = serve(map_dir)
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(srv.address)
    try:
        sock.send_multipart([b"", b"FETCH", json.dumps({"id": 0, "offset": 0, "size": 4096}).encode()])
        assert sock.poll(5000)
        kind, header, data = sock.recv_multipart()
        assert kind == b"CHUNK" and len(data) == 4096 and json.loads(header)["offset"] == 0
        time.sleep(0.3)
        assert srv.stats["chunks"] == 1 and srv.stats["bytes"] == 4096
        assert not sock.poll(100)
        sock.send_multipart([b"", b"FETCH", json.dumps({"id": 0, "offset": 0, "size": 1 << 30}).encode()])
        assert sock.poll(5000) and sock.recv_multipart()[0] == b"ERROR"  # no giant chunk either
    finally:
        sock.close()
        ctx.term()
