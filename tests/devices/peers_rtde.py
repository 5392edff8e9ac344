"""Protocol-level peers of a UR controller on this machine: an RTDE server (port 30004 protocol) and a
Dashboard server (port 29999 text protocol), both fed by a small simulated arm.

The RTDE server speaks the real protocol version 2 (see weldcell.plugins.ur.rtde_protocol) so the real
``rtde_receive.RTDEReceiveInterface`` and our own client can connect. Each peer binds a random
127.x.y.z address so the fixed UR ports are free for it.

ur_rtde's pybind11 calls block while holding the GIL, so a peer in the test's own process would
deadlock against it: :class:`PeerProcess` runs the arm and both servers in a child process and is
driven through a pipe.
"""

from __future__ import annotations

import multiprocessing as mp
import random
import socket
import struct
import threading
import time

import numpy as np
from weldcell.plugins.ur import rtde_protocol as P
from weldcell.sdk.geometry import T_to_ur_pose


def free_loopback_host(port: int) -> str:
    """A 127.x.y.z address where ``port`` can be bound (the UR ports are fixed in ur_rtde)."""
    for _ in range(50):
        host = f"127.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(2, 254)}"
        s = socket.socket()
        try:
            s.bind((host, port))
            return host
        except OSError:
            continue
        finally:
            s.close()
    raise RuntimeError("no free loopback address")


class SimArm:
    """The controller's state: joints, flange pose (TCP = flange), modes; moved by the fake control side."""

    def __init__(self, model) -> None:
        self.model = model
        self.lock = threading.Lock()
        self.q = np.array(model.home, dtype=float)
        self.qd = np.zeros(6)
        self.robot_mode = 7  # RUNNING
        self.safety_mode = 1  # NORMAL
        self.t0 = time.monotonic()

    def flange_pose(self) -> list[float]:
        with self.lock:
            return list(T_to_ur_pose(self.model.fk(self.q)))

    def set_q(self, q) -> None:
        with self.lock:
            self.q = np.asarray(q, dtype=float).copy()

    def protective_stop(self, on: bool = True) -> None:
        with self.lock:
            self.safety_mode = 3 if on else 1

    def values(self) -> dict[str, object]:
        with self.lock:
            q = self.q.copy()
            mode, smode = self.robot_mode, self.safety_mode
            qd = self.qd.copy()
        pose = list(T_to_ur_pose(self.model.fk(q)))
        bits = 1 if smode == 1 else 0
        if smode == 3:
            bits |= 1 << P.SAFETY_BIT_PROTECTIVE_STOPPED
        return {
            "timestamp": time.monotonic() - self.t0,
            "actual_q": tuple(q),
            "target_q": tuple(q),
            "actual_qd": tuple(qd),
            "actual_TCP_pose": tuple(pose),
            "target_TCP_pose": tuple(pose),
            "robot_mode": mode,
            "safety_mode": smode,
            "safety_status": smode,
            "safety_status_bits": bits,
            "runtime_state": 2,
            "speed_scaling": 1.0,
            "target_speed_fraction": 1.0,
            "robot_status_bits": 0b1111,
        }


def _zero(t: str):
    fmt = P.TYPE_FORMATS[t]
    if fmt[0].isdigit():
        return (False if fmt[-1] == "?" else 0,) * int(fmt[:-1])
    return False if fmt == "?" else 0


class RTDEPeer:
    """An RTDE server on ``host:port`` streaming ``arm.values()`` at the requested frequency."""

    def __init__(
        self, arm: SimArm, host: str | None = None, port: int = P.PORT, version=(5, 11, 1, 108)
    ) -> None:
        self.arm = arm
        self.port = port
        self.host = host or free_loopback_host(port)
        self.version = version
        self.setups: list[list[str]] = []
        self.accept_clients = True
        self.frozen = False
        self._clients: list[socket.socket] = []
        self._stop = threading.Event()
        self._srv = socket.create_server((self.host, self.port))
        self._srv.settimeout(0.1)
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    # -- control -------------------------------------------------------------------------------------
    def drop_clients(self) -> None:
        """Close every client connection (as a controller reboot or cable pull would)."""
        for c in list(self._clients):
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()
        self._clients.clear()

    def close(self) -> None:
        self._stop.set()
        self.drop_clients()
        self._thread.join(2)
        self._srv.close()

    # -- server --------------------------------------------------------------------------------------
    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._srv.accept()
            except (TimeoutError, OSError):
                continue
            if not self.accept_clients:
                conn.close()
                continue
            self._clients.append(conn)
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    @staticmethod
    def _recv_exact(conn: socket.socket, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = conn.recv(n - len(buf))
            if not chunk:
                raise ConnectionError("client closed")
            buf += chunk
        return buf

    def _client(self, conn: socket.socket) -> None:
        streaming = threading.Event()
        out: dict[str, object] = {"names": [], "types": [], "period": 1 / 125, "id": 1}
        send_lock = threading.Lock()

        def send(cmd: int, payload: bytes = b"") -> None:
            with send_lock:
                conn.sendall(P.pack(cmd, payload))

        def stream() -> None:
            nxt = time.monotonic()
            while not self._stop.is_set():
                if not streaming.is_set() or self.frozen:
                    time.sleep(0.002)
                    continue
                vals = self.arm.values()
                types = out["types"]
                names = out["names"]
                data = P.pack_values(
                    types, [vals.get(n, _zero(t)) for n, t in zip(names, types, strict=True)]
                )
                try:
                    send(P.DATA_PACKAGE, struct.pack(">B", out["id"]) + data)
                except OSError:
                    return
                nxt += out["period"]
                time.sleep(max(0.0, nxt - time.monotonic()))

        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        try:
            while not self._stop.is_set():
                size, cmd = P.HEADER.unpack(self._recv_exact(conn, P.HEADER.size))
                payload = self._recv_exact(conn, size - P.HEADER.size)
                if cmd == P.REQUEST_PROTOCOL_VERSION:
                    (ver,) = struct.unpack(">H", payload)
                    send(cmd, struct.pack(">B", 1 if ver in (1, 2) else 0))
                elif cmd == P.GET_URCONTROL_VERSION:
                    send(cmd, struct.pack(">IIII", *self.version))
                elif cmd == P.CONTROL_PACKAGE_SETUP_OUTPUTS:
                    (freq,) = struct.unpack(">d", payload[:8])
                    names = [n for n in payload[8:].decode().split(",") if n]
                    types = [P.variable_type(n) for n in names]
                    self.setups.append(names)
                    if "NOT_FOUND" not in types:
                        out.update(names=names, types=types, period=1.0 / max(1.0, min(freq, 500.0)))
                    send(
                        cmd,
                        struct.pack(">B", out["id"] if "NOT_FOUND" not in types else 0)
                        + ",".join(types).encode(),
                    )
                elif cmd == P.CONTROL_PACKAGE_SETUP_INPUTS:
                    names = [n for n in payload.decode().split(",") if n]
                    types = [P.variable_type(n) for n in names]
                    send(cmd, struct.pack(">B", 2) + ",".join(types).encode())
                elif cmd == P.CONTROL_PACKAGE_START:
                    ok = bool(out["types"])
                    if ok:
                        streaming.set()
                    send(cmd, struct.pack(">B", int(ok)))
                elif cmd == P.CONTROL_PACKAGE_PAUSE:
                    streaming.clear()
                    send(cmd, struct.pack(">B", 1))
                elif cmd == P.DATA_PACKAGE:
                    pass  # input registers: accepted, not used by the receive side
                else:
                    msg = f"unknown package type {cmd}".encode()
                    send(P.TEXT_MESSAGE, struct.pack(">B", len(msg)) + msg + b"\x04peer\x01")
        except (ConnectionError, OSError, struct.error):
            pass
        finally:
            streaming.clear()
            conn.close()


class DashboardPeer:
    """The Dashboard server's line protocol (port 29999): enough for popups and protective stops."""

    def __init__(self, arm: SimArm, host: str, port: int = 29999) -> None:
        self.arm = arm
        self.host, self.port = host, port
        self.commands: list[str] = []
        self._stop = threading.Event()
        self._srv = socket.create_server((host, port))
        self._srv.settimeout(0.1)
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self._srv.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._srv.accept()
            except (TimeoutError, OSError):
                continue
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn: socket.socket) -> None:
        with conn:
            conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
            f = conn.makefile("rb")
            for raw in f:
                cmd = raw.decode().strip()
                self.commands.append(cmd)
                if cmd == "close safety popup":
                    reply = "closing safety popup"
                elif cmd == "unlock protective stop":
                    if self.arm.safety_mode == 3:
                        self.arm.protective_stop(False)
                        reply = "Protective stop releasing"
                    else:
                        reply = (
                            "Cannot unlock protective stop until 5s after occurrence. Always inspect cause"
                        )
                elif cmd == "robotmode":
                    reply = f"Robotmode: {P.ROBOT_MODES[self.arm.robot_mode]}"
                elif cmd == "safetystatus":
                    reply = f"Safetystatus: {P.SAFETY_MODES[self.arm.safety_mode]}"
                elif cmd == "PolyscopeVersion":
                    reply = "URSoftware 5.11.1.108318 (Nov 12 2021)"
                elif cmd == "quit":
                    conn.sendall(b"Disconnected\n")
                    return
                else:
                    reply = f"could not understand: '{cmd}'"
                conn.sendall(reply.encode() + b"\n")


def _child(conn, model_name: str, host: str) -> None:
    from weldcell.hal.kinematics import get_model

    arm = SimArm(get_model(model_name))
    rtde = RTDEPeer(arm, host)
    dash = DashboardPeer(arm, host)
    conn.send(("ready", rtde.host))
    while True:
        try:
            cmd, arg = conn.recv()
        except EOFError:
            break
        if cmd == "close":
            break
        if cmd == "set_q":
            arm.set_q(arg)
            reply = None
        elif cmd == "get_q":
            reply = arm.q.tolist()
        elif cmd == "is_stopped":
            reply = arm.safety_mode != 1
        elif cmd == "protective_stop":
            arm.protective_stop(arg)
            reply = None
        elif cmd == "drop_clients":
            rtde.drop_clients()
            reply = None
        elif cmd == "freeze":
            rtde.frozen = bool(arg)
            reply = None
        elif cmd == "accept_clients":
            rtde.accept_clients = bool(arg)
            reply = None
        elif cmd == "dashboard_commands":
            reply = list(dash.commands)
        elif cmd == "setups":
            reply = list(rtde.setups)
        else:
            reply = ValueError(f"unknown peer command {cmd}")
        conn.send(reply)
    rtde.close()
    dash.close()
    conn.close()


class PeerProcess:
    """RTDE + Dashboard peers of a simulated ``model_name`` arm in a child process."""

    def __init__(self, model_name: str = "ur5") -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        host = free_loopback_host(P.PORT)
        self.model_name = model_name
        self._proc = ctx.Process(target=_child, args=(child, model_name, host), daemon=True)
        self._proc.start()
        if not self._conn.poll(30):
            self._proc.kill()
            raise RuntimeError("RTDE peer process did not start")
        _, self.host = self._conn.recv()
        self._lock = threading.Lock()

    def call(self, cmd: str, arg=None):
        with self._lock:
            self._conn.send((cmd, arg))
            reply = self._conn.recv()
        if isinstance(reply, Exception):
            raise reply
        return reply

    def alive(self) -> bool:
        return self._proc.is_alive()

    def close(self) -> None:
        try:
            with self._lock:
                self._conn.send(("close", None))
        except OSError:
            pass
        self._proc.join(5)
        if self._proc.is_alive():
            self._proc.kill()


class FakeRTDEControlInterface:
    """Stands in for ``rtde_control.RTDEControlInterface`` (which needs the controller's script ports).

    It simulates the arm with weldcell's kinematic model: moveL follows the straight line by IK in
    5 mm steps, moveJ goes to the joints, a moveL path runs waypoint by waypoint, speedL integrates the
    twist for its time; the new joints go to the peer process, whose RTDE stream reports them. Every call
    is recorded in ``calls``. A protective stop in the peer makes motions fail (return False).
    """

    FLAG_UPLOAD_SCRIPT = 1
    FLAG_USE_EXT_UR_CAP = 8
    peers: dict[str, PeerProcess] = {}
    calls: list[tuple] = []

    def __init__(
        self,
        hostname: str,
        frequency: float = -1.0,
        flags: int = 1,
        ur_cap_port: int = 50002,
        rt_priority: int = 0,
    ) -> None:
        if hostname not in self.peers:
            raise RuntimeError(f"Couldn't connect to {hostname}:30004 (no controller)")
        from weldcell.hal.kinematics import get_model

        self.peer = self.peers[hostname]
        self.model = get_model(self.peer.model_name)
        self.connected = True
        self.tcp = [0.0] * 6
        self.calls.append(("connect", hostname, frequency, flags, ur_cap_port))

    # -- connection --------------------------------------------------------------------------------
    def isConnected(self) -> bool:
        return self.connected and self.peer.alive()

    def disconnect(self) -> None:
        self.connected = False

    def reconnect(self) -> bool:
        self.connected = self.peer.alive()
        return self.connected

    def isProgramRunning(self) -> bool:
        return self.isConnected()

    def setTcp(self, pose) -> bool:
        self.calls.append(("setTcp", list(pose)))
        self.tcp = list(pose)
        return True

    # -- motion ------------------------------------------------------------------------------------
    def _q(self) -> np.ndarray:
        return np.asarray(self.peer.call("get_q"), dtype=float)

    def _stopped(self) -> bool:
        return bool(self.peer.call("is_stopped"))

    def _go_linear(self, pose) -> bool:
        from weldcell.sdk.geometry import T_from_ur_pose, invert

        T1 = T_from_ur_pose(pose) @ invert(T_from_ur_pose(self.tcp))
        q0 = self._q()
        T0 = self.model.fk(q0)
        qs = self.model.linear_path_joints(T0, T1, q0, step=0.005)
        self.peer.call("set_q", np.asarray(qs)[-1].tolist())
        return True

    def moveL(self, pose_or_path, speed: float = 0.25, acceleration: float = 1.2, asynchronous: bool = False):
        path = pose_or_path if isinstance(pose_or_path[0], list | tuple) else None
        if path is not None:
            self.calls.append(("moveL_path", [list(w) for w in path], speed))
            if self._stopped():
                return False
            return all(self._go_linear(w[:6]) for w in path)
        self.calls.append(("moveL", list(pose_or_path), speed, acceleration, asynchronous))
        if self._stopped():
            return False
        return self._go_linear(pose_or_path)

    def moveJ(self, q, speed: float = 1.05, acceleration: float = 1.4, asynchronous: bool = False) -> bool:
        self.calls.append(("moveJ", list(q), speed, acceleration, asynchronous))
        if self._stopped():
            return False
        self.peer.call("set_q", list(q))
        return True

    def speedL(self, xd, acceleration: float = 0.25, time: float = 0.0) -> bool:
        from scipy.spatial.transform import Rotation
        from weldcell.sdk.geometry import make_T

        self.calls.append(("speedL", list(xd), acceleration, time))
        if self._stopped():
            return False
        q0 = self._q()
        T0 = self.model.fk(q0)
        v, w = np.asarray(xd[:3]), np.asarray(xd[3:])
        T1 = make_T(Rotation.from_rotvec(w * time).as_matrix() @ T0[:3, :3], T0[:3, 3] + v * time)
        self.peer.call("set_q", self.model.ik(T1, q0).tolist())
        return True

    def stopL(self, a: float = 10.0, asynchronous: bool = False) -> None:
        self.calls.append(("stopL", a))

    def stopJ(self, a: float = 2.0, asynchronous: bool = False) -> None:
        self.calls.append(("stopJ", a))

    def triggerProtectiveStop(self) -> bool:
        self.peer.call("protective_stop", True)
        return True
