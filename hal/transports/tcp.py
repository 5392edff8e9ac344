"""TCP client and UDP endpoint transports (standard library ``socket``)."""

from __future__ import annotations

import select
import socket

from weldcell.hal.transports.base import Backoff, StreamTransport, Transport


class TcpTransport(StreamTransport):
    """A TCP client: ``open`` connects within ``connect_timeout``; reads time out after ``timeout`` s."""

    what = "TCP"

    def __init__(
        self,
        host: str,
        port: int,
        timeout: float = 1.0,
        connect_timeout: float = 2.0,
        backoff: Backoff | None = None,
        nodelay: bool = True,
    ) -> None:
        super().__init__(timeout, backoff)
        self.host, self.port = host, int(port)
        self.connect_timeout = float(connect_timeout)
        self.nodelay = nodelay
        self._sock: socket.socket | None = None

    def describe(self) -> str:
        return f"tcp://{self.host}:{self.port}"

    def fix_hint(self) -> str:
        return f"check that {self.host} is reachable and listening on port {self.port} (network, firewall)"

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    def _open(self) -> None:
        self._buf.clear()
        s = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        if self.nodelay:
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        s.settimeout(None)
        s.setblocking(False)
        self._sock = s

    def _close(self) -> None:
        s, self._sock = self._sock, None
        self._buf.clear()
        if s is not None:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()

    def _read_some(self, timeout: float) -> bytes:
        s = self._sock
        if s is None:
            raise self.closed("not open")
        ready, _, _ = select.select([s], [], [], max(0.0, timeout))
        if not ready:
            return b""
        try:
            data = s.recv(65536)
        except BlockingIOError:
            return b""
        except OSError as e:
            self._close()
            raise self.closed(f"connection lost ({e})") from e
        if not data:
            self._close()
            raise self.closed("connection closed by the peer")
        return data

    def _write(self, data: bytes) -> None:
        s = self._sock
        if s is None:
            raise self.closed("not open")
        view = memoryview(data)
        while view:
            _, w, _ = select.select([], [s], [], self.timeout)
            if not w:
                raise self.timed_out("room to send", self.timeout)
            try:
                n = s.send(view)
            except BlockingIOError:
                continue
            except OSError as e:
                self._close()
                raise self.closed(f"connection lost while sending ({e})") from e
            view = view[n:]


class UdpTransport(Transport):
    """A UDP endpoint sending to ``host:port`` (and receiving its replies); frames are datagrams.

    ``bind`` = (host, port) to receive on a fixed local port (e.g. a sensor that streams to us).
    A "connected" UDP socket reports an ICMP port-unreachable as :class:`TransportClosed`.
    """

    what = "UDP"

    def __init__(
        self,
        host: str,
        port: int,
        timeout: float = 1.0,
        bind: tuple[str, int] | None = None,
        backoff: Backoff | None = None,
    ) -> None:
        super().__init__(timeout, backoff)
        self.host, self.port = host, int(port)
        self.bind = bind
        self._sock: socket.socket | None = None

    def describe(self) -> str:
        return f"udp://{self.host}:{self.port}"

    def fix_hint(self) -> str:
        return f"check that the device at {self.host}:{self.port} is on and sending (network, firewall)"

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    @property
    def local_address(self) -> tuple[str, int]:
        self.require_open()
        return self._sock.getsockname()  # type: ignore[union-attr]

    def _open(self) -> None:
        fam = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        s = socket.socket(fam, socket.SOCK_DGRAM)
        try:
            if self.bind is not None:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind(self.bind)
            s.connect((self.host, self.port))
        except OSError:
            s.close()
            raise
        s.setblocking(False)
        self._sock = s

    def _close(self) -> None:
        s, self._sock = self._sock, None
        if s is not None:
            s.close()

    def send(self, data: bytes | str) -> None:
        """Send one datagram."""
        self.require_open()
        try:
            self._sock.send(data.encode() if isinstance(data, str) else bytes(data))  # type: ignore[union-attr]
        except OSError as e:
            raise self.closed(f"send failed ({e})") from e

    def recv(self, max_bytes: int = 65507, timeout: float | None = None) -> bytes:
        """One datagram; :class:`TransportTimeout` when none arrives in time."""
        self.require_open()
        t = self.timeout if timeout is None else timeout
        s = self._sock
        ready, _, _ = select.select([s], [], [], max(0.0, t))
        if not ready:
            raise self.timed_out("datagram", t)
        try:
            return s.recv(max_bytes)  # type: ignore[union-attr]
        except ConnectionRefusedError as e:
            raise self.closed("port unreachable (nothing listens there)") from e
        except OSError as e:
            raise self.closed(f"receive failed ({e})") from e

    read_frame = recv
