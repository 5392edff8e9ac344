"""The optoNCDT 1420/1320 RS422 protocol (no I/O): 3-byte binary values and the ASCII command set.

Values (1420/1320 manuals, "Measurement data format"): each output value is three bytes sent L, M, H;
the two most significant bits tell them apart — L ``00 D5..D0``, M ``01 D11..D6``, H ``1 a D17 D16
D15..D12`` where ``a`` is 0 for the first output value of a block (the distance) and 1 for additional
values (intensity, counters, ... when selected). Distance without mastering is 16 bits::

    d = (x * 102 / 65520 - 1) * MR / 100        (mm from the start of the measuring range)

(x in [643, 64877] is the measuring range, with 1 % reserves around it); error values are 18-bit:
262075 too much data for the baud rate, 262076 no peak, 262077 peak before the range (too close),
262078 peak behind the range (too far), 262080 cannot be calculated, 262081 peak too large,
262082 laser off.

Commands are ASCII lines ending in CR; the sensor answers with its reply and a ``->`` prompt (an
error reply starts with ``Exxx``), and it keeps sending values meanwhile: ASCII text never contains a
byte with bit 7 set, so it never completes an L-M-H triple and is separated from the values.
"""

from __future__ import annotations

from dataclasses import dataclass, field

FULL_SCALE = 65520
ERROR_CODES = {
    262075: "too much data for the baud rate",
    262076: "no peak (no object)",
    262077: "too close to the sensor",
    262078: "too far from the sensor",
    262080: "measurement value cannot be calculated",
    262081: "peak too large",
    262082: "laser off",
}
PROMPT = b"->"


def encode_value(x: int, additional: bool = False) -> bytes:
    """Three bytes (L, M, H) of one 18-bit output value (used by test peers)."""
    if not 0 <= x < 1 << 18:
        raise ValueError(f"value {x} outside 18 bits")
    return bytes((x & 0x3F, 0x40 | (x >> 6) & 0x3F, 0x80 | (0x40 if additional else 0) | (x >> 12) & 0x3F))


def dvo_from_distance(d: float, measuring_range: float) -> int:
    return int(round((d / measuring_range * 100.0 + 1.0) * FULL_SCALE / 102.0))


def distance_from_dvo(x: int, measuring_range: float, start_of_range: float) -> float | None:
    if x > FULL_SCALE:
        return None
    return start_of_range + (x * 102.0 / FULL_SCALE - 1.0) * measuring_range / 100.0


def error_text(x: int) -> str:
    return ERROR_CODES.get(x, f"value {x} outside the output range")


@dataclass
class Decoder:
    """Splits the byte stream into first output values (distances) and the ASCII reply text."""

    lost_bytes: int = 0
    good_bytes: int = 0
    additional: int = 0
    """Additional output values seen (skipped: only the distance is read)."""
    text: bytearray = field(default_factory=bytearray)
    _buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[int]:
        buf = self._buf
        buf += data
        out: list[int] = []
        i, n = 0, len(buf)
        while i < n:
            b = buf[i]
            if b & 0xC0 == 0x00 and n - i < 3 and (n - i == 1 or buf[i + 1] & 0xC0 == 0x40):
                break  # maybe the start of a value still arriving
            if b & 0xC0 == 0x00 and i + 2 < n and buf[i + 1] & 0xC0 == 0x40 and buf[i + 2] & 0x80:
                h = buf[i + 2]
                x = (h & 0x3F) << 12 | (buf[i + 1] & 0x3F) << 6 | (b & 0x3F)
                if h & 0x40:
                    self.additional += 1
                else:
                    out.append(x & 0x3FFFF)
                self.good_bytes += 3
                i += 3
                continue
            if b & 0x80:
                self.lost_bytes += 1  # an H-byte whose L or M byte was lost
            else:
                self.text.append(b)  # ASCII reply text (or an L/M byte whose partner was lost)
            i += 1
        del buf[:i]
        if len(self.text) > 16384:
            self.lost_bytes += len(self.text)
            self.text.clear()
        return out

    def take_reply(self) -> str | None:
        """The reply text up to and including the next ``->`` prompt, or None when none is complete."""
        j = self.text.find(PROMPT)
        if j < 0 and self._buf and not any(c & 0x80 for c in self._buf):
            if (self.text + self._buf).find(PROMPT) >= 0:  # the prompt is the last thing that came
                self.text += self._buf
                self._buf.clear()
                j = self.text.find(PROMPT)
        if j < 0:
            return None
        reply = bytes(self.text[: j + len(PROMPT)]).decode("ascii", "replace")
        del self.text[: j + len(PROMPT)]
        return reply
