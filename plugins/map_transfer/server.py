"""The map server (robot side): serves a segmented map folder, even while it grows, over ZeroMQ.

Protocol (ROUTER here, DEALER on the client; every request is ``[token, command, json]``):

* ``MANIFEST {}`` → ``["MANIFEST", manifest json]``: the folder's manifest as it is now (re-read when
  its file changed, so segments appear as the mapper closes them).
* ``FETCH {"id", "offset", "size"}`` → ``["CHUNK", {"id", "offset", "size", "crc32"}, bytes]``: one
  chunk of a segment file, read from the disk on demand. The client keeps at most ``credit`` chunk
  requests in flight (zguide "file transfer", model 3: credit-based flow control), so the server
  never buffers more than one chunk per request and a slow client cannot make it queue the map.
* any failure → ``["ERROR", {"code", "message", "fix"}]``; codes ``unauthorized`` (wrong or missing
  token, compared with :func:`hmac.compare_digest`), ``bad-request``, ``no-segment``,
  ``segment-corrupt`` (the file on the robot fails the manifest's sha256: checked before the first
  chunk is served, again whenever the file changes).
"""

from __future__ import annotations

import hmac
import json
import logging
import os
import threading
import zlib
from collections.abc import Callable
from pathlib import Path

from weldcell.plugins.map_transfer.segments import MANIFEST, read_manifest
from weldcell.sdk import artifacts
from weldcell.sdk.errors import DataError, DeviceError

_log = logging.getLogger(__name__)
MAX_CHUNK = 16 << 20  # a client may not ask for more than this in one chunk


class MapServer:
    """Serve ``root`` on ``bind`` until :meth:`stop`. ``chunk_filter(id, offset, data) -> data`` is a
    hook for fault injection (tests damage chunks on the wire with it)."""

    def __init__(
        self,
        root: str | Path,
        bind: str = "tcp://127.0.0.1:5599",
        token: str | None = None,
        chunk_filter: Callable[[int, int, bytes], bytes] | None = None,
    ) -> None:
        import zmq

        self.root = Path(root)
        read_manifest(self.root)  # a clear error now rather than on the first request
        self._token = token.encode() if token else None
        self._filter = chunk_filter
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.ROUTER)
        self._sock.setsockopt(zmq.LINGER, 0)
        try:
            self._sock.bind(bind)
        except zmq.ZMQError as e:
            self._sock.close()
            self._ctx.term()
            raise DeviceError(f"cannot listen on {bind} ({e})", "choose a free port with --bind") from e
        self.address = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._manifest: dict = {}
        self._manifest_key: tuple = ()
        self._verified: dict[int, tuple] = {}
        self.stats = {"requests": 0, "chunks": 0, "bytes": 0, "refused": 0}

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> MapServer:
        """Serve in a background thread."""
        self._thread = threading.Thread(target=self.serve_forever, name="map-server", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> bool:
        """Stop serving and close the socket; True when the serving thread has ended."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                return False
            self._thread = None
        return True

    def __enter__(self) -> MapServer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def serve_forever(self) -> None:
        """Answer requests until :meth:`stop` (polls every 100 ms for the stop flag)."""
        import zmq

        try:
            while not self._stop.is_set():
                if self._sock.poll(100, zmq.POLLIN):
                    frames = self._sock.recv_multipart()
                    try:
                        reply = self._answer(frames[1:])
                    except Exception as e:  # one bad request never stops the server of a running robot
                        _log.exception("map server: request failed")
                        reply = _error(
                            "internal",
                            f"the map server failed on this request ({e})",
                            "see the server's log; other requests are still served",
                        )
                    self._sock.send_multipart([frames[0], *reply])
        finally:
            self._sock.close(0)
            self._ctx.term()

    # -- requests --------------------------------------------------------------------------------
    def _answer(self, frames: list[bytes]) -> list[bytes]:
        self.stats["requests"] += 1
        if len(frames) != 3:
            return _error("bad-request", "a request is [token, command, json]", "update the client")
        token, cmd, body = frames
        if self._token is not None and not hmac.compare_digest(token, self._token):
            self.stats["refused"] += 1
            return _error(
                "unauthorized",
                "the map server refused the client: wrong or missing token",
                "set the robot's token in WELDCELL_MAP_TOKEN (or --token-env) on the client",
            )
        try:
            req = json.loads(body or b"{}")
            if cmd == b"MANIFEST":
                return [b"MANIFEST", json.dumps(self.manifest()).encode()]
            if cmd == b"FETCH":
                return self._chunk(int(req["id"]), int(req["offset"]), int(req["size"]))
        except DataError as e:
            return _error(getattr(e, "code", "no-segment"), e.message, e.fix or "")
        except OSError as e:
            return _error("no-manifest", f"the map folder cannot be read on the robot ({e})", "check MAP_DIR")
        except (ValueError, KeyError, TypeError) as e:
            return _error("bad-request", f"unreadable request ({e})", "update the client")
        return _error("bad-request", f"unknown command {cmd[:20]!r}", "update the client")

    def manifest(self) -> dict:
        """The manifest, re-read when its file changed (the mapper may still be adding segments)."""
        st = os.stat(self.root / MANIFEST)
        key = (st.st_mtime_ns, st.st_size, st.st_ino)
        if key != self._manifest_key:
            self._manifest = read_manifest(self.root)
            self._manifest_key = key
        return self._manifest

    def _entry(self, seg_id: int) -> dict:
        for e in self.manifest()["segments"]:
            if e["id"] == seg_id:
                return e
        raise DataError(f"the map has no segment {seg_id}", "ask for a segment listed in the manifest")

    def _check_file(self, e: dict) -> Path:
        """The segment's file, verified against the manifest's sha256 once per file version."""
        path = self.root / e["file"]
        try:
            st = path.stat()
        except FileNotFoundError:
            err = DataError(f"segment {e['id']} ({e['file']}) is missing on the robot", "write the map again")
            err.code = "segment-corrupt"
            raise err from None
        key = (st.st_mtime_ns, st.st_size, e["sha256"])
        if self._verified.get(e["id"]) != key:
            if st.st_size != e["bytes"] or artifacts.sha256_file(path) != e["sha256"]:
                err = DataError(
                    f"segment {e['id']} ({e['file']}) fails its sha256 on the robot: the map file is damaged",
                    "re-run the segmentation (weldcell map segment) or the mapping job on the robot",
                )
                err.code = "segment-corrupt"
                raise err
            self._verified[e["id"]] = key
        return path

    def _chunk(self, seg_id: int, offset: int, size: int) -> list[bytes]:
        e = self._entry(seg_id)
        if offset < 0 or size <= 0 or size > MAX_CHUNK or offset >= e["bytes"]:
            return _error(
                "bad-request", f"chunk {offset}+{size} outside segment {seg_id}", "update the client"
            )
        path = self._check_file(e)
        with open(path, "rb") as f:
            f.seek(offset)
            data = f.read(size)
        header = {"id": seg_id, "offset": offset, "size": len(data), "crc32": zlib.crc32(data)}
        if self._filter is not None:
            data = self._filter(seg_id, offset, data)
        self.stats["chunks"] += 1
        self.stats["bytes"] += len(data)
        return [b"CHUNK", json.dumps(header).encode(), data]


def _error(code: str, message: str, fix: str) -> list[bytes]:
    return [b"ERROR", json.dumps({"code": code, "message": message, "fix": fix}).encode()]
