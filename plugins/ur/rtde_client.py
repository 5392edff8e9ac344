"""A minimal RTDE handshake over :class:`~weldcell.hal.transports.TcpTransport` (no ur-rtde needed).

Used by ``weldcell devices`` to tell whether a controller answers: it connects to port 30004,
negotiates protocol version 2 and reads the controller version. State streaming itself goes
through ur-rtde's ``RTDEReceiveInterface``, which works against a real controller and our
loopback peer alike.
"""

from __future__ import annotations

import struct

from weldcell.hal.transports import TcpTransport
from weldcell.plugins.ur import rtde_protocol as P
from weldcell.sdk.errors import DeviceError


def _request(t: TcpTransport, command: int, payload: bytes, timeout: float) -> bytes:
    t.send(P.pack(command, payload))
    while True:
        frame = t.read_frame(">H", length_includes_header=True, timeout=timeout)
        if frame and frame[0] == command:
            return frame[1:]
        # text messages and stray data packages are skipped


def rtde_handshake(host: str, port: int = P.PORT, timeout: float = 1.0) -> tuple[int, int, int, int]:
    """Controller version (major, minor, bugfix, build) after negotiating RTDE protocol 2.

    Raises :class:`DeviceError` when nothing answers, or the controller refuses protocol 2.
    """
    t = TcpTransport(host, port, timeout=timeout, connect_timeout=timeout)
    with t:
        (accepted,) = struct.unpack(
            ">B", _request(t, P.REQUEST_PROTOCOL_VERSION, struct.pack(">H", 2), timeout)
        )
        if not accepted:
            raise DeviceError(
                f"the controller at {host}:{port} refused RTDE protocol version 2",
                "update the robot software (RTDE v2 needs CB3 3.3 / any e-Series)",
            )
        reply = _request(t, P.GET_URCONTROL_VERSION, b"", timeout)
        return struct.unpack(">IIII", reply[:16])  # type: ignore[return-value]
