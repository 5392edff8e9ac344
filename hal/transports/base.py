"""What every transport shares: errors, reconnect with bounded exponential backoff, buffered reading.

A transport is a small object with ``open()``/``close()`` (and ``with``), ``send``/``recv`` with
timeouts, and ``reconnect()``. Failures raise :class:`~weldcell.sdk.errors.DeviceError` subclasses:
:class:`TransportTimeout` (nothing arrived in time: the peer may be alive but silent) and
:class:`TransportClosed` (the connection is gone: reconnect). Vendor libraries (pyserial,
websockets) are imported inside ``open`` so importing ``weldcell.hal`` never needs them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from weldcell.sdk.errors import DeviceError


class TransportTimeout(DeviceError):
    """Nothing (or not enough) arrived within the timeout."""


class TransportClosed(DeviceError):
    """The connection is not open, was closed by the peer, or could not be (re)opened."""


@dataclass(frozen=True)
class Backoff:
    """Reconnect schedule: ``attempts`` tries with waits ``initial * factor**k`` (at most ``max_delay``)."""

    attempts: int = 5
    initial: float = 0.05
    factor: float = 2.0
    max_delay: float = 2.0

    def delays(self) -> list[float]:
        """Waits before attempts 2..N (the first attempt is immediate)."""
        return [min(self.max_delay, self.initial * self.factor**k) for k in range(max(0, self.attempts - 1))]


class Transport:
    """Base class: lifecycle, reconnect with backoff, ``with``. Subclasses implement ``_open``/``_close``."""

    what = "transport"

    def __init__(self, timeout: float = 1.0, backoff: Backoff | None = None) -> None:
        self.timeout = float(timeout)
        self.backoff = backoff or Backoff()
        self.reconnects = 0

    # -- to implement --------------------------------------------------------------------------------
    def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    @property
    def is_open(self) -> bool:
        raise NotImplementedError

    def describe(self) -> str:
        """Where this transport talks to (for messages)."""
        return self.what

    def fix_hint(self) -> str:
        return "check that the device is powered, connected and reachable, then retry"

    # -- lifecycle -----------------------------------------------------------------------------------
    def open(self) -> None:
        """Open (no-op when open); :class:`TransportClosed` when the peer cannot be reached."""
        if self.is_open:
            return
        try:
            self._open()
        except DeviceError:
            raise
        except (OSError, TimeoutError) as e:
            self._safe_close()
            raise TransportClosed(f"cannot open {self.describe()}: {e}", self.fix_hint()) from e

    def close(self) -> None:
        """Close; never raises for an already broken connection."""
        self._safe_close()

    def _safe_close(self) -> None:
        try:
            self._close()
        except Exception:  # noqa: BLE001 - closing a broken link must not raise
            pass

    def reconnect(self, backoff: Backoff | None = None, sleep: Callable[[float], None] = time.sleep) -> int:
        """Close and open again, retrying with exponential backoff; returns the attempt that succeeded.

        Raises :class:`TransportClosed` naming the last error after ``backoff.attempts`` failures.
        """
        b = backoff or self.backoff
        self._safe_close()
        delays = [0.0, *b.delays()]
        last: Exception | None = None
        for i, d in enumerate(delays, start=1):
            if d:
                sleep(d)
            try:
                self.open()
                self.reconnects += 1
                return i
            except DeviceError as e:
                last = e
        msg = getattr(last, "message", str(last))
        raise TransportClosed(
            f"could not reconnect to {self.describe()} after {len(delays)} attempts ({msg})", self.fix_hint()
        )

    def require_open(self) -> None:
        if not self.is_open:
            raise TransportClosed(f"{self.describe()} is not open", "call open() (or reconnect()) first")

    def timed_out(self, what: str, timeout: float) -> TransportTimeout:
        return TransportTimeout(
            f"no {what} from {self.describe()} within {timeout:.3g} s",
            "check that the device is sending (powered, streaming, right settings) or raise the timeout",
        )

    def closed(self, why: str) -> TransportClosed:
        return TransportClosed(f"{self.describe()}: {why}", "reconnect(); " + self.fix_hint())

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.describe()} {'open' if self.is_open else 'closed'}>"


class StreamTransport(Transport):
    """A byte stream (TCP, serial): buffered exact, line and length-prefixed frame reads."""

    def __init__(self, timeout: float = 1.0, backoff: Backoff | None = None) -> None:
        super().__init__(timeout, backoff)
        self._buf = bytearray()

    def _read_some(self, timeout: float) -> bytes:
        """A chunk of bytes within ``timeout``: b"" on timeout; TransportClosed when the peer is gone."""
        raise NotImplementedError

    def _write(self, data: bytes) -> None:
        raise NotImplementedError

    def send(self, data: bytes | str) -> None:
        """Write all of ``data`` (str is UTF-8 encoded)."""
        self.require_open()
        self._write(data.encode() if isinstance(data, str) else bytes(data))

    def _fill(self, want: Callable[[], int | None], timeout: float | None, what: str) -> int:
        """Read until ``want()`` returns an end index into the buffer; TransportTimeout after ``timeout``."""
        self.require_open()
        t = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + t
        while True:
            end = want()
            if end is not None:
                return end
            left = deadline - time.monotonic()
            if left <= 0:
                raise self.timed_out(what, t)
            self._buf += self._read_some(left)

    def recv(self, max_bytes: int = 65536, timeout: float | None = None) -> bytes:
        """Whatever is available (at least one byte) up to ``max_bytes``."""
        end = self._fill(lambda: min(len(self._buf), max_bytes) if self._buf else None, timeout, "data")
        return self._take(end)

    def recv_exact(self, n: int, timeout: float | None = None) -> bytes:
        """Exactly ``n`` bytes."""
        end = self._fill(lambda: n if len(self._buf) >= n else None, timeout, f"{n} bytes")
        return self._take(end)

    def read_line(self, eol: bytes = b"\n", timeout: float | None = None, max_len: int = 65536) -> bytes:
        """One line including ``eol``; a DeviceError when none ends within ``max_len`` bytes."""

        def want() -> int | None:
            i = self._buf.find(eol)
            if i >= 0:
                return i + len(eol)
            if len(self._buf) > max_len:
                self._buf.clear()
                raise TransportClosed(
                    f"{self.describe()}: no end of line ({eol!r}) within {max_len} bytes",
                    "check the line ending and the baud rate / protocol settings",
                )
            return None

        return self._take(self._fill(want, timeout, "line"))

    def read_frame(
        self, length_format: str = ">H", length_includes_header: bool = False, timeout: float | None = None
    ) -> bytes:
        """A length-prefixed frame; returns the bytes after the length field.

        ``length_format`` is the struct format of the length field; ``length_includes_header`` when the
        length counts the length field itself (RTDE does).
        """
        import struct

        hdr = struct.Struct(length_format)

        def want() -> int | None:
            if len(self._buf) < hdr.size:
                return None
            (n,) = hdr.unpack_from(self._buf)
            total = n if length_includes_header else hdr.size + n
            if total < hdr.size:
                raise TransportClosed(f"{self.describe()}: invalid frame length {n}", "check the protocol")
            return total if len(self._buf) >= total else None

        return self._take(self._fill(want, timeout, "frame"))[hdr.size :]

    def _take(self, n: int) -> bytes:
        out = bytes(self._buf[:n])
        del self._buf[:n]
        return out

    def clear_input(self) -> None:
        """Drop buffered, unread bytes."""
        self._buf.clear()
