"""Buffered, time-stamped reading streams for the streaming device kinds (displacement, IMU, GNSS).

A device read one value per call cannot keep up with a sensor at 200-1500 Hz. A stream runs a
background reader thread that pulls readings from the adapter as fast as the device sends them
and keeps them in a bounded buffer; the consumer collects everything since its last call::

    with laser as dev:
        dev.start_stream()
        while scanning:
            for r in dev.read_available(timeout=0.05):   # in order, each reading once
                ...
        rest = dev.stop_stream()                          # whatever is left

Rules (the device-adapter guide's "Streaming devices"):

- The reader calls the adapter's ``_read_burst(timeout)``; by default that is ``[self._read(timeout)]``.
  Adapters whose protocol delivers bursts (a serial chunk holding many values) override it and may
  return an empty list when nothing arrived yet. ``stamp`` is the host's arrival time; a device's own
  clock goes into the reading's ``device_stamp``. :func:`backdate` spreads one burst's arrival time
  over its samples at the device's rate.
- A full buffer drops the *oldest* reading and counts it in ``overruns`` (never silently).
- An exception from the reader (a pulled cable, a silent device) stops the stream and puts the device
  into its lifecycle ERROR state. Everything received before stays readable: ``read_available()``
  returns it, and the call after the last reading raises the :class:`DeviceError`.
  ``stop_stream()`` returns what is left without raising.
- ``deactivate()`` and ``close()`` stop the stream first (its readings stay collectable by
  ``read_available()`` / ``stop_stream()``). ``read()`` is refused while a stream runs.
- ``stream_rate_hz`` (class or instance attribute) paces the reader for devices whose ``_read``
  returns at once (simulated devices); real adapters block on their transport and leave it None.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from weldcell.hal.lifecycle import Device, State
from weldcell.hal.readings import Displacement, GnssFix, ImuReading
from weldcell.sdk.errors import DeviceError, UsageError, WeldcellError

Reading = Displacement | ImuReading | GnssFix
"""A reading of a streaming device kind."""


@dataclass(frozen=True)
class StreamStatus:
    """Counters of a stream. ``received == delivered + overruns + buffered``."""

    running: bool
    received: int = 0
    """Readings the reader got from the device."""
    delivered: int = 0
    """Readings handed to the consumer (``read_available`` / ``stop_stream``)."""
    overruns: int = 0
    """Readings dropped because the buffer was full (the oldest ones)."""
    errors: int = 0
    """Reader errors (at most 1: an error stops the stream)."""
    last_error: str = ""
    last_stamp: float | None = None
    """``stamp`` of the newest reading received."""
    buffered: int = 0
    """Readings waiting to be collected."""
    capacity: int = 0


def backdate(n: int, t_arrival: float, period: float, after: float | None = None) -> np.ndarray:
    """Stamps for ``n`` samples that arrived together at ``t_arrival``, sampled every ``period`` s.

    The last sample gets ``t_arrival``, earlier ones ``period`` apart before it (a serial burst holds
    the samples taken since the previous burst). ``after``, the previous burst's last stamp, keeps the
    stamps increasing when bursts arrive irregularly: no stamp is earlier than ``after + k * period``
    (capped at ``t_arrival``).
    """
    t = t_arrival - period * np.arange(n - 1, -1, -1, dtype=float)
    if after is not None and n:
        t = np.minimum(np.maximum(t, after + period * np.arange(1, n + 1)), t_arrival)
    return t


class ReadingStream:
    """The buffer and reader thread of one device's stream (use the device's methods, not this)."""

    def __init__(self, device: StreamingDevice, capacity: int, read_timeout: float) -> None:
        self.device = device
        self.capacity = int(capacity)
        self.read_timeout = float(read_timeout)
        self._buf: deque = deque()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._received = self._delivered = self._overruns = self._errors = 0
        self._last_error = ""
        self._error: DeviceError | None = None
        self._last_stamp: float | None = None
        self._running = False

    # -- reader ----------------------------------------------------------------------------------
    def start(self) -> None:
        self._running = True
        self._thread = threading.Thread(
            target=self._run, name=f"stream-{self.device.kind}-{self.device.name}", daemon=True
        )
        self._thread.start()

    def _run(self) -> None:
        dev = self.device
        rate = getattr(dev, "stream_rate_hz", None)
        period = 1.0 / rate if rate else 0.0
        next_t = time.monotonic()
        try:
            while not self._stop.is_set():
                if period:
                    next_t += period
                    wait = next_t - time.monotonic()
                    if wait > 0 and self._stop.wait(wait):
                        break
                    if wait < -10 * period:  # fell far behind: do not burst to catch up
                        next_t = time.monotonic()
                readings = dev._read_burst(self.read_timeout)
                if readings:
                    self._push(readings)
        except Exception as e:  # noqa: BLE001 - any reader failure is the device's fault state
            self._on_error(e)
        finally:
            with self._cond:
                self._running = False
                self._cond.notify_all()

    def _push(self, readings: list) -> None:
        with self._cond:
            for r in readings:
                if len(self._buf) >= self.capacity:
                    self._buf.popleft()
                    self._overruns += 1
                self._buf.append(r)
            self._received += len(readings)
            self._last_stamp = readings[-1].stamp
            self._cond.notify_all()
        self.device.mark_reading(readings[-1].stamp)

    def _on_error(self, e: Exception) -> None:
        dev = self.device
        reason = e.message if isinstance(e, WeldcellError) else f"{type(e).__name__}: {e}"
        with self._cond:
            self._errors += 1
            self._last_error = reason
            if self._stop.is_set():  # shutting down (deactivate/close): not a device fault
                return
        if dev.lifecycle is State.ACTIVE:
            err = dev.fault(f"stream reader failed: {reason}")
        else:
            err = DeviceError(f"{dev.kind} '{dev.name}': stream reader failed: {reason}", dev._hint())
        if isinstance(e, DeviceError) and e.fix:
            err.fix = e.fix
        with self._cond:
            self._error = err
            self._cond.notify_all()

    def halt(self) -> None:
        """Stop the reader thread (waits for its current read to return)."""
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(self.read_timeout + 2.0)
        with self._cond:
            self._running = bool(t is not None and t.is_alive())

    # -- consumer --------------------------------------------------------------------------------
    def take(self, timeout: float = 0.0) -> list:
        with self._cond:
            if not self._buf and timeout > 0 and self._running and self._error is None:
                self._cond.wait_for(lambda: self._buf or not self._running or self._error, timeout)
            if self._buf:
                out = list(self._buf)
                self._buf.clear()
                self._delivered += len(out)
                return out
            if self._error is not None:
                raise self._error
            if not self._running:
                raise DeviceError(
                    f"{self.device.kind} '{self.device.name}': the stream was stopped and is empty",
                    "call start_stream() again (the device must be active)",
                )
            return []

    def drain(self) -> list:
        with self._cond:
            out = list(self._buf)
            self._buf.clear()
            self._delivered += len(out)
            return out

    @property
    def pending(self) -> int:
        with self._cond:
            return len(self._buf)

    def status(self) -> StreamStatus:
        with self._cond:
            return StreamStatus(
                running=self._running,
                received=self._received,
                delivered=self._delivered,
                overruns=self._overruns,
                errors=self._errors,
                last_error=self._last_error,
                last_stamp=self._last_stamp,
                buffered=len(self._buf),
                capacity=self.capacity,
            )


class StreamingDevice(Device):
    """Base of the streaming interfaces: adds ``start_stream`` / ``read_available`` / ``stop_stream``."""

    stream_rate_hz: float | None = None
    """Pace of the reader thread for devices whose ``_read`` does not block (None: as fast as it returns)."""
    stream_read_timeout: float = 0.5
    """``timeout`` passed to ``_read_burst`` by the reader thread [s]."""

    _stream: ReadingStream | None = None

    # -- adapter hooks ---------------------------------------------------------------------------
    def _read(self, timeout: float):
        raise NotImplementedError

    def _read_burst(self, timeout: float) -> list:
        """Readings that arrived within ``timeout`` (default: one ``_read``). May return []."""
        return [self._read(timeout)]

    # -- public API ------------------------------------------------------------------------------
    def start_stream(self, capacity: int = 65536) -> None:
        """Start the background reader (device must be ACTIVE) with a buffer of ``capacity`` readings."""
        if capacity < 1:
            raise UsageError(f"stream capacity must be >= 1, got {capacity}", "pass capacity=65536 or so")
        self.require_active()
        old = self._stream
        if old is not None:
            if old.status().running:
                raise DeviceError(
                    f"{self.kind} '{self.name}': a stream is already running",
                    "call stop_stream() before starting another",
                )
            if old.pending:
                raise DeviceError(
                    f"{self.kind} '{self.name}': the previous stream still holds {old.pending} readings",
                    "collect them with stop_stream() first (nothing captured is dropped silently)",
                )
        self._stream = ReadingStream(self, capacity, self.stream_read_timeout)
        self._stream.start()

    def read_available(self, timeout: float = 0.0) -> list:
        """Every reading since the last call, in order (waits up to ``timeout`` s for the first one).

        After the stream failed, returns what was received before the failure; the call after that
        raises the :class:`DeviceError`.
        """
        s = self._stream
        if s is None:
            raise DeviceError(
                f"{self.kind} '{self.name}': no stream was started", "call start_stream() first"
            )
        return s.take(timeout)

    def stop_stream(self) -> list:
        """Stop the reader and return the readings not yet collected (never raises for a failed stream)."""
        s = self._stream
        if s is None:
            return []
        s.halt()
        return s.drain()

    def stream_status(self) -> StreamStatus:
        """Counters of the current (or last) stream."""
        s = self._stream
        return StreamStatus(running=False) if s is None else s.status()

    @property
    def streaming(self) -> bool:
        s = self._stream
        return s is not None and s.status().running

    def _refuse_while_streaming(self) -> None:
        if self.streaming:
            raise DeviceError(
                f"{self.kind} '{self.name}' is streaming; read() would steal its readings",
                "use read_available(), or stop_stream() before read()",
            )

    # -- lifecycle: the stream stops before the device does ---------------------------------------
    def _halt_stream(self) -> None:
        s = self._stream
        if s is not None:
            s.halt()

    def deactivate(self) -> None:
        self._halt_stream()
        super().deactivate()

    def close(self) -> None:
        self._halt_stream()
        super().close()


def recv_within_silence(
    device: Device, port, timeout: float, last_byte: float, silence_timeout: float, silent: str
) -> bytes:
    """Bytes a byte-stream device (serial, TCP) sent within ``timeout``, never waiting past its silence
    limit, so that a silent device is detected on time; ``b""`` when none came yet.

    Raises ``device.fault`` when the connection is lost (a pulled cable) or nothing came for longer than
    ``silence_timeout`` since ``last_byte`` (monotonic time of the last byte); ``silent`` is that message,
    with ``{seconds}`` for how long it has been silent ("IMU silent for {seconds:.2f} s while active")."""
    from weldcell.hal.transports import TransportClosed, TransportTimeout

    timeout = min(timeout, max(0.001, last_byte + silence_timeout - time.monotonic()))
    try:
        data = port.recv(timeout=timeout)
    except TransportTimeout:
        data = b""
    except TransportClosed as e:
        raise device.fault(f"connection lost ({e.message}); the cable may have been pulled") from None
    if not data and time.monotonic() - last_byte > silence_timeout:
        raise device.fault(silent.format(seconds=time.monotonic() - last_byte))
    return data
