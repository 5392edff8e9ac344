"""Micro-Epsilon optoNCDT 1402 over RS422-USB through pyserial (device ``displacement.optoncdt``)."""

from __future__ import annotations

import re
import time

import serial  # noqa: F401 - the vendor library of this adapter (extra 'serial'); used by SerialTransport
from weldcell.hal.interfaces import DisplacementSensor
from weldcell.hal.readings import Displacement
from weldcell.hal.stream import backdate, recv_within_silence
from weldcell.hal.transports import SerialTransport, TransportClosed, TransportTimeout
from weldcell.plugins.optoncdt import protocol as p
from weldcell.plugins.optoncdt.settings import OptoNcdtSettings
from weldcell.sdk.errors import DeviceError

GARBAGE_MIN_BYTES = 64


class OptoNcdt(DisplacementSensor):
    """An optoNCDT 1402: binary 14-bit values at up to 1.5 kHz, ILD1402 command set.

    ``distance`` is metres from the sensor face (start of range + value); error codes (no object, too
    close, too far, ...) give ``distance=None`` with the reason in ``error``. Bursts of values that
    arrive together are stamped back from their arrival time at the measuring rate.
    """

    def __init__(self, settings: OptoNcdtSettings, name: str = "laser") -> None:
        super().__init__(name, frame=name)
        self.settings = settings
        self.port = SerialTransport(settings.port, baudrate=settings.baudrate, timeout=settings.reply_timeout)
        self.port.options["exclusive"] = True  # a port held by another program is an error, not shared
        self.decoder = self._new_decoder()
        self.info: dict[str, str] = {}
        self._last_byte = 0.0
        self._last_stamp: float | None = None
        self._held: list[int] = []  # values that arrived with the DAT_OUT_ON reply, not yet returned

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        try:
            self._configure()
        except BaseException:
            self.port.close()  # a failed configure leaves the port free for the next try
            raise

    def _configure(self) -> None:
        s = self.settings
        self.port.open()
        self._send(p.DAT_OUT_OFF)  # stop a running output so replies are not buried in values
        self.info = parse_info(self._send(p.GET_INFO).data)
        mr = self.info.get("MR")
        if mr and abs(float(mr) / 1000.0 - s.measuring_range) > 1e-6:
            raise DeviceError(
                f"optoNCDT on {s.port} reports a measuring range of {mr} mm, the settings say "
                f"{s.measuring_range * 1000:g} mm",
                "set measuring_range (and start_of_range) to the data sheet values of this ILD1402 model",
            )
        if s.apply_settings:
            self._send(p.SET_OUTPUT_CHANNEL, 1)  # digital (RS422) output
            self._send(p.ASCII_OUTPUT, 0)  # binary values
            n = s.averaging_number
            self._send(p.SET_AV, p.AVERAGE_TYPES[s.averaging], n)
            self._send(p.LASER_ON if s.laser else p.LASER_OFF)
            if parse_rate(self.info) != s.rate_hz:
                self._set_rate(s.rate_hz)

    def _new_decoder(self):
        return p.Decoder()

    def on_activate(self) -> None:
        self._held = []
        self._send(p.DAT_OUT_ON, keep_values=True)  # values read together with the reply are kept
        dec = self.decoder  # keep a value split across the reply; count losses from here on
        dec.lost_bytes = dec.good_bytes = 0
        dec.errors.clear()
        self._last_stamp = None
        self._last_byte = time.monotonic()

    def on_deactivate(self) -> None:
        try:
            self._send(p.DAT_OUT_OFF)
        except DeviceError:
            pass  # a broken link is reported by the next configure; stopping must not fail

    def on_close(self) -> None:
        self.port.close()

    def on_recover(self) -> None:
        self.port.close()
        self.decoder = self._new_decoder()

    # -- commands --------------------------------------------------------------------------------
    def _send(
        self, code: int, *params: int, timeout: float | None = None, keep_values: bool = False
    ) -> p.Reply:
        """Send a command and wait for its reply.

        Values arriving meanwhile are dropped (they belong to an output being switched off), except with
        ``keep_values``: after DAT_OUT_ON the first values often share a read with the reply, and they
        are measurements the caller asked for.
        """
        t = self.settings.reply_timeout if timeout is None else timeout
        self.decoder.replies.clear()  # stale answers
        try:
            self.port.send(p.command(code, *params))
        except TransportClosed as e:
            raise self._port_error(e) from None
        return self._wait_reply(code, t, keep_values)

    def _wait_reply(self, code: int, timeout: float, keep_values: bool = False) -> p.Reply:
        dec = self.decoder
        got = 0
        values = 0
        deadline = time.monotonic() + timeout
        while True:
            for k, r in enumerate(dec.replies):
                if r.code == code:
                    del dec.replies[: k + 1]
                    return r
            if time.monotonic() >= deadline:
                break
            try:
                data = self.port.recv(timeout=max(0.001, deadline - time.monotonic()))
            except TransportTimeout:
                break
            except TransportClosed as e:
                raise self._port_error(e) from None
            got += len(data)
            dvos = dec.feed(data)
            values += len(dvos)
            if keep_values:
                self._held += dvos
        raise self._no_reply(code, got, values)

    def _set_rate(self, rate_hz: int) -> None:
        """SET_SCANRATE makes the sensor reboot; it announces itself with its GET_INFO answer."""
        self._send(p.SET_SCANRATE, p.SCANRATES[rate_hz])
        self.info = parse_info(self._wait_reply(p.GET_INFO, self.settings.reboot_timeout).data)
        if parse_rate(self.info) not in (None, rate_hz):
            raise DeviceError(
                f"optoNCDT kept its rate of {parse_rate(self.info)} Hz after SET_SCANRATE {rate_hz} Hz",
                "check that the sensor runs the ILD1402 data protocol and supports this rate",
            )

    def _no_reply(self, code: int, got: int, values: int) -> DeviceError:
        s = self.settings
        if got == 0:
            return DeviceError(
                f"optoNCDT on {s.port} is silent: no answer to command 0x{code:02X} "
                f"within {s.reply_timeout} s",
                "check the sensor's power (24 V), the RS422 wiring (Tx/Rx pairs) and that the converter "
                "is the one at this port",
            )
        if values == 0 or self.decoder.lost_bytes > self.decoder.good_bytes:
            return DeviceError(
                f"optoNCDT on {s.port}: {got} bytes of garbage and no reply at {s.baudrate} baud",
                "wrong baud rate: the ILD1402 protocol runs at 115200 (the ILD1401 protocol at 38400); "
                "set baudrate to the sensor's",
            )
        return DeviceError(
            f"optoNCDT on {s.port} sends values but does not answer command 0x{code:02X}",
            "the sensor may run the ILD1401 data protocol or another model's command set; switch it to "
            "the ILD1402 protocol, or set apply_settings = false",
        )

    def _port_error(self, e: DeviceError) -> DeviceError:
        return DeviceError(
            f"optoNCDT on {self.settings.port}: {e.message}",
            e.fix or "check the USB cable of the RS422 converter",
        )

    # -- readings --------------------------------------------------------------------------------
    def _readings(self, dvos: list[int], t_arrival: float) -> list[Displacement]:
        s = self.settings
        stamps = backdate(len(dvos), t_arrival, 1.0 / s.rate_hz, after=self._last_stamp)
        if len(stamps):
            self._last_stamp = float(stamps[-1])
        out = []
        for dvo, t in zip(dvos, stamps, strict=True):
            d, err = self._convert(dvo)
            out.append(Displacement(float(t), d, self.frame, error=err))
        return out

    def _convert(self, dvo: int) -> tuple[float | None, str | None]:
        """Digital value -> (metres from the sensor face, None) or (None, the sensor's error)."""
        s = self.settings
        d = p.distance_from_dvo(dvo, s.measuring_range, s.start_of_range)
        return d, None if d is not None else p.ERROR_CODES.get(dvo, f"error code {dvo}")

    def _read_burst(self, timeout: float) -> list[Displacement]:
        if self._held:
            held, self._held = self._held, []
            return self._readings(held, time.time())
        data = recv_within_silence(
            self,
            self.port,
            timeout,
            self._last_byte,
            self.settings.silence_timeout,
            "sensor silent for {seconds:.2f} s while measuring (power, RS422 wiring, or output switched off)",
        )
        if not data:
            return []
        now = time.monotonic()
        self._last_byte = now
        dvos = self.decoder.feed(data)
        dec = self.decoder
        if dec.lost_bytes > GARBAGE_MIN_BYTES and dec.lost_bytes > 4 * dec.good_bytes:
            raise self.fault(
                f"{dec.lost_bytes} undecodable bytes against {dec.good_bytes} good ones: wrong baud rate "
                "or a different data protocol"
            )
        return self._readings(dvos, time.time())

    def _read(self, timeout: float) -> Displacement:
        """The newest value (older unread ones are dropped: use the stream to keep every value)."""
        deadline = time.monotonic() + timeout
        latest: list[Displacement] = []
        while True:
            got = self._read_burst(0.0 if latest else max(0.0, deadline - time.monotonic()))
            if got:
                latest = got
                continue
            if latest:
                return latest[-1]
            if time.monotonic() >= deadline:
                raise self.fault(f"sensor silent: no value within {timeout} s")

    @property
    def lost_bytes(self) -> int:
        """Bytes dropped while re-synchronising since activation."""
        return self.decoder.lost_bytes


def parse_info(data: bytes) -> dict[str, str]:
    """GET_INFO's "key: value" lines."""
    info = {}
    for line in data.decode("ascii", "replace").splitlines():
        k, sep, v = line.partition(":")
        if sep:
            info[k.strip()] = v.strip()
    return info


def parse_rate(info: dict[str, str]) -> int | None:
    m = re.match(r"(\d+)", info.get("Scanrate", ""))
    return int(m.group(1)) if m else None
