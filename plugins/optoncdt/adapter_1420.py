"""optoNCDT 1420/1320 over RS422-USB (device ``displacement.optoncdt`` with ``family = "1420"``)."""

from __future__ import annotations

import re
import time

from weldcell.hal.transports import TransportClosed, TransportTimeout
from weldcell.plugins.optoncdt import protocol_1420 as q
from weldcell.plugins.optoncdt.adapter import OptoNcdt
from weldcell.sdk.errors import DeviceError


class OptoNcdt1420(OptoNcdt):
    """An optoNCDT 1420 or 1320: 3-byte values (the first output value = distance), ASCII commands.

    configure: ``GETINFO`` (model, serial, measuring range checked against the settings); activate:
    ``OUTPUT RS422``; deactivate: ``OUTPUT NONE``. The measuring rate, averaging and laser power are
    set in the sensor (web interface or its ASCII commands) and are not changed here; ``rate_hz``
    tells the adapter the configured rate for time stamps.
    """

    def _new_decoder(self):
        return q.Decoder()

    def _convert(self, dvo: int) -> tuple[float | None, str | None]:
        s = self.settings
        d = q.distance_from_dvo(dvo, s.measuring_range, s.start_of_range)
        return d, None if d is not None else q.error_text(dvo)

    def _configure(self) -> None:
        s = self.settings
        self.port.open()
        reply = self._command("GETINFO")
        self.info = parse_info_1420(reply)
        m = re.match(r"([\d.]+)\s*mm", self.info.get("Measuring range", ""))
        if m and abs(float(m.group(1)) / 1000.0 - s.measuring_range) > 1e-6:
            raise DeviceError(
                f"optoNCDT {self.info.get('Name', '')} on {s.port} reports a measuring range of "
                f"{m.group(1)} mm, the settings say {s.measuring_range * 1000:g} mm",
                "set measuring_range (and start_of_range) to the data sheet values of this model",
            )

    def on_activate(self) -> None:
        if self.settings.apply_settings:
            self._command("OUTPUT RS422")
        self.decoder = self._new_decoder()
        self._last_stamp = None
        self._last_byte = time.monotonic()

    def on_deactivate(self) -> None:
        if not self.settings.apply_settings:
            return
        try:
            self._command("OUTPUT NONE")
        except DeviceError:
            pass

    def _command(self, text: str) -> str:
        """Send an ASCII command, return its reply up to the ``->`` prompt; ``Exxx`` replies raise."""
        s = self.settings
        dec = self.decoder
        dec.text.clear()
        try:
            self.port.send(text.encode("ascii") + b"\r")
        except TransportClosed as e:
            raise self._port_error(e) from None
        got = values = 0
        deadline = time.monotonic() + s.reply_timeout
        while True:
            reply = dec.take_reply()
            if reply is not None:
                break
            if time.monotonic() >= deadline:
                raise self._no_reply_1420(text, got, values)
            try:
                data = self.port.recv(timeout=max(0.001, deadline - time.monotonic()))
            except TransportTimeout:
                continue
            except TransportClosed as e:
                raise self._port_error(e) from None
            got += len(data)
            values += len(dec.feed(data))
        err = re.search(r"^\s*(E\d{2,3}.*)$", reply, re.MULTILINE)
        if err:
            raise DeviceError(
                f"optoNCDT on {s.port} refused '{text}': {err.group(1).strip()}",
                "check the command against the sensor's manual (login level, parameter range)",
            )
        return reply

    def _no_reply_1420(self, text: str, got: int, values: int) -> DeviceError:
        s = self.settings
        if got == 0:
            return DeviceError(
                f"optoNCDT on {s.port} is silent: no answer to '{text}' within {s.reply_timeout} s",
                "check the sensor's power, the RS422 wiring (Tx/Rx pairs) and the converter at this port",
            )
        if values == 0 or self.decoder.good_bytes < got / 2:  # random bytes rarely form L-M-H triples
            return DeviceError(
                f"optoNCDT on {s.port}: {got} bytes of garbage and no reply at {s.baudrate} baud",
                "wrong baud rate: the 1420/1320 default is 921600; set baudrate to the sensor's",
            )
        return DeviceError(
            f"optoNCDT on {s.port} sends values but does not answer '{text}'",
            "the sensor may be a 1402 (set family = '1402') or its command interface is off",
        )


def parse_info_1420(reply: str) -> dict[str, str]:
    info = {}
    for line in reply.splitlines():
        k, sep, v = line.partition(":")
        if sep:
            info[k.strip().lstrip("->")] = v.strip()
    return info
