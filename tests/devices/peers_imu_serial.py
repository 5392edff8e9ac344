"""A pseudo-terminal serial IMU streaming HFI-A9 or WitMotion frames at its rate.

The IMU rotates about z at ``omega`` rad/s, level, so the truth of every sample ``i`` is known:
gyro (0, 0, omega), acceleration (0, 0, +g) as specific force, yaw ``omega * i / rate``.
``corrupt_every`` flips one byte in every n-th frame (its checksum then fails), ``garbage`` sends noise
(a wrong baud rate), ``mute(seconds)`` is a power dip (the IMU restarts streaming on its own),
``pull()`` is a pulled cable.
"""

from __future__ import annotations

import math
import random

from weldcell.plugins.imu_serial import protocol as p

from tests.devices.pty_peer import PtyPeer

G = 9.80665


class ImuPeer(PtyPeer):
    def __init__(self, protocol: str = "hfi-a9", rate: float = 400.0, omega: float = 0.5) -> None:
        super().__init__()
        self.protocol = protocol
        self.rate = rate
        self.omega = omega
        self.corrupt_every = 0
        self.garbage = False
        self.silent = False
        self.muted_until = 0.0
        self.samples = 0
        self.frames_sent = 0
        self.corrupted = 0
        self._t0 = None
        self._rng = random.Random(5)

    def mute(self, seconds: float = 0.9) -> None:
        import time

        self.muted_until = time.monotonic() + seconds

    def truth(self, i: int) -> dict:
        return {"gyro": (0.0, 0.0, self.omega), "accel": (0.0, 0.0, G), "yaw": self.omega * i / self.rate}

    def frames(self, i: int) -> list[bytes]:
        t = self.truth(i)
        yaw = math.degrees(t["yaw"])
        yaw = (yaw + 180.0) % 360.0 - 180.0
        if self.protocol == "hfi-a9":
            # the A9 reports acceleration in g with the opposite sign and pitch/yaw negated
            imu = [float(i), *t["gyro"], *(-a / G for a in t["accel"]), 20.0, 0.0, -40.0]
            return [p.a9_frame(p.A9_IMU, imu), p.a9_frame(p.A9_ANGLES, [0.0, 0.0, 0.0, -yaw])]
        acc = tuple(round(a / G / 16.0 * 32768) for a in t["accel"]) + (2500,)
        gyr = tuple(round(math.degrees(w) / 2000.0 * 32768) for w in t["gyro"]) + (0,)
        ang = (0, 0, round(yaw / 180.0 * 32767), 0)
        ms = int(1000 * (i / self.rate)) % 1000
        s = int(i / self.rate)
        time_frame = (0x0B18, 0x0A18, s % 60 << 8 | 0, ms)  # 2024-11-24 10:00:ss
        return [
            p.wit_frame(p.WIT_TIME, time_frame),
            p.wit_frame(p.WIT_ACC, acc),
            p.wit_frame(p.WIT_GYRO, gyr),
            p.wit_frame(p.WIT_ANGLE, ang),
            p.wit_frame(p.WIT_MAG, (100, 0, -200, 0)),
        ]

    def produce(self, now: float) -> bytes:
        if now < self.muted_until or self.silent:
            self._t0 = None
            self.samples_at_t0 = self.samples
            return b""
        if self.garbage:
            return bytes(self._rng.randrange(256) for _ in range(64))
        if self._t0 is None:
            self._t0 = now
            self.samples_at_t0 = self.samples
        due = int((now - self._t0) * self.rate) - (self.samples - self.samples_at_t0)
        out = bytearray()
        for _ in range(max(0, due)):
            for f in self.frames(self.samples):
                self.frames_sent += 1
                if self.corrupt_every and self.frames_sent % self.corrupt_every == 0:
                    f = bytearray(f)
                    f[len(f) // 2] ^= 0x5A
                    self.corrupted += 1
                out += f
            self.samples += 1
        self.queue(bytes(out))  # lossless: only the losses a test asks for happen
        return b""
