"""The Leap Motion adapter: the Leap service's WebSocket (``ws://127.0.0.1:6437/v6.json``).

On connect it sends ``{"enableGestures": ...}``, ``{"background": ...}``, ``{"focused": ...}``; a reader
thread keeps the newest frame. When the service drops the connection the reader reconnects with
exponential backoff (bounded attempts) and resends the configuration, so a scan keeps going; when it
cannot, or no frame arrives within ``frame_timeout``, ``read()`` raises DeviceError and the device
enters ERROR.
"""

from __future__ import annotations

import json
import logging
import threading
import time

import websockets  # noqa: F401 - the vendor library (extra "leap"); the transport uses its sync client
from weldcell.hal.interfaces import GestureSensor
from weldcell.hal.readings import HandsFrame
from weldcell.hal.transports import Backoff, TransportClosed, TransportTimeout, WebSocketTransport
from weldcell.plugins.leap.protocol import frame_from_json, is_frame
from weldcell.plugins.leap.settings import LeapSettings
from weldcell.sdk.errors import DataError, DeviceError

log = logging.getLogger("weldcell.leap")

_FIX = (
    "check that the Leap service (LeapControlPanel / leapd) runs with 'Allow Web Apps' enabled and the "
    "sensor is plugged in"
)


class LeapMotion(GestureSensor):
    """A Leap Motion controller (device ``gesture.leap``). Hands in metres, Leap frame (y up)."""

    def __init__(
        self, settings: LeapSettings | None = None, name: str = "gesture", frame: str | None = None
    ) -> None:
        super().__init__(name, frame=frame or name)
        self.settings = settings or LeapSettings()
        s = self.settings
        self.transport = WebSocketTransport(
            s.url,
            timeout=s.frame_timeout,
            open_timeout=s.open_timeout,
            backoff=Backoff(attempts=s.reconnect_attempts, initial=s.reconnect_delay, max_delay=1.0),
        )
        self.service_version: dict | None = None
        self.reconnects = 0
        self._cond = threading.Condition()
        self._latest: HandsFrame | None = None
        self._latest_at = 0.0
        self._count = 0
        self._returned = 0
        self._failure: str | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- lifecycle -------------------------------------------------------------------------------
    def _hello(self) -> None:
        """Read the service's version message (if any) and send our configuration."""
        s = self.settings
        try:
            first = self.transport.recv_json(timeout=s.open_timeout)
        except TransportTimeout:
            first = None
        if isinstance(first, dict) and "version" in first and not is_frame(first):
            self.service_version = first
        elif is_frame(first):
            self._publish(first)
        for msg in (
            {"enableGestures": s.enable_gestures},
            {"background": s.background},
            {"focused": s.focused},
        ):
            self.transport.send(json.dumps(msg))

    def on_configure(self) -> None:
        try:
            self.transport.open()
        except TransportClosed as e:
            raise DeviceError(
                f"Leap service not reachable at {self.settings.url}: {e.message}", _FIX
            ) from None
        self._hello()

    def on_activate(self) -> None:
        self._failure = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._reader, name=f"leap-{self.name}", daemon=True)
        self._thread.start()

    def on_deactivate(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2 * self.settings.frame_timeout + 1)
            self._thread = None

    def on_close(self) -> None:
        self.on_deactivate()
        self.transport.close()

    def on_recover(self) -> None:
        self.on_close()
        with self._cond:
            self._latest, self._failure = None, None

    # -- reader thread ---------------------------------------------------------------------------
    def _publish(self, msg: dict) -> None:
        f = frame_from_json(msg, time.time(), self.frame)
        with self._cond:
            self._latest, self._latest_at = f, time.monotonic()
            self._count += 1
            self._cond.notify_all()

    def _reader(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.transport.recv_json(timeout=0.1)
            except TransportTimeout:
                continue
            except DataError as e:
                log.warning("skipping a message: %s", e.message)
                continue
            except TransportClosed as e:
                if self._stop.is_set():
                    return
                log.warning("Leap connection lost (%s); reconnecting", e.message)
                try:
                    self.transport.reconnect()
                    self._hello()
                    self.reconnects += 1
                    continue
                except DeviceError as e2:
                    with self._cond:
                        self._failure = f"connection to the Leap service lost and not regained: {e2.message}"
                        self._cond.notify_all()
                    return
            if is_frame(msg):
                try:
                    self._publish(msg)
                except DataError as e:
                    log.warning("skipping a malformed frame: %s", e.message)

    def _fault(self, message: str) -> DeviceError:
        e = self.fault(message)
        return DeviceError(e.message, _FIX + "; then recover() and configure() again")

    # -- readings --------------------------------------------------------------------------------
    def _read(self, timeout: float) -> HandsFrame:
        """The newest frame not returned before, waiting up to ``timeout`` (at most ``frame_timeout``)."""
        wait = min(timeout, self.settings.frame_timeout) if timeout > 0 else self.settings.frame_timeout
        deadline = time.monotonic() + wait
        with self._cond:
            while self._failure is None and (self._latest is None or self._count == self._returned):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            if self._failure is not None:
                raise self._fault(self._failure)
            if self._latest is None or self._count == self._returned:
                raise self._fault(f"no frame from the Leap service within {wait:.3g} s")
            self._returned = self._count
            return self._latest
