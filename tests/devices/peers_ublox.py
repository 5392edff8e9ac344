"""A pseudo-terminal u-blox receiver: replays real captures, or answers UBX-CFG and streams NAV-PVT.

``replay(path)`` sends a capture from ../shared/data/ublox-gnss-logs/ byte for byte (nothing dropped);
in live mode the peer acknowledges CFG-RATE / CFG-MSG / CFG-VALSET with ACK-ACK (or ACK-NAK for
``nak``), then sends a pyubx2-generated NAV-PVT every navigation period, with ``fix`` False giving
fixType 0. ``garbage`` is noise (a wrong baud rate), ``mute(s)`` a power dip, ``pull()`` a pulled cable.
"""

from __future__ import annotations

import os
import random
import time
from pathlib import Path

from pyubx2 import GET, SET, UBXMessage, UBXReader

from tests.devices.pty_peer import PtyPeer

LOGS = Path(
    os.environ.get("WELDCELL_UBLOX_LOGS", Path(__file__).resolve().parents[3] / "shared/data/ublox-gnss-logs")
)


TXT = b"$GNTXT,01,01,02,ANTSTATUS=OK*25\r\n"


class UbloxPeer(PtyPeer):
    def __init__(self, live: bool = True) -> None:
        super().__init__()
        self.live = live
        self.period = 1.0
        self.fix = True
        self.nak: set[str] = set()
        self.garbage = False
        self.silent = False
        self.muted_until = 0.0
        self.configured: list[UBXMessage] = []
        self.epochs = 0
        self._next = None
        self._inbox = bytearray()
        self._rng = random.Random(7)

    def replay(self, name: str) -> int:
        data = (LOGS / name).read_bytes()
        self.queue(data)
        return len(data)

    def mute(self, seconds: float = 1.5) -> None:
        self.muted_until = time.monotonic() + seconds

    def on_bytes(self, data: bytes) -> None:
        if self.silent or self.garbage:
            return
        self.muted_until = 0.0  # it answers, so it is back
        self._inbox += data
        while True:
            i = self._inbox.find(b"\xb5\x62")
            if i < 0 or len(self._inbox) < i + 8:
                return
            n = self._inbox[i + 4] | self._inbox[i + 5] << 8
            if len(self._inbox) < i + 8 + n:
                return
            raw = bytes(self._inbox[i : i + 8 + n])
            del self._inbox[: i + 8 + n]
            msg = UBXReader.parse(raw, msgmode=SET, validate=0)
            self.configured.append(msg)
            if msg.identity == "CFG-RATE":
                self.period = msg.measRate / 1000.0
            kind = "ACK-NAK" if msg.identity in self.nak else "ACK-ACK"
            self.queue(UBXMessage("ACK", kind, GET, clsID=raw[2], msgID=raw[3]).serialize())

    def pvt(self, k: int) -> bytes:
        fix = self.fix
        return UBXMessage(
            "NAV",
            "NAV-PVT",
            GET,
            iTOW=k * 1000,
            year=2024,
            month=11,
            day=24,
            hour=10,
            min=0,
            second=k % 60,
            validDate=1,
            validTime=1,
            fixType=3 if fix else 0,
            gnssFixOk=1 if fix else 0,
            numSV=9 if fix else 0,
            lat=45.0 + 1e-6 * k if fix else 0.0,
            lon=7.0 if fix else 0.0,
            height=250000 if fix else 0,
            hMSL=200000 if fix else 0,
            hAcc=1500 if fix else 4294967,
            vAcc=2500 if fix else 4294967,
            velN=100,
            velE=-20,
            velD=5,
        ).serialize()

    def produce(self, now: float) -> bytes:
        if self.silent or now < self.muted_until:
            self._next = None
            return b""
        if self.garbage:
            return bytes(self._rng.randrange(256) for _ in range(32))
        if not self.live:
            if self.queued == 0 and now >= (self._next or 0.0):  # idle: the receiver's periodic TXT
                self._next = now + 0.05
                self.queue(TXT)
            return b""
        if self._next is None:
            self._next = now + self.period
        if now >= self._next:
            self._next += self.period
            self.epochs += 1
            self.queue(self.pvt(self.epochs))
        return b""
