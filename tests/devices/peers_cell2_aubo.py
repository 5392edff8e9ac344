"""A simulated AUBO ARCS controller: the robot (kinematic AUBO i5), a JSON-RPC/TCP server that the real
``pyaubo_sdk.RpcClient`` talks to, and an in-process fake of the ``pyaubo_sdk`` classes.

Wire format (observed from pyaubo-sdk 0.24 against this peer): every frame is ``b"SOF\\x01"`` + a 4-byte
big-endian length + a JSON-RPC 2.0 body, e.g. ``{"id": "...", "jsonrpc": "2.0", "method":
"rob1.MotionControl.moveLine", "params": {"pose": [...], "a": 1.2, "v": 0.25, "blend_radius": 0.0,
"duration": 0.0}}``; the login frame is plain text ``__login__\\n<user>\\n<hash>\\n<version>\\n``.
Run ``python peers_cell2_aubo.py`` to serve on a free port (printed on stdout). The SDK holds the GIL while
it waits for a reply, so the server must live in another process. ``__peer__.drop`` closes every other
client connection; ``__peer__.set`` changes the simulated robot (tests' fault injection).
"""

from __future__ import annotations

import json
import socket
import struct
import sys
import threading
import time
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parent))

from weldcell.hal.kinematics import get_model  # noqa: E402
from weldcell.sdk.geometry import T_from_rotvec, T_from_rpy, T_to_rpy, interpolate_poses  # noqa: E402

#: enums travel as their names (``"Running"``, ``"ProtectiveStop"``), as pyaubo-sdk 0.24 decodes them
#: positional argument names of the pyaubo_sdk methods (as the SDK names them on the wire)
PARAMS = {
    "MotionControl.moveLine": ("pose", "a", "v", "blend_radius", "duration"),
    "MotionControl.moveJoint": ("q", "a", "v", "blend_radius", "duration"),
    "MotionControl.speedLine": ("xd", "a", "t"),
    "MotionControl.stopLine": ("acc", "acc_rot"),
    "MotionControl.stopJoint": ("acc",),
    "MotionControl.getExecId": (),
    "MotionControl.setSpeedFraction": ("fraction",),
    "RobotState.getTcpPose": (),
    "RobotState.getJointPositions": (),
    "RobotState.getRobotModeType": (),
    "RobotState.getSafetyModeType": (),
    "RobotState.isSteady": (),
    "RobotConfig.getTcpOffset": (),
    "RobotManage.setUnlockProtectiveStop": (),
}


class AuboSim:
    """The controller's robot: joints, active TCP offset, queued motions with real durations."""

    def __init__(self, tcp_offset=(0.0, 0.0, 0.1, 0.0, 0.0, 0.3), max_motion_time: float = 0.15) -> None:
        self.model = get_model("aubo-i5")
        self.q = self.model.home.copy()
        self.tcp_offset = list(tcp_offset)
        self.robot_mode = "Running"
        self.safety = "Normal"
        self.max_motion_time = max_motion_time
        self.queue: list[tuple[int, float, np.ndarray]] = []  # (exec id, end time, final q)
        self.next_id = 1
        self.log: list[tuple[str, dict]] = []
        self.lock = threading.RLock()

    # -- kinematics --------------------------------------------------------------------------------
    def T_ctrl(self, q) -> np.ndarray:
        o = self.tcp_offset
        return self.model.fk(q) @ T_from_rpy(o[3:], o[:3])

    def _settle(self) -> None:
        now = time.monotonic()
        while self.queue and self.queue[0][1] <= now:
            _, _, self.q = self.queue.pop(0)

    def _enqueue(self, q_final: np.ndarray, seconds: float) -> int:
        start = self.queue[-1][1] if self.queue else time.monotonic()
        eid = self.next_id
        self.next_id += 1
        self.queue.append((eid, start + min(seconds, self.max_motion_time), q_final))
        return eid

    def _q_last(self) -> np.ndarray:
        return self.queue[-1][2] if self.queue else self.q

    # -- the RPC methods ---------------------------------------------------------------------------
    def call(self, method: str, params: dict):
        with self.lock:
            self._settle()
            self.log.append((method, params))
            name = method.split(".")[-1]
            blocked = self.robot_mode != "Running" or self.safety != "Normal"
            if name in ("moveLine", "moveJoint", "speedLine") and blocked:
                return -13  # AUBO_BAD_STATE
            if method == "MotionControl.moveLine":
                p = np.asarray(params["pose"], dtype=float)
                o = self.tcp_offset
                T_flange = T_from_rpy(p[3:], p[:3]) @ np.linalg.inv(T_from_rpy(o[3:], o[:3]))
                q0 = self._q_last()
                start = self.T_ctrl(q0)
                q = q0
                for T in interpolate_poses(start, T_flange @ T_from_rpy(o[3:], o[:3]), np.linspace(0, 1, 6))[
                    1:
                ]:
                    q = self.model.ik(T @ np.linalg.inv(T_from_rpy(o[3:], o[:3])), q)
                dist = float(np.linalg.norm(start[:3, 3] - p[:3]))
                self._enqueue(q, dist / max(params["v"], 1e-6))
                return 0
            if method == "MotionControl.moveJoint":
                q = np.asarray(params["q"], dtype=float)
                self._enqueue(q, float(np.max(np.abs(q - self._q_last()))) / max(params["v"], 1e-6))
                return 0
            if method == "MotionControl.speedLine":
                xd, t = np.asarray(params["xd"], dtype=float), float(params["t"])
                T = self.T_ctrl(self._q_last())
                T_new = np.eye(4)
                T_new[:3, :3] = T_from_rotvec(xd[3:] * t)[:3, :3] @ T[:3, :3]
                T_new[:3, 3] = T[:3, 3] + xd[:3] * t
                o = self.tcp_offset
                self.queue.clear()
                self.q = self.model.ik(T_new @ np.linalg.inv(T_from_rpy(o[3:], o[:3])), self.q)
                return 0
            if name in ("stopLine", "stopJoint"):
                self.queue.clear()
                return 0
            if name == "getExecId":
                return self.queue[0][0] if self.queue else -1
            if name == "setSpeedFraction":
                return 0
            if name == "getTcpPose":
                T = self.T_ctrl(self.q)
                return [*T[:3, 3].tolist(), *T_to_rpy(T).tolist()]
            if name == "getJointPositions":
                return self.q.tolist()
            if name == "getRobotModeType":
                return self.robot_mode
            if name == "getSafetyModeType":
                return self.safety
            if name == "isSteady":
                return not self.queue
            if name == "getTcpOffset":
                return list(self.tcp_offset)
            if name == "setUnlockProtectiveStop":
                if self.safety in ("ProtectiveStop", "SafeguardStop"):
                    self.safety = "Normal"
                return 0
            raise KeyError(method)


# ------------------------------------------------------------------------------------ in-process fake
class _Part:
    def __init__(self, sim: AuboSim, cls: str, client: FakeRpcClient) -> None:
        self._sim, self._cls, self._client = sim, cls, client

    def __getattr__(self, name: str):
        key = f"{self._cls}.{name}"
        if key not in PARAMS:
            raise AttributeError(name)
        import pyaubo_sdk

        def method(*args):
            if not self._client.hasConnected():
                raise pyaubo_sdk.AuboException(f"{name}-RPC request timeout.")
            out = self._sim.call(key, dict(zip(PARAMS[key], args, strict=True)))
            if name == "getRobotModeType":
                return pyaubo_sdk.RobotModeType.__members__[out]
            if name == "getSafetyModeType":
                return pyaubo_sdk.SafetyModeType.__members__[out]
            return out

        return method


class FakeRobotInterface:
    def __init__(self, sim: AuboSim, client: FakeRpcClient) -> None:
        self._sim, self._client = sim, client

    def getMotionControl(self):  # noqa: N802 - pyaubo_sdk names
        return _Part(self._sim, "MotionControl", self._client)

    def getRobotState(self):  # noqa: N802
        return _Part(self._sim, "RobotState", self._client)

    def getRobotConfig(self):  # noqa: N802
        return _Part(self._sim, "RobotConfig", self._client)

    def getRobotManage(self):  # noqa: N802
        return _Part(self._sim, "RobotManage", self._client)


class FakeRpcClient:
    """Mirrors ``pyaubo_sdk.RpcClient``: connect/login/getRobotNames/getRobotInterface/... (in process)."""

    def __init__(self, sim: AuboSim, reachable: bool = True) -> None:
        self._sim, self._reachable = sim, reachable
        self._connected = self._logged = False
        self.timeout_ms = 0

    def setRequestTimeout(self, ms: int) -> int:  # noqa: N802
        self.timeout_ms = ms
        return 0

    def connect(self, ip: str, port: int) -> int:
        self._connected = self._reachable
        return 0 if self._connected else -8  # AUBO_CONN_REFUSED

    def hasConnected(self) -> bool:  # noqa: N802
        return self._connected

    def login(self, user: str, password: str) -> int:
        self._logged = self._connected and password == "aubo-test-pw"
        return 0 if self._logged else -1

    def hasLogined(self) -> bool:  # noqa: N802
        return self._logged

    def logout(self) -> int:
        self._logged = False
        return 0

    def disconnect(self) -> int:
        self._connected = self._logged = False
        return 0

    def getRobotNames(self) -> list[str]:  # noqa: N802
        return ["rob1"]

    def getRobotInterface(self, name: str) -> FakeRobotInterface:  # noqa: N802
        return FakeRobotInterface(self._sim, self)


# ---------------------------------------------------------------------------------------- TCP server
def _frame(obj) -> bytes:
    body = json.dumps(obj).encode()
    return b"SOF\x01" + struct.pack(">I", len(body)) + body


class AuboServer:
    """JSON-RPC over TCP, as the ARCS controller's port 30004."""

    def __init__(self, sim: AuboSim, host: str = "127.0.0.1", port: int = 0) -> None:
        self.sim = sim
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((host, port))
        self.sock.listen(8)
        self.port = self.sock.getsockname()[1]
        self.clients: list[socket.socket] = []

    def serve_forever(self) -> None:
        while True:
            c, _ = self.sock.accept()
            self.clients.append(c)
            threading.Thread(target=self._serve, args=(c,), daemon=True).start()

    def _reply(self, msg: dict):
        m = msg["method"]
        if m == "SystemInfo.getInterfaceVersionCode":
            return 24001
        if m == "getRobotNames":
            return ["rob1"]
        if m == "getAxisNames":
            return []
        if m == "__peer__.set":
            for k, v in msg.get("params", {}).items():
                setattr(self.sim, k, v)
            return 0
        if m == "__peer__.state":
            with self.sim.lock:
                return {"q": self.sim.q.tolist(), "log": [x[0] for x in self.sim.log]}
        robot, _, rest = m.partition(".")
        if robot != "rob1":
            raise KeyError(m)
        return self.sim.call(rest, msg.get("params") or {})

    def _serve(self, c: socket.socket) -> None:
        buf = b""
        try:
            while True:
                d = c.recv(65536)
                if not d:
                    return
                buf += d
                while len(buf) >= 8 and buf[:3] == b"SOF":
                    n = struct.unpack(">I", buf[4:8])[0]
                    if len(buf) < 8 + n:
                        break
                    body, buf = buf[8 : 8 + n], buf[8 + n :]
                    if body.startswith(b"__login__"):
                        c.sendall(_frame({"jsonrpc": "2.0", "result": 0}))
                        continue
                    msg = json.loads(body)
                    if msg["method"] == "__peer__.drop":
                        for other in list(self.clients):
                            if other is not c:
                                try:
                                    other.shutdown(socket.SHUT_RDWR)
                                    other.close()
                                except OSError:
                                    pass
                                self.clients.remove(other)
                        c.sendall(_frame({"id": msg["id"], "jsonrpc": "2.0", "result": 0}))
                        continue
                    try:
                        res = {"id": msg["id"], "jsonrpc": "2.0", "result": self._reply(msg)}
                    except KeyError as e:
                        res = {
                            "id": msg["id"],
                            "jsonrpc": "2.0",
                            "error": {"code": -32601, "message": f"Method not found: {e}"},
                        }
                    c.sendall(_frame(res))
        except OSError:
            return


def peer_request(port: int, method: str, params: dict | None = None, timeout: float = 2.0):
    """One JSON-RPC request to the peer from the test process (control channel)."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        msg = {"id": "ctl", "jsonrpc": "2.0", "method": method}
        if params:
            msg["params"] = params
        s.sendall(_frame(msg))
        head = b""
        while len(head) < 8:
            head += s.recv(8 - len(head))
        n = struct.unpack(">I", head[4:8])[0]
        body = b""
        while len(body) < n:
            body += s.recv(n - len(body))
        return json.loads(body)["result"]


if __name__ == "__main__":
    srv = AuboServer(AuboSim())
    print(srv.port, flush=True)
    srv.serve_forever()
