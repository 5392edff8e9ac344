"""Shared transports for device adapters: serial (pyserial), TCP and UDP (socket), WebSocket (websockets).

Importing this package imports no vendor library; pyserial and websockets load when a port or
connection is opened.
"""

from weldcell.hal.transports.base import (
    Backoff,
    StreamTransport,
    Transport,
    TransportClosed,
    TransportTimeout,
)
from weldcell.hal.transports.serial_port import SerialTransport
from weldcell.hal.transports.tcp import TcpTransport, UdpTransport
from weldcell.hal.transports.websocket import WebSocketTransport

__all__ = [
    "Backoff",
    "SerialTransport",
    "StreamTransport",
    "TcpTransport",
    "Transport",
    "TransportClosed",
    "TransportTimeout",
    "UdpTransport",
    "WebSocketTransport",
]
