"""The map client (operator side): fetches a segmented map segment by segment, resumably.

Each segment is downloaded into ``OUT/.partial/<file>.part`` with up to ``credit`` chunk requests in
flight; every chunk carries a CRC-32 and a damaged or truncated chunk is requested again. The
offsets received are checkpointed in ``<file>.state.json`` (after the data is flushed to the disk),
so a client that is killed or loses the connection resumes where it stopped. A finished segment is
checked against the manifest's sha256 (a mismatch discards it and fetches it again, once), moved into
``OUT`` and only then listed in ``OUT/manifest.json``: the local folder is always a valid
``weldcell/map-segments@1`` map of the segments received so far, each exactly once.
"""

from __future__ import annotations

import json
import os
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from pydantic import Field
from weldcell.plugins.map_transfer.segments import MANIFEST, SCHEMA
from weldcell.sdk import artifacts
from weldcell.sdk.errors import DataError, DeviceError, UsageError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration


class FetchSettings(Settings):
    """How the client asks for chunks and how long it waits."""

    chunk_size: int = Field(1 << 20, ge=1024, le=16 << 20, description="bytes per chunk request")
    credit: int = Field(8, ge=1, le=256, description="chunk requests in flight (credit-based flow control)")
    timeout: Duration = Field(2.0, gt=0, description="re-send outstanding requests after this silence [s]")
    retries: int = Field(5, ge=0, description="re-sends in a row before giving up (the partial is kept)")
    poll: Duration = Field(0.05, gt=0, description="manifest poll period while the map grows [s]")
    wait: Duration = Field(60.0, ge=0, description="give up waiting for new segments after this [s]")
    checkpoint_bytes: int = Field(8 << 20, ge=1, description="flush + save progress every this many bytes")


@dataclass
class FetchReport:
    """What one fetch did."""

    segments: list[int] = field(default_factory=list)  # ids received in this run, in order
    skipped: list[int] = field(default_factory=list)  # already present locally
    chunks: int = 0
    bytes: int = 0
    bad_chunks: int = 0  # failed their CRC or were short, and were requested again
    resends: int = 0
    refetched_segments: int = 0
    complete: bool = False
    first_segment_s: float | None = None
    seconds: float = 0.0


Progress = Callable[[dict, int], None]  # (manifest entry, bytes received so far)


class MapClient:
    """Fetch the map served at ``address`` into ``out``."""

    def __init__(
        self, address: str, out: str | Path, token: str | None = None, settings: FetchSettings | None = None
    ) -> None:
        import zmq

        self.address = address
        self.out = Path(out)
        self.s = settings or FetchSettings()
        self._token = (token or "").encode()
        self._ctx = zmq.Context()
        self._sock = None
        self._connect()
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / ".partial").mkdir(exist_ok=True)
        for stale in (self.out / ".partial").glob(".*.tmp"):  # an atomic write cut short by a kill
            stale.unlink(missing_ok=True)
        self.local = self._load_local()

    def _connect(self) -> None:
        import zmq

        if self._sock is not None:
            self._sock.close(0)
        self._sock = self._ctx.socket(zmq.DEALER)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.connect(self.address)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close(0)
            self._sock = None
        self._ctx.term()

    def __enter__(self) -> MapClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- local folder ---------------------------------------------------------------------------
    def _load_local(self) -> dict:
        p = self.out / MANIFEST
        if p.is_file():
            data = artifacts.read_json(p)
            if data.get("schema") != SCHEMA:
                raise UsageError(f"{p} is not a segmented map", "fetch into an empty folder")
            return data
        return {"schema": SCHEMA, "frame": "world", "units": "m", "complete": False, "segments": []}

    def _have(self, e: dict) -> bool:
        """Segment ``e`` is here: listed with the same sha256 and its file present with its size (a
        file deleted or cut short locally is fetched again)."""
        f = self.out / e["file"]
        listed = any(x["id"] == e["id"] and x["sha256"] == e["sha256"] for x in self.local["segments"])
        return listed and f.is_file() and f.stat().st_size == e["bytes"]

    # -- requests -------------------------------------------------------------------------------
    def _send(self, cmd: bytes, body: dict) -> None:
        self._sock.send_multipart([self._token, cmd, json.dumps(body).encode()])

    def _recv(self, timeout: float) -> list[bytes] | None:
        if not self._sock.poll(int(timeout * 1000)):
            return None
        frames = self._sock.recv_multipart()
        if frames[0] == b"ERROR":
            _raise(json.loads(frames[1]))
        return frames

    def manifest(self) -> dict:
        """The server's manifest now (retried on silence; DeviceError when the server stays silent)."""
        for _ in range(self.s.retries + 1):
            self._send(b"MANIFEST", {})
            while True:
                frames = self._recv(self.s.timeout)
                if frames is None:
                    break
                if frames[0] == b"MANIFEST":
                    return json.loads(frames[1])  # late CHUNK replies of an old request are dropped
            self._connect()  # a fresh socket drops stale replies of a dead connection
        raise DeviceError(
            f"the map server at {self.address} does not answer",
            "check the address and that `weldcell map serve` runs; the fetch resumes later",
        )

    # -- fetching -------------------------------------------------------------------------------
    def fetch(
        self,
        on_progress: Progress | None = None,
        on_segment: Callable[[dict], None] | None = None,
        wait_complete: bool = True,
    ) -> FetchReport:
        """Fetch every segment not yet here, following the map while it grows until it is complete
        (or no new segment came for ``wait`` seconds)."""
        rep = FetchReport()
        t0 = time.perf_counter()
        last_new = time.monotonic()
        while True:
            m = self.manifest()
            todo = [e for e in m["segments"] if not self._have(e)]
            rep.skipped += [e["id"] for e in m["segments"] if e["id"] not in rep.segments and self._have(e)]
            for e in todo:
                self._fetch_segment(e, rep, on_progress)
                self._add_local(e)
                rep.segments.append(e["id"])
                if rep.first_segment_s is None:
                    rep.first_segment_s = time.perf_counter() - t0
                if on_segment is not None:
                    on_segment(e)
                last_new = time.monotonic()
            if m.get("complete"):
                self.local["complete"] = True
                self._save_local(m)
                rep.complete = True
                break
            if not wait_complete or time.monotonic() - last_new > self.s.wait:
                break
            time.sleep(self.s.poll)
        rep.skipped = sorted(set(rep.skipped) - set(rep.segments))
        rep.seconds = time.perf_counter() - t0
        return rep

    def _add_local(self, e: dict) -> None:
        kept = [x for x in self.local["segments"] if x["id"] != e["id"]]
        self.local["segments"] = sorted([*kept, e], key=lambda x: x["id"])  # travel order, each id once
        self._save_local()

    def _save_local(self, server: dict | None = None) -> None:
        if server is not None:
            for k in ("source", "settings"):
                if k in server:
                    self.local[k] = server[k]
        artifacts.write_json(self.out / MANIFEST, self.local)

    def _fetch_segment(self, e: dict, rep: FetchReport, on_progress: Progress | None) -> None:
        for _attempt in range(2):
            part = _Partial(self.out / ".partial" / e["file"], e, self.s.chunk_size)
            try:
                self._pull_chunks(e, part, rep, on_progress)
                part.flush()
                if artifacts.sha256_file(part.data_path) == e["sha256"]:
                    # the folder entry is made durable by the manifest write that follows (same folder)
                    os.replace(part.data_path, self.out / e["file"])
                    part.drop_state()
                    return
            finally:
                part.close()
            part.discard()
            rep.refetched_segments += 1
        raise DataError(
            f"segment {e['id']} fails its sha256 after two complete downloads",
            "the link corrupts data beyond the chunk CRC; check the network and fetch again",
        )

    def _pull_chunks(self, e: dict, part: _Partial, rep: FetchReport, on_progress: Progress | None) -> None:
        missing = sorted(set(range(0, e["bytes"], part.chunk)) - part.received)
        inflight: dict[int, float] = {}
        silent = 0
        since_ckpt = 0
        if on_progress is not None:
            on_progress(e, part.done_bytes())
        while missing or inflight:
            while missing and len(inflight) < self.s.credit:
                off = missing.pop(0)
                self._send(
                    b"FETCH", {"id": e["id"], "offset": off, "size": min(part.chunk, e["bytes"] - off)}
                )
                inflight[off] = time.monotonic()
            frames = self._recv(self.s.timeout)
            if frames is None:  # silence: the connection dropped or the server restarted; ask again
                silent += 1
                if silent > self.s.retries:
                    part.checkpoint()
                    raise DeviceError(
                        f"the map server at {self.address} stopped answering",
                        "run the fetch again: it resumes where it stopped",
                    )
                rep.resends += len(inflight)
                self._connect()
                missing = sorted(set(missing) | set(inflight))
                inflight.clear()
                continue
            silent = 0
            if frames[0] != b"CHUNK" or len(frames) != 3:
                continue
            h = json.loads(frames[1])
            off, data = h.get("offset"), frames[2]
            if h.get("id") != e["id"] or off not in inflight:
                continue  # a late reply to a request already answered or re-sent: never written twice
            del inflight[off]
            want = min(part.chunk, e["bytes"] - off)
            if len(data) != want or h.get("size") != want or zlib.crc32(data) != h.get("crc32"):
                rep.bad_chunks += 1
                missing.insert(0, off)
                continue
            part.write(off, data)
            rep.chunks += 1
            rep.bytes += len(data)
            since_ckpt += len(data)
            if since_ckpt >= self.s.checkpoint_bytes:
                part.checkpoint()
                since_ckpt = 0
            if on_progress is not None:
                on_progress(e, part.done_bytes())


class _Partial:
    """A partly downloaded segment: its data file and the offsets known to be written."""

    def __init__(self, data_path: Path, e: dict, chunk: int) -> None:
        self.data_path = Path(str(data_path) + ".part")
        self.state_path = Path(str(data_path) + ".state.json")
        self.e = e
        self.received: set[int] = set()
        self.chunk = chunk
        if self.state_path.is_file() and self.data_path.is_file():
            try:
                st = json.loads(self.state_path.read_text())
            except json.JSONDecodeError:
                st = {}
            if st.get("sha256") == e["sha256"] and st.get("bytes") == e["bytes"]:
                self.chunk = int(st["chunk"])  # resume with the chunking the offsets were made with
                self.received = {int(o) for o in st["received"]}
        mode = "r+b" if self.data_path.is_file() and self.received else "w+b"
        self.f = open(self.data_path, mode)
        self.f.truncate(e["bytes"])

    def done_bytes(self) -> int:
        return sum(min(self.chunk, self.e["bytes"] - o) for o in self.received)

    def write(self, offset: int, data: bytes) -> None:
        os.pwrite(self.f.fileno(), data, offset)
        self.received.add(offset)

    def flush(self) -> None:
        self.f.flush()
        os.fsync(self.f.fileno())

    def checkpoint(self) -> None:
        """Flush the data, then record the offsets (never an offset whose data is not on the disk)."""
        self.flush()
        artifacts.write_json(
            self.state_path,
            {
                "sha256": self.e["sha256"],
                "bytes": self.e["bytes"],
                "chunk": self.chunk,
                "received": sorted(self.received),
            },
        )

    def close(self) -> None:
        if not self.f.closed:
            if self.received and self.data_path.exists():
                self.checkpoint()
            self.f.close()

    def drop_state(self) -> None:
        self.received = set()
        self.state_path.unlink(missing_ok=True)

    def discard(self) -> None:
        self.drop_state()
        self.data_path.unlink(missing_ok=True)


def _raise(err: dict) -> None:
    code, msg, fix = err.get("code"), err.get("message", "server error"), err.get("fix") or None
    if code == "unauthorized":
        raise UsageError(msg, fix)
    if code in ("segment-corrupt", "no-segment", "no-manifest"):
        raise DataError(msg, fix)
    raise DeviceError(f"the map server answered: {msg}", fix)
