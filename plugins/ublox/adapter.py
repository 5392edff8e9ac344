"""u-blox receivers through pyubx2 (device ``gnss.ublox``): UBX NAV-PVT, NMEA GGA/RMC fallback, UBX-CFG."""

from __future__ import annotations

import time

import pyubx2
import serial  # noqa: F401 - pyserial (extra 'serial') is the port underneath SerialTransport
from pyubx2 import ERR_LOG, NMEA_PROTOCOL, SET, UBX_PROTOCOL, UBXMessage, UBXReader
from weldcell.hal.interfaces import Gnss
from weldcell.hal.readings import GnssFix
from weldcell.hal.transports import SerialTransport, TransportClosed, TransportTimeout
from weldcell.plugins.ublox.convert import fix_from_gga, fix_from_pvt
from weldcell.plugins.ublox.settings import UbloxSettings
from weldcell.sdk.errors import DeviceError

MESSAGE_STARTS = (b"\xb5\x62", b"$")
PVT_HOLD = 3.0
"""Seconds after the last NAV-PVT during which NMEA GGA epochs are ignored (they repeat the PVT)."""


class _Wait(Exception):
    """The buffer ends inside a message: wait for more bytes (never seen by pyubx2's error handling)."""


class _Resync(Exception):
    """A corrupt message: drop its first byte and look for the next header."""


MAX_UBX_PAYLOAD = 8192
"""Longer declared UBX lengths are corruption (the largest M8 messages are a few kB)."""


class _Buffer:
    """The byte source pyubx2 reads from: a rewindable view of the bytes received so far."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.pos = 0

    def read(self, n: int = 1) -> bytes:
        if self.pos + n > len(self.buf):
            raise _Wait
        out = bytes(self.buf[self.pos : self.pos + n])
        self.pos += n
        return out

    def readline(self) -> bytes:
        i = self.buf.find(b"\n", self.pos)
        if i < 0:
            raise _Wait
        out = bytes(self.buf[self.pos : i + 1])
        self.pos = i + 1
        return out

    def commit(self) -> int:
        n = self.pos
        del self.buf[:n]
        self.pos = 0
        return n

    def skip_garbage(self) -> int:
        """Drop bytes before the first possible message start; returns how many."""
        starts = [i for i in (self.buf.find(s) for s in MESSAGE_STARTS) if i >= 0]
        n = min(starts) if starts else max(0, len(self.buf) - 1)
        del self.buf[:n]
        self.pos = 0
        return n


class UbloxGnss(Gnss):
    """One :class:`GnssFix` per navigation epoch: from NAV-PVT when the receiver sends it, else from
    NMEA GGA (with RMC's date and GST's sigmas). No fix is a reading with ``fix_type="none"``.

    Corrupted messages (bad checksum, truncated, bad terminators) are skipped and counted in
    ``parse_errors``; bytes outside any message in ``skipped_bytes``; the reader re-synchronises on
    the next message header.
    """

    def __init__(self, settings: UbloxSettings, name: str = "gnss") -> None:
        super().__init__(name, frame="enu")
        self.settings = settings
        self.port = SerialTransport(settings.port, baudrate=settings.baudrate, timeout=settings.ack_timeout)
        self.port.options["exclusive"] = True
        self._reset()

    def _reset(self) -> None:
        self.buffer = _Buffer()
        self.parse_errors = 0
        self.last_parse_error = ""
        self.skipped_bytes = 0
        self.messages = 0
        self.acks: list[tuple[str, str]] = []
        self._last_pvt = -1e9
        self._date = None
        self._gst = None
        self._last_byte = time.monotonic()
        self._reader = UBXReader(
            self.buffer,
            protfilter=NMEA_PROTOCOL | UBX_PROTOCOL,
            quitonerror=ERR_LOG,
            errorhandler=self._on_parse_error,
        )

    def _on_parse_error(self, err: Exception) -> None:
        self.parse_errors += 1
        self.last_parse_error = str(err)
        if "Unknown message type" in str(err):
            self.buffer.commit()  # intact (checksum good) but not parsed by pyubx2: skip it whole
            return
        raise _Resync  # corrupt: resynchronise from the byte after its first one

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        try:
            self._configure()
        except BaseException:
            self.port.close()  # a failed configure leaves the port free for the next try
            raise

    def _configure(self) -> None:
        s = self.settings
        try:
            self.port.open()
        except DeviceError as e:
            raise DeviceError(f"GNSS receiver on {s.port}: {e.message}", e.fix) from None
        self._reset()
        if s.configure_receiver:
            for msg in self.config_messages():
                self._send_config(msg)
        else:
            self._wait_first_message()

    def config_messages(self) -> list[UBXMessage]:
        """CFG-RATE + NAV-PVT on every port (M8: CFG-MSG), or one CFG-VALSET (gen9)."""
        s = self.settings
        meas_ms = int(round(1000.0 / s.rate_hz))
        if s.config_messages == "valset":
            return [
                UBXMessage.config_set(
                    1,
                    0,
                    [
                        ("CFG_RATE_MEAS", meas_ms),
                        ("CFG_RATE_NAV", 1),
                        ("CFG_MSGOUT_UBX_NAV_PVT_UART1", 1),
                        ("CFG_MSGOUT_UBX_NAV_PVT_USB", 1),
                    ],
                )
            ]
        return [
            UBXMessage("CFG", "CFG-RATE", SET, measRate=meas_ms, navRate=1, timeRef=1),
            UBXMessage("CFG", "CFG-MSG", SET, msgClass=0x01, msgID=0x07, rateUART1=1, rateUSB=1),
        ]

    def _send_config(self, msg: UBXMessage) -> None:
        s = self.settings
        try:
            self.port.send(msg.serialize())
        except TransportClosed as e:
            raise DeviceError(f"GNSS receiver on {s.port}: {e.message}", e.fix) from None
        deadline = time.monotonic() + s.ack_timeout
        got = 0
        while time.monotonic() < deadline:
            got += self._pump(deadline - time.monotonic(), [])
            for kind, ident in self.acks:
                if ident == msg.identity:
                    self.acks.clear()
                    if kind == "ACK-NAK":
                        raise DeviceError(
                            f"the receiver on {s.port} refused {msg.identity} (ACK-NAK)",
                            "M8 receivers (protocol < 27) take config_messages = 'cfg-msg', gen9 and "
                            "later 'valset'; or set configure_receiver = false and use u-center",
                        )
                    return
        raise self._no_answer(f"no acknowledgement of {msg.identity}", got)

    def _wait_first_message(self) -> None:
        deadline = time.monotonic() + self.settings.open_timeout
        got = 0
        while time.monotonic() < deadline:
            got += self._pump(deadline - time.monotonic(), [])
            if self.messages:
                return
        raise self._no_answer("no UBX or NMEA message", got)

    def _no_answer(self, what: str, got: int) -> DeviceError:
        s = self.settings
        if got == 0:
            return DeviceError(
                f"GNSS receiver on {s.port} is silent: {what}",
                "check the cable and the receiver's power; on a UART check TX/RX and that its output "
                "protocol includes UBX or NMEA",
            )
        if self.messages == 0:
            return DeviceError(
                f"GNSS receiver on {s.port}: {got} bytes without one valid message at {s.baudrate} baud "
                f"({self.parse_errors} corrupt)",
                "wrong baud rate: M8 receivers default to 9600 on UART1; set baudrate to the receiver's",
            )
        return DeviceError(
            f"GNSS receiver on {s.port}: {what} (it sends messages but does not answer)",
            "the port may be output-only or UBX input disabled (CFG-PRT inProtoMask); or set "
            "configure_receiver = false",
        )

    def on_activate(self) -> None:
        self._last_byte = time.monotonic()

    def on_close(self) -> None:
        self.port.close()

    def on_recover(self) -> None:
        self.port.close()

    # -- reading ---------------------------------------------------------------------------------
    def _pump(self, timeout: float, fixes: list[GnssFix]) -> int:
        """Receive for up to ``timeout`` s, parse every complete message; returns the bytes received."""
        try:
            data = self.port.recv(timeout=max(0.001, timeout))
        except TransportTimeout:
            return 0
        except TransportClosed as e:
            raise DeviceError(f"GNSS receiver on {self.settings.port}: {e.message}", e.fix) from None
        self._last_byte = time.monotonic()
        b = self.buffer
        b.buf += data
        t = time.time()
        while True:
            self.skipped_bytes += b.skip_garbage()
            if b.buf[:2] == b"\xb5\x62" and len(b.buf) >= 6 and b.buf[4] | b.buf[5] << 8 > MAX_UBX_PAYLOAD:
                self.parse_errors += 1
                self.last_parse_error = "UBX length field out of range"
                del b.buf[:1]
                continue
            try:
                raw, msg = self._reader.read()
            except _Wait:
                b.pos = 0
                break
            except _Resync:
                del b.buf[:1]
                b.pos = 0
                continue
            except Exception as e:  # noqa: BLE001 - pyubx2 lets some decoding errors escape on garbage
                self.parse_errors += 1
                self.last_parse_error = f"{type(e).__name__}: {e}"
                del b.buf[:1]
                b.pos = 0
                continue
            b.commit()
            if msg is None:
                continue
            self.messages += 1
            fix = self._on_message(msg, t)
            if fix is not None:
                fixes.append(fix)
        if len(b.buf) > 65536:  # a message that never ends: drop and resynchronise
            self.parse_errors += 1
            self.skipped_bytes += len(b.buf)
            b.buf.clear()
        return len(data)

    def _on_message(self, msg, t: float) -> GnssFix | None:
        ident = msg.identity
        origin = self.settings.origin
        if ident == "NAV-PVT":
            self._last_pvt = time.monotonic()
            return fix_from_pvt(msg, t, self.frame, origin)
        if ident in ("ACK-ACK", "ACK-NAK"):
            self.acks.append((ident, _acked(msg)))
            return None
        if ident.endswith("RMC"):
            self._date = msg.date if hasattr(msg, "date") and not isinstance(msg.date, str) else None
            return None
        if ident.endswith("GST"):
            self._gst = msg
            return None
        if ident.endswith("GGA") and time.monotonic() - self._last_pvt > PVT_HOLD:
            return fix_from_gga(msg, t, self.frame, origin, self._date, self._gst)
        return None

    def _read_burst(self, timeout: float) -> list[GnssFix]:
        silent_at = self._last_byte + self.settings.silence_timeout
        now = time.monotonic()
        fixes: list[GnssFix] = []
        try:
            self._pump(min(timeout, max(0.001, silent_at - now)), fixes)
        except DeviceError as e:
            raise self.fault(f"connection lost ({e.message}); the cable may have been pulled") from None
        now = time.monotonic()
        if not fixes and now - self._last_byte > self.settings.silence_timeout:
            raise self.fault(f"receiver silent for {now - self._last_byte:.1f} s while active")
        return fixes

    def _read(self, timeout: float) -> GnssFix:
        """The next epoch's fix (a fix with ``fix_type="none"`` when the receiver has none)."""
        deadline = time.monotonic() + timeout
        while True:
            got = self._read_burst(max(0.001, deadline - time.monotonic()))
            if got:
                return got[-1]
            if time.monotonic() >= deadline:
                raise self.fault(f"no navigation solution within {timeout} s (no NAV-PVT or GGA)")


def _acked(msg) -> str:
    """The identity of the message an ACK-ACK/ACK-NAK answers."""
    try:
        return pyubx2.UBX_MSGIDS[bytes([msg.clsID, msg.msgID])]
    except (KeyError, AttributeError, TypeError):
        return ""
