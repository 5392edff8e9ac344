"""A serial device on a pseudo-terminal: the test talks to the master side, the adapter opens the slave path.

Subclasses implement ``on_bytes(data)`` (what the device does with bytes the host sent) and
``produce(now)`` (bytes the device sends unprompted, e.g. its measurement stream); ``pull()`` closes the
master as a pulled USB cable does (the adapter's next read fails with EIO).
"""

from __future__ import annotations

import os
import select
import sys
import threading
import time

import pytest


class PtyPeer:
    tick = 0.002
    """Seconds between calls of ``produce``."""

    def __init__(self) -> None:
        if sys.platform == "win32":  # pragma: no cover
            pytest.skip("pseudo-terminals need a POSIX system")
        import tty

        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        tty.setraw(self.master)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.received = bytearray()
        self.dropped = 0
        self.pulled = False
        self._out = bytearray()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self):
        self._thread.start()
        return self

    # -- device behaviour (override) -----------------------------------------------------------------
    def on_bytes(self, data: bytes) -> None:
        pass

    def produce(self, now: float) -> bytes:
        return b""

    # -- plumbing --------------------------------------------------------------------------------
    def write(self, data: bytes) -> None:
        """Send to the host; bytes the host's full input buffer cannot take are dropped (and counted)."""
        with self._lock:
            if self.pulled or not data:
                return
            try:
                n = os.write(self.master, data)
            except (BlockingIOError, OSError):
                n = 0
            self.dropped += len(data) - n

    def queue(self, data: bytes) -> None:
        """Send to the host without loss: what the host's input buffer cannot take waits (a UART with flow
        control, or a replayed capture)."""
        with self._lock:
            self._out += data

    @property
    def queued(self) -> int:
        return len(self._out)

    def _flush(self) -> None:
        with self._lock:
            if self.pulled or not self._out:
                return
            try:
                n = os.write(self.master, bytes(self._out[:4096]))
            except (BlockingIOError, OSError):
                n = 0
            del self._out[:n]

    def _run(self) -> None:
        while not self._stop.is_set():
            if self.pulled:
                return
            try:
                r, _, _ = select.select([self.master], [], [], self.tick)
            except (OSError, ValueError):
                return
            if r:
                try:
                    data = os.read(self.master, 4096)
                except (BlockingIOError, OSError):
                    data = b""
                if data:
                    self.received += data
                    self.on_bytes(data)
            out = self.produce(time.monotonic())
            if out:
                self.write(out)
            self._flush()

    def pull(self) -> None:
        """The cable is pulled: the master side disappears."""
        with self._lock:
            self.pulled = True
            try:
                os.close(self.master)
            except OSError:
                pass

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(1.0)
        if not self.pulled:
            self.pull()
        try:
            os.close(self.slave)
        except OSError:
            pass
