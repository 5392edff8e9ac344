"""hal.transports against real peers on this machine: a pseudo-terminal, TCP/UDP and WebSocket servers."""

from __future__ import annotations

import os
import socket
import struct
import sys
import threading
import time

import pytest
from weldcell.hal.transports import (
    Backoff,
    SerialTransport,
    TcpTransport,
    TransportClosed,
    TransportTimeout,
    UdpTransport,
    WebSocketTransport,
)
from weldcell.sdk.errors import DataError, DeviceError, MissingExtraError

# ------------------------------------------------------------------------------------------------ peers


class TcpEchoServer:
    """Echoes lines; ``drop()`` closes the current clients, the server keeps listening."""

    def __init__(self) -> None:
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.port = self.srv.getsockname()[1]
        self.srv.settimeout(0.05)
        self.clients: list[socket.socket] = []
        self.accepted = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                c, _ = self.srv.accept()
            except (TimeoutError, OSError):
                continue
            self.accepted += 1
            self.clients.append(c)
            threading.Thread(target=self._echo, args=(c,), daemon=True).start()

    def _echo(self, c: socket.socket) -> None:
        try:
            while True:
                data = c.recv(4096)
                if not data:
                    return
                if data.startswith(b"FRAME"):
                    body = b"payload-" + data[5:].strip()
                    c.sendall(struct.pack(">HB", len(body) + 3, ord("U")) + body)
                else:
                    c.sendall(data)
        except OSError:
            return

    def drop(self) -> None:
        for c in self.clients:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()
        self.clients.clear()

    def close(self) -> None:
        self.stop.set()
        self.drop()
        self.thread.join(1)
        self.srv.close()


@pytest.fixture
def tcp_server():
    s = TcpEchoServer()
    yield s
    s.close()


@pytest.fixture
def pty_pair():
    if sys.platform == "win32":
        pytest.skip("pseudo-terminals need a POSIX system")
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    yield master, os.ttyname(slave)
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


# ------------------------------------------------------------------------------------------------ serial


def test_serial_lines_both_ways_over_a_pty(pty_pair):
    master, path = pty_pair
    with SerialTransport(path, baudrate=115200, timeout=1.0) as port:
        os.write(master, b"DIST 12.345\r\nDIST 12.4")
        assert port.read_line(b"\r\n") == b"DIST 12.345\r\n"
        with pytest.raises(TransportTimeout) as e:
            port.read_line(b"\r\n", timeout=0.1)  # the second line is not finished yet
        assert "within" in e.value.message and e.value.fix
        os.write(master, b"00\r\n")
        assert port.read_line(b"\r\n") == b"DIST 12.400\r\n"
        port.send("MEASURE\r\n")
        got = b""
        deadline = time.time() + 1
        while not got.endswith(b"\r\n") and time.time() < deadline:
            got += os.read(master, 64)
        assert got == b"MEASURE\r\n"


def test_serial_exact_and_frames(pty_pair):
    master, path = pty_pair
    with SerialTransport(path) as port:
        os.write(master, struct.pack(">H", 4) + b"abcd" + b"xyz")
        assert port.read_frame(">H") == b"abcd"
        assert port.recv_exact(3) == b"xyz"


def test_serial_missing_port_is_a_device_error_with_a_fix(tmp_path):
    port = SerialTransport(str(tmp_path / "ttyNOPE"), timeout=0.1)
    with pytest.raises(TransportClosed) as e:
        port.open()
    assert "ttyNOPE" in e.value.message and "plugged" in e.value.fix
    with pytest.raises(TransportClosed):
        port.reconnect(Backoff(attempts=3, initial=0.001))


def test_serial_reconnects_after_the_device_vanishes(pty_pair):
    master, path = pty_pair
    port = SerialTransport(path, timeout=0.2)
    port.open()
    os.write(master, b"A\n")
    assert port.read_line() == b"A\n"
    port._ser.close()  # the OS handle dies as on a USB unplug
    with pytest.raises(DeviceError):
        port.read_line(timeout=0.1)
    assert port.reconnect(Backoff(attempts=3, initial=0.001)) == 1
    os.write(master, b"B\n")
    assert port.read_line() == b"B\n"
    port.close()


def test_serial_without_pyserial_names_the_extra(monkeypatch, pty_pair):
    monkeypatch.setitem(sys.modules, "serial", None)
    with pytest.raises(MissingExtraError) as e:
        SerialTransport(pty_pair[1]).open()
    assert "weldcell[serial]" in e.value.fix


def test_importing_transports_loads_no_vendor_library():
    import subprocess

    code = (
        "import sys, weldcell.hal, weldcell.hal.transports; "
        "print(sorted(m for m in ('serial','websockets') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


# ------------------------------------------------------------------------------------------------ TCP


def test_tcp_line_frame_and_timeout(tcp_server):
    with TcpTransport("127.0.0.1", tcp_server.port, timeout=1.0) as t:
        t.send(b"hello\nwor")
        assert t.read_line() == b"hello\n"
        with pytest.raises(TransportTimeout):
            t.read_line(timeout=0.1)
        t.send(b"ld\n")
        assert t.read_line() == b"world\n"
        t.send(b"FRAME7")
        assert t.read_frame(">H", length_includes_header=True) == b"Upayload-7"


def test_tcp_refused_connection_is_a_device_error(tcp_server):
    port = tcp_server.port
    tcp_server.close()
    t = TcpTransport("127.0.0.1", port, connect_timeout=0.5)
    with pytest.raises(TransportClosed) as e:
        t.open()
    assert str(port) in e.value.message and e.value.fix
    with pytest.raises(TransportClosed) as e:
        t.reconnect(Backoff(attempts=3, initial=0.001))
    assert "after 3 attempts" in e.value.message


def test_tcp_reconnects_after_the_server_drops_the_client(tcp_server):
    t = TcpTransport("127.0.0.1", tcp_server.port, timeout=1.0)
    t.open()
    t.send(b"one\n")
    assert t.read_line() == b"one\n"
    time.sleep(0.05)
    tcp_server.drop()
    with pytest.raises(TransportClosed) as e:
        t.read_line(timeout=1.0)
    assert "closed by the peer" in e.value.message or "lost" in e.value.message
    assert not t.is_open
    assert t.reconnect() == 1 and t.reconnects == 1
    t.send(b"two\n")
    assert t.read_line() == b"two\n"
    assert tcp_server.accepted == 2
    t.close()


def test_reconnect_backs_off_until_the_server_returns():
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    slept: list[float] = []
    servers = []

    def sleep(d):  # the server comes back during the third wait
        slept.append(d)
        if len(slept) == 3:
            servers.append(socket.create_server(("127.0.0.1", port)))

    t = TcpTransport("127.0.0.1", port, connect_timeout=0.5)
    assert t.reconnect(Backoff(attempts=6, initial=0.01, factor=2.0, max_delay=0.03), sleep=sleep) == 4
    assert slept == [0.01, 0.02, 0.03]
    t.close()
    servers[0].close()


# ------------------------------------------------------------------------------------------------ UDP


def test_udp_datagrams_timeout_and_unreachable():
    srv = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    srv.bind(("127.0.0.1", 0))
    port = srv.getsockname()[1]

    def echo():
        data, addr = srv.recvfrom(2048)
        srv.sendto(data.upper(), addr)

    th = threading.Thread(target=echo, daemon=True)
    th.start()
    with UdpTransport("127.0.0.1", port, timeout=1.0) as u:
        u.send(b"ping")
        assert u.recv() == b"PING"
        th.join(1)
        with pytest.raises(TransportTimeout):
            u.recv(timeout=0.05)
        srv.close()  # nothing listens any more: the kernel answers port-unreachable
        u.send(b"ping")
        with pytest.raises(DeviceError):
            u.recv(timeout=0.5)
        assert u.reconnect() == 1 and u.is_open


# ------------------------------------------------------------------------------------------------ WebSocket


@pytest.fixture
def ws_server():
    from websockets.sync.server import serve

    state = {"conns": [], "count": 0}

    def handler(ws):
        state["conns"].append(ws)
        state["count"] += 1
        for msg in ws:
            ws.send(f"echo:{msg}")

    server = serve(handler, "127.0.0.1", 0)
    th = threading.Thread(target=server.serve_forever, daemon=True)
    th.start()
    server.port = server.socket.getsockname()[1]
    server.state = state
    yield server
    server.shutdown()
    th.join(2)


def test_websocket_messages_json_and_timeout(ws_server):
    with WebSocketTransport(f"ws://127.0.0.1:{ws_server.port}/v6.json", timeout=1.0) as ws:
        ws.send("hi")
        assert ws.recv() == "echo:hi"
        with pytest.raises(TransportTimeout):
            ws.recv(timeout=0.05)
        ws.send_json({"a": 1})
        with pytest.raises(DataError) as e:  # "echo:{...}" is not JSON
            ws.recv_json()
        assert "not JSON" in e.value.message


def test_websocket_reconnects_after_the_server_drops_the_client(ws_server):
    ws = WebSocketTransport(f"ws://127.0.0.1:{ws_server.port}/", timeout=1.0)
    ws.open()
    ws.send("a")
    assert ws.recv() == "echo:a"
    ws_server.state["conns"][0].close()
    with pytest.raises(TransportClosed):
        ws.recv(timeout=1.0)
    assert not ws.is_open
    ws.reconnect()
    ws.send("b")
    assert ws.recv() == "echo:b" and ws_server.state["count"] == 2
    ws.close()


def test_websocket_unreachable_is_a_device_error():
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    with pytest.raises(TransportClosed) as e:
        WebSocketTransport(f"ws://127.0.0.1:{port}/", open_timeout=0.5).open()
    assert f"127.0.0.1:{port}" in e.value.message and e.value.fix


def test_websocket_without_websockets_names_the_extra(monkeypatch):
    for m in [m for m in sys.modules if m == "websockets" or m.startswith("websockets.")]:
        monkeypatch.delitem(sys.modules, m)
    monkeypatch.setitem(sys.modules, "websockets", None)
    with pytest.raises(MissingExtraError) as e:
        WebSocketTransport("ws://127.0.0.1:1/").open()
    assert "weldcell[leap]" in e.value.fix
