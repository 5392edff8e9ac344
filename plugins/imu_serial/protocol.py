"""Serial IMU frame protocols (no I/O here): HandsFree HFI-A9 and the WitMotion 0x55 family.

**HFI-A9** (as its vendor's own ROS drivers, HANDS-FREE/handsfree_ros_imu, parse it; the vendor
publishes no protocol document): ``0xAA 0x55 LEN`` + LEN payload bytes + CRC-16/MODBUS (init 0xFFFF,
reflected polynomial 0xA001) over ``LEN + payload``, sent low byte first. Two frame kinds:

- LEN 0x2C (44): 4 header bytes, then 10 little-endian float32: [0] not used by the vendor, [1:4]
  angular rate (rad/s), [4:7] acceleration (g; the vendor multiplies by -9.8 to get the ROS sign),
  [7:10] magnetic field (passed through unscaled by the vendor);
- LEN 0x14 (20): 4 header bytes, then 4 float32: [0] not used, [1:4] roll, pitch, yaw (degrees; the
  vendor negates pitch and yaw to get a right-handed body frame).

**WitMotion** (WT901/JY901 family, the common "0x55" protocol): 11-byte frames ``0x55 TYPE`` + 8 data
bytes (four little-endian int16) + checksum (sum of the first 10 bytes, low 8 bits). TYPE 0x50 time
(YY MM DD hh mm ss, ms as uint16), 0x51 acceleration (x/32768*16 g), 0x52 angular rate
(x/32768*2000 deg/s), 0x53 angles (x/32768*180 deg), 0x54 magnetic field (raw counts), 0x59
quaternion (w, x, y, z /32768).

Each decoder's ``feed(bytes)`` returns the completed frames in order and counts ``bad_checksum`` frames
and ``skipped`` bytes (garbage dropped while looking for the next header).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

A9_HEADER = b"\xaa\x55"
A9_IMU = 0x2C
A9_ANGLES = 0x14
A9_LENGTHS = (A9_IMU, A9_ANGLES)

WIT_TIME, WIT_ACC, WIT_GYRO, WIT_ANGLE, WIT_MAG, WIT_QUAT = 0x50, 0x51, 0x52, 0x53, 0x54, 0x59
WIT_TYPES = (WIT_TIME, WIT_ACC, WIT_GYRO, WIT_ANGLE, WIT_MAG, WIT_QUAT)


def crc16_modbus(data: bytes) -> int:
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def a9_frame(length: int, floats: list[float], header: bytes = b"\x00\x00\x00\x00") -> bytes:
    """One HFI-A9 frame (used by test peers)."""
    body = bytes([length]) + header + struct.pack(f"<{len(floats)}f", *floats)
    if len(body) != length + 1:
        raise ValueError(f"payload of {len(body) - 1} bytes does not match LEN {length}")
    return A9_HEADER + body + struct.pack("<H", crc16_modbus(body))


def wit_frame(kind: int, values: tuple[int, int, int, int]) -> bytes:
    """One WitMotion frame from four int16 (used by test peers)."""
    body = bytes([0x55, kind]) + struct.pack("<4h", *values)
    return body + bytes([sum(body) & 0xFF])


@dataclass
class Frame:
    kind: int
    """A9: LEN (0x2C / 0x14); WitMotion: TYPE."""
    values: tuple


@dataclass
class _Counters:
    frames: int = 0
    bad_checksum: int = 0
    skipped: int = 0
    _buf: bytearray = field(default_factory=bytearray)


class A9Decoder(_Counters):
    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        i = 0
        while True:
            j = buf.find(A9_HEADER, i)
            if j < 0:
                keep = 1 if buf[-1:] == A9_HEADER[:1] else 0
                self.skipped += len(buf) - i - keep
                i = len(buf) - keep
                break
            self.skipped += j - i
            i = j
            if len(buf) < i + 3:
                break
            n = buf[i + 2]
            if n not in A9_LENGTHS:
                self.skipped += 1  # not a frame we know (or a corrupted length): look further
                i += 1
                continue
            end = i + n + 5
            if len(buf) < end:
                break
            body = bytes(buf[i + 2 : end - 2])
            (crc,) = struct.unpack_from("<H", buf, end - 2)
            if crc16_modbus(body) != crc:
                self.bad_checksum += 1
                self.skipped += 1
                i += 1  # resynchronise on the next header after this one's first byte
                continue
            floats = struct.unpack_from(f"<{(n - 4) // 4}f", body, 5)
            out.append(Frame(n, floats))
            self.frames += 1
            i = end
        del buf[:i]
        return out


class WitDecoder(_Counters):
    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        i = 0
        n = len(buf)
        while n - i >= 11:
            if buf[i] != 0x55 or buf[i + 1] not in WIT_TYPES:
                self.skipped += 1
                i += 1
                continue
            if sum(buf[i : i + 10]) & 0xFF != buf[i + 10]:
                self.bad_checksum += 1
                self.skipped += 1
                i += 1
                continue
            out.append(Frame(buf[i + 1], struct.unpack_from("<4h", buf, i + 2)))
            self.frames += 1
            i += 11
        del buf[:i]
        return out
