"""The optoNCDT 1402 RS422 protocol (no I/O here): binary values, error codes and the command frames.

Measurement values (ILD1402 data protocol, binary output): one 14-bit digital value per measurement in
two bytes, the **H-byte first** — ``1 D13..D7`` — then the **L-byte** — ``0 D6..D0``; bit 7 is the flag
that tells them apart, so a lost byte is detected and the stream re-synchronises on the next H-byte.
Digital values 0..16368 span the measuring range with 1 % reserve at both ends::

    d = (dvo * 1.02 / 16368 - 0.01) * MR        (mm from the start of the measuring range, SMR)

Values above 16368 are error codes (16370 no object, 16372 too close, 16374 too far, 16376 cannot be
evaluated, 16378 laser off, 16380/16382 target moving too fast towards/away) — never a distance.

Commands (8.3 of the ILD1402 manual): ``"+++\\r" "ILD1"`` then a 32-bit command word
``0x20 CC 00 LL`` (CC the command, LL the frame length in 32-bit words counted from "ILD1") and its
parameters, all big-endian. The sensor answers ``"ILD1" 0xA0 CC 00 LL [data] "  \\r\\n"``; replies are
ASCII/0xA0 bytes, and four consecutive bytes with bit 7 clear never occur in a value stream, so a reply
("ILD1...") can be cut out of a running measurement stream without ambiguity.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

FULL_SCALE = 16368
ERROR_CODES = {
    16370: "no object detected",
    16372: "too close to the sensor",
    16374: "too far from the sensor",
    16376: "object cannot be evaluated",
    16378: "laser off",
    16380: "target moves towards the sensor too fast",
    16382: "target moves away from the sensor too fast",
}

PREFIX = b"+++\r"
MAGIC = b"ILD1"
REPLY_END = b"  \r\n"

# command codes (CC of the command word 0x20CC00LL), ILD1402 manual 8.3.2
GET_INFO = 0x49
GET_SETTINGS = 0x4A
SET_AV = 0x7F
DAT_OUT_OFF = 0x76
DAT_OUT_ON = 0x77
SET_OUTPUT_CHANNEL = 0x90
SET_SCANRATE = 0x85
LASER_ON = 0x87
LASER_OFF = 0x86
ASCII_OUTPUT = 0x88

SCANRATES = {1500: 0, 1000: 1, 750: 2, 375: 3, 50: 4}
"""Measuring rate [Hz] -> SET_SCANRATE parameter."""
AVERAGE_TYPES = {"moving": 0, "median": 1}
MEDIAN_SIZES = (3, 5, 7, 9)


def command(code: int, *params: int) -> bytes:
    """The bytes that send command ``code`` with 32-bit parameters."""
    words = 2 + len(params)
    return (
        PREFIX
        + MAGIC
        + struct.pack(">I", 0x20000000 | (code << 16) | words)
        + b"".join(struct.pack(">I", p & 0xFFFFFFFF) for p in params)
    )


def reply(code: int, data: bytes = b"") -> bytes:
    """The sensor's answer to ``code`` (used by test peers)."""
    words = 2 + (len(data) + 3) // 4
    return MAGIC + struct.pack(">I", 0xA0000000 | (code << 16) | words) + data + REPLY_END


def encode_value(dvo: int) -> bytes:
    """Two bytes of one 14-bit digital value (H-byte, L-byte)."""
    if not 0 <= dvo < 1 << 14:
        raise ValueError(f"digital value {dvo} outside 14 bits")
    return bytes((0x80 | (dvo >> 7), dvo & 0x7F))


def dvo_from_distance(d: float, measuring_range: float) -> int:
    """The digital value of ``d`` metres from the start of the measuring range."""
    return int(round((d / measuring_range + 0.01) * FULL_SCALE / 1.02))


def distance_from_dvo(dvo: int, measuring_range: float, start_of_range: float) -> float | None:
    """Metres from the sensor face (SMR + d); None for error codes."""
    if dvo > FULL_SCALE:
        return None
    return start_of_range + (dvo * 1.02 / FULL_SCALE - 0.01) * measuring_range


@dataclass
class Reply:
    code: int
    data: bytes


@dataclass
class Decoder:
    """Splits a byte stream into digital values and command replies; counts what it had to drop.

    ``feed(bytes)`` returns the values completed by those bytes, in order; ``replies`` collects replies.
    """

    lost_bytes: int = 0
    """Bytes dropped while re-synchronising (a lost H- or L-byte leaves its partner alone)."""
    errors: dict[int, int] = field(default_factory=dict)
    """Error code -> count."""
    replies: list[Reply] = field(default_factory=list)
    good_bytes: int = 0
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[int]:
        buf = self._buf
        buf += data
        out: list[int] = []
        i, n = 0, len(buf)
        while i < n:
            b = buf[i]
            if b & 0x80:
                if i + 1 >= n:
                    break  # H-byte waiting for its L-byte
                b2 = buf[i + 1]
                if b2 & 0x80:
                    self.lost_bytes += 1  # an H-byte whose L-byte was lost
                    i += 1
                    continue
                dvo = ((b & 0x7F) << 7) | b2
                if dvo > FULL_SCALE:
                    self.errors[dvo] = self.errors.get(dvo, 0) + 1
                out.append(dvo)
                self.good_bytes += 2
                i += 2
                continue
            if b == MAGIC[0]:
                end = self._reply_at(buf, i)
                if end == -1:
                    break  # a reply still arriving
                if end > 0:
                    i = end
                    continue
            self.lost_bytes += 1  # an L-byte without its H-byte
            i += 1
        del buf[:i]
        if len(buf) > 4096:  # never grow without bound on garbage
            self.lost_bytes += len(buf)
            buf.clear()
        return out

    def _reply_at(self, buf: bytearray, i: int) -> int:
        """End index of a reply starting at ``i``; -1 when it is incomplete; 0 when this is no reply."""
        head = bytes(buf[i : i + 8])
        if len(head) < 4:
            return -1 if MAGIC.startswith(head) else 0
        if head[:4] != MAGIC:
            return 0
        if len(head) < 8:
            return -1
        (word,) = struct.unpack(">I", head[4:8])
        if word >> 24 != 0xA0:
            return 0
        end = buf.find(REPLY_END, i + 8)
        if end < 0:
            return -1 if len(buf) - i < 2048 else 0
        self.replies.append(Reply((word >> 16) & 0xFF, bytes(buf[i + 8 : end])))
        return end + len(REPLY_END)
