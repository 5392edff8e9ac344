"""A USB-serial IMU through pyserial (device ``imu.serial``): HFI-A9 or WitMotion frames, full rate."""

from __future__ import annotations

import datetime as _dt
import time

import numpy as np
import serial  # noqa: F401 - the vendor library of this adapter (extra 'serial'); used by SerialTransport
from scipy.spatial.transform import Rotation
from weldcell.hal.interfaces import Imu
from weldcell.hal.readings import ImuReading
from weldcell.hal.stream import backdate, recv_within_silence
from weldcell.hal.transports import SerialTransport, TransportClosed, TransportTimeout
from weldcell.plugins.imu_serial import protocol as p
from weldcell.plugins.imu_serial.settings import ImuSerialSettings
from weldcell.sdk.errors import DeviceError

G = 9.80665
GARBAGE_MIN_BYTES = 256


class SerialImu(Imu):
    """Reads every frame the IMU sends; one :class:`ImuReading` per measurement cycle.

    HFI-A9: one reading per 0x2C frame (rate, acceleration, field) with the latest 0x14 angles as
    orientation. WitMotion: frames of one cycle (0x51..0x54, 0x59, 0x50) are merged; the cycle ends
    when its set of frame types is complete or a type repeats. Bad checksums are skipped and counted
    (``bad_checksum``); stamps are arrival times spread over each burst at the measured rate.
    """

    def __init__(self, settings: ImuSerialSettings, name: str = "imu") -> None:
        super().__init__(name, frame=name)
        self.settings = settings
        self.port = SerialTransport(settings.port, baudrate=settings.baudrate, timeout=settings.open_timeout)
        self.port.options["exclusive"] = True
        self._reset()

    def _reset(self) -> None:
        self.decoder = p.A9Decoder() if self.settings.protocol == "hfi-a9" else p.WitDecoder()
        self._orientation: np.ndarray | None = None
        self._cycle: dict[int, tuple] = {}
        self._cycle_types: set[int] = set()
        self._last_byte = time.monotonic()
        self._last_stamp: float | None = None
        self._t_first: float | None = None
        self._n_readings = 0
        self._pending: list[ImuReading] = []

    @property
    def bad_checksum(self) -> int:
        return self.decoder.bad_checksum

    @property
    def skipped_bytes(self) -> int:
        return self.decoder.skipped

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        try:
            self._configure()
        except BaseException:
            self.port.close()  # a failed configure leaves the port free for the next try
            raise

    def _configure(self) -> None:
        """Open the port and wait for the first good frame (the IMU streams on its own)."""
        s = self.settings
        try:
            self.port.open()
        except DeviceError as e:
            raise DeviceError(f"IMU on {s.port}: {e.message}", e.fix) from None
        self._reset()
        got = 0
        deadline = time.monotonic() + s.open_timeout
        while time.monotonic() < deadline:
            try:
                data = self.port.recv(timeout=max(0.001, deadline - time.monotonic()))
            except TransportTimeout:
                break
            except TransportClosed as e:
                raise DeviceError(f"IMU on {s.port}: {e.message}", e.fix) from None
            got += len(data)
            if self.decoder.feed(data):
                self._reset()
                return
        if got == 0:
            raise DeviceError(
                f"IMU on {s.port} is silent: no byte within {s.open_timeout} s",
                "check the USB cable and the IMU's power; some IMUs need their output enabled once "
                "with the vendor's tool",
            )
        raise DeviceError(
            f"IMU on {s.port}: {got} bytes without one valid {s.protocol} frame at {s.baudrate} baud "
            f"({self.decoder.bad_checksum} bad checksums)",
            "wrong baud rate or protocol: the HFI-A9 sends at 921600 baud; WitMotion IMUs at 9600 or "
            "115200 — set baudrate and protocol to the IMU's",
        )

    def on_activate(self) -> None:
        self.port.clear_input()
        self._reset()

    def on_close(self) -> None:
        self.port.close()

    def on_recover(self) -> None:
        self.port.close()

    # -- readings --------------------------------------------------------------------------------
    def _read_burst(self, timeout: float) -> list[ImuReading]:
        data = recv_within_silence(
            self,
            self.port,
            timeout,
            self._last_byte,
            self.settings.silence_timeout,
            "IMU silent for {seconds:.2f} s while active",
        )
        if not data:
            return []
        now = time.monotonic()
        self._last_byte = now
        dec = self.decoder
        parts = self._merge(dec.feed(data))
        if dec.skipped > GARBAGE_MIN_BYTES and dec.frames == 0:
            raise self.fault(f"{dec.skipped} bytes without a valid frame: wrong baud rate or protocol")
        return self._stamp(parts, time.time())

    def _stamp(self, parts: list[dict], t_arrival: float) -> list[ImuReading]:
        if not parts:
            return []
        if self._t_first is None:
            self._t_first = t_arrival
        self._n_readings += len(parts)
        span = t_arrival - self._t_first
        period = span / (self._n_readings - 1) if self._n_readings > 50 else 1.0 / self.settings.rate_hz
        stamps = backdate(len(parts), t_arrival, period, after=self._last_stamp)
        self._last_stamp = float(stamps[-1])
        return [
            ImuReading(
                float(t),
                q["accel"],
                q["gyro"],
                mag=q.get("mag"),
                orientation=q.get("orientation"),
                frame=self.frame,
                device_stamp=q.get("device_stamp"),
            )
            for q, t in zip(parts, stamps, strict=True)
        ]

    def _merge(self, frames: list[p.Frame]) -> list[dict]:
        if self.settings.protocol == "hfi-a9":
            return self._merge_a9(frames)
        return self._merge_wit(frames)

    def _merge_a9(self, frames: list[p.Frame]) -> list[dict]:
        out = []
        for f in frames:
            v = f.values
            if f.kind == p.A9_ANGLES:
                r, pi, y = np.radians(v[1:4])
                self._orientation = Rotation.from_euler("xyz", [r, -pi, -y]).as_quat()
                continue
            out.append(
                {
                    "gyro": np.asarray(v[1:4], float),
                    "accel": -G * np.asarray(v[4:7], float),
                    "mag": self.settings.mag_scale * np.asarray(v[7:10], float),
                    "orientation": self._orientation,
                }
            )
        return out

    def _merge_wit(self, frames: list[p.Frame]) -> list[dict]:
        out = []
        for f in frames:
            if f.kind in self._cycle:
                out += self._flush()
            self._cycle[f.kind] = f.values
            if self._cycle_types and set(self._cycle) >= self._cycle_types:
                out += self._flush()
        return out

    def _flush(self) -> list[dict]:
        c, self._cycle = self._cycle, {}
        self._cycle_types = set(c)
        if p.WIT_ACC not in c or p.WIT_GYRO not in c:
            return []  # a cycle needs at least acceleration and rate
        q = {
            "accel": np.asarray(c[p.WIT_ACC][:3], float) / 32768.0 * 16.0 * G,
            "gyro": np.radians(np.asarray(c[p.WIT_GYRO][:3], float) / 32768.0 * 2000.0),
        }
        if p.WIT_MAG in c:
            q["mag"] = self.settings.mag_scale * np.asarray(c[p.WIT_MAG][:3], float)
        if p.WIT_QUAT in c:
            w, x, y, z = np.asarray(c[p.WIT_QUAT], float) / 32768.0
            q["orientation"] = np.array([x, y, z, w]) / max(np.linalg.norm([x, y, z, w]), 1e-12)
        elif p.WIT_ANGLE in c:
            q["orientation"] = Rotation.from_euler(
                "xyz", np.radians(np.asarray(c[p.WIT_ANGLE][:3], float) / 32768.0 * 180.0)
            ).as_quat()
        if p.WIT_TIME in c:
            q["device_stamp"] = wit_time(c[p.WIT_TIME])
        return [q]

    def _read(self, timeout: float) -> ImuReading:
        """The newest reading (older unread ones are dropped: use the stream to keep every one)."""
        deadline = time.monotonic() + timeout
        latest: list[ImuReading] = []
        while True:
            got = self._read_burst(0.0 if latest else max(0.0, deadline - time.monotonic()))
            if got:
                latest = got
                continue
            if latest:
                return latest[-1]
            if time.monotonic() >= deadline:
                raise self.fault(f"IMU silent: no complete reading within {timeout} s")


def wit_time(values: tuple) -> float | None:
    """WitMotion 0x50 time frame -> seconds since the Unix epoch (the IMU's clock, UTC assumed)."""
    raw = b"".join(int(v).to_bytes(2, "little", signed=True) for v in values)
    yy, mm, dd, hh, mi, ss = raw[:6]
    ms = int.from_bytes(raw[6:8], "little")
    try:
        t = _dt.datetime(2000 + yy, mm, dd, hh, mi, ss, ms * 1000, tzinfo=_dt.UTC)
    except ValueError:
        return None
    return t.timestamp()
