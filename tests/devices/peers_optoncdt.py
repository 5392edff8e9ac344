"""A pseudo-terminal optoNCDT 1402: ILD1402 command frames in, binary 14-bit values out at its rate.

The target distance follows ``profile(i)`` (metres from the sensor face, None = no object); every
``error_every``-th value is the "too far" error code. Faults: ``drop_byte_every`` loses bytes on the
line, ``mode = "garbage"`` answers like a port at the wrong baud rate, ``mode = "silent"`` never answers,
``mute()`` stops sending until the next command arrives (a power dip), ``pull()`` is a pulled cable.
"""

from __future__ import annotations

import random
import struct

from weldcell.plugins.optoncdt import protocol as p

from tests.devices.pty_peer import PtyPeer


class OptoNcdtPeer(PtyPeer):
    def __init__(self, measuring_range: float = 0.05, start_of_range: float = 0.045, rate: int = 1500):
        super().__init__()
        self.mr, self.smr = measuring_range, start_of_range
        self.rate = rate
        self.output_on = False
        self.laser_on = True
        self.ascii = False
        self.channel = 0
        self.average = (0, 1)
        self.mode = "ok"
        self.muted = False
        self.drop_byte_every = 0
        self.error_every = 0
        self.profile = lambda i: self.smr + self.mr * (0.5 + 0.3 * ((i % 200) / 200.0 - 0.5))
        self.sent_values: list[int] = []
        self.commands: list[int] = []
        self._cmd = bytearray()
        self._t0 = None
        self._sent_bytes = 0
        self._rng = random.Random(3)

    # -- commands --------------------------------------------------------------------------------
    def info(self) -> bytes:
        av = "moving average" if self.average[0] == 0 else "median"
        return (
            "ILD 1402: Standard\r\nA/N: 4120154\r\nS/N: 1234570\r\n"
            f"MR: {round(self.mr * 1000)}\r\nSoftVer: 1.001.796\r\n"
            f"Out Channel: {'digital' if self.channel else 'analog'}\r\n"
            f"Filter Type: {av}\r\nFilter Number: {self.average[1]}\r\n"
            f"Scanrate: {self.rate}Hz\r\ntype of digital output: {'ascii' if self.ascii else 'binary'}\r\n"
        ).encode()

    def on_bytes(self, data: bytes) -> None:
        self.muted = False
        if self.mode == "garbage":
            self.write(bytes(self._rng.randrange(256) for _ in range(3 * len(data))))
            return
        if self.mode == "silent":
            return
        self._cmd += data
        while True:
            i = self._cmd.find(p.PREFIX + p.MAGIC)
            if i < 0 or len(self._cmd) < i + 12:
                return
            (word,) = struct.unpack(">I", self._cmd[i + 8 : i + 12])
            nwords = word & 0xFF
            end = i + 4 + 4 * nwords
            if len(self._cmd) < end:
                return
            params = [struct.unpack(">I", self._cmd[k : k + 4])[0] for k in range(i + 12, end, 4)]
            del self._cmd[:end]
            self._command((word >> 16) & 0xFF, params)

    def _command(self, code: int, params: list[int]) -> None:
        self.commands.append(code)
        data = b""
        if code == p.DAT_OUT_ON:
            self.output_on = True
            self._t0 = None
        elif code == p.DAT_OUT_OFF:
            self.output_on = False
        elif code == p.GET_INFO:
            data = self.info()
        elif code == p.LASER_ON:
            self.laser_on = True
        elif code == p.LASER_OFF:
            self.laser_on = False
        elif code == p.SET_OUTPUT_CHANNEL:
            self.channel = params[0]
        elif code == p.ASCII_OUTPUT:
            self.ascii = bool(params[0])
        elif code == p.SET_AV:
            self.average = (params[0], params[1])
        elif code == p.SET_SCANRATE:
            self.rate = {v: k for k, v in p.SCANRATES.items()}[params[0]]
            self.write(p.reply(code))
            self.write(b"CI1402\r\n" + p.reply(p.GET_INFO, self.info()))  # reboot and boot message
            return
        self.write(p.reply(code, data))

    # -- measurement stream ----------------------------------------------------------------------
    def value(self, i: int) -> int:
        if not self.laser_on:
            return 16378
        if self.error_every and i % self.error_every == self.error_every - 1:
            return 16374
        d = self.profile(i)
        if d is None:
            return 16370
        return min(max(p.dvo_from_distance(d - self.smr, self.mr), 0), p.FULL_SCALE)

    def produce(self, now: float) -> bytes:
        if not self.output_on or self.muted or self.mode != "ok":
            return b""
        if self._t0 is None:
            self._t0 = now
        due = int((now - self._t0) * self.rate) - len(self.sent_values)
        out = bytearray()
        for _ in range(max(0, due)):
            v = self.value(len(self.sent_values))
            self.sent_values.append(v)
            for b in p.encode_value(v):
                self._sent_bytes += 1
                if self.drop_byte_every and self._sent_bytes % self.drop_byte_every == 0:
                    continue
                out.append(b)
        self.queue(bytes(out))  # lossless: only the losses a test asks for happen
        return b""

    def mute(self) -> None:
        """Stop sending until the host sends something (a power dip: the sensor restarts on a command)."""
        self.muted = True


class OptoNcdt1420Peer(PtyPeer):
    """A pseudo-terminal optoNCDT 1420: ASCII commands (CR-terminated, replies end with the ``->``
    prompt) answered *while* 3-byte values keep streaming, interleaved byte-wise with the values."""

    def __init__(self, measuring_range: float = 0.01, start_of_range: float = 0.02, rate: int = 1000):
        super().__init__()
        from weldcell.plugins.optoncdt import protocol_1420 as q

        self.q = q
        self.mr, self.smr, self.rate = measuring_range, start_of_range, rate
        self.output = "RS422"
        self.mode = "ok"
        self.muted = False
        self.error_every = 0
        self.drop_byte_every = 0
        self.profile = lambda i: self.smr + self.mr * (0.5 + 0.4 * ((i % 100) / 100.0 - 0.5))
        self.sent_values: list[int] = []
        self.commands: list[str] = []
        self._line = bytearray()
        self._reply = bytearray()
        self._t0 = None
        self._sent_bytes = 0
        self._rng = random.Random(4)

    def on_bytes(self, data: bytes) -> None:
        self.muted = False
        if self.mode == "garbage":
            self.queue(bytes(self._rng.randrange(256) for _ in range(3 * len(data))))
            return
        if self.mode == "silent":
            return
        self._line += data
        while b"\r" in self._line:
            i = self._line.index(b"\r")
            cmd = self._line[:i].decode()
            del self._line[: i + 1]
            self.commands.append(cmd)
            self._reply += self.answer(cmd).encode()

    def answer(self, cmd: str) -> str:
        if cmd == "GETINFO":
            return (
                "GETINFO\r\nName: ILD1420-10\r\nSerial: 15030002\r\nOption: 000\r\nArticle: 4120212\r\n"
                f"Cable head: Wire\r\nMeasuring range: {self.mr * 1000:.2f}mm\r\nVersion: 001.010\r\n->"
            )
        if cmd.startswith("OUTPUT "):
            self.output = cmd.split()[1]
            return f"{cmd}\r\n->"
        return f"{cmd}\r\nE200 unknown command\r\n->"

    def value(self, i: int) -> int:
        if self.error_every and i % self.error_every == self.error_every - 1:
            return 262078
        return self.q.dvo_from_distance(self.profile(i) - self.smr, self.mr)

    def produce(self, now: float) -> bytes:
        if self.muted or self.mode != "ok":
            return b""
        out = bytearray()
        if self.output == "RS422":
            if self._t0 is None:
                self._t0, self._n0 = now, len(self.sent_values)
            due = int((now - self._t0) * self.rate) - (len(self.sent_values) - self._n0)
            for _ in range(max(0, due)):
                v = self.value(len(self.sent_values))
                self.sent_values.append(v)
                for b in self.q.encode_value(v):
                    self._sent_bytes += 1
                    if self.drop_byte_every and self._sent_bytes % self.drop_byte_every == 0:
                        continue
                    out.append(b)
                out += self._reply[:2]  # reply text interleaved between values
                del self._reply[:2]
        else:
            self._t0 = None
        out += self._reply
        self._reply.clear()
        self.queue(bytes(out))
        return b""

    def mute(self) -> None:
        self.muted = True
