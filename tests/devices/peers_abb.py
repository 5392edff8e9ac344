"""Protocol-level peers of an ABB IRC5 controller on loopback: a Robot Web Services 1.0 HTTP server (HTTP
Digest login, ``-http-session-``/``ABBCX`` session cookies, JSON answers as RobotWare 6 sends them) and
an EGM UDP peer (EgmRobot feedback at 250 Hz, EgmSensor corrections), both fed by a simulated IRB 2600
that runs an emulation of the WeldcellServer RAPID module (plugins/abb/rapid/WeldcellServer.mod): the
PERS variables are parsed from the module file itself, so the adapter can only write what it declares.
"""

from __future__ import annotations

import hashlib
import json
import re
import secrets
import socket
import threading
import time
import urllib.parse
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
from abb_robot_client._egm_protobuf import egm_pb2
from weldcell.hal.kinematics import get_model
from weldcell.plugins.abb import RAPID_MODULE
from weldcell.plugins.abb import rapid_values as V
from weldcell.sdk.geometry import interpolate_poses, rotation_angle

REALM = "validusers@robapi.abb"
ERR_NOT_FOUND = -1073442816
ERR_NOT_ALLOWED = -1073445859
ERRNO_REACH = 1070  # what the emulated RAPID puts in wc_errno for an unreachable target
_PERS = re.compile(r"PERS\s+(\w+)\s+(\w+)(?:\{(\d+)\})?\s*:=\s*(.*?);", re.S)


def module_variables(text: str | None = None) -> dict[str, tuple[str, int | None, str]]:
    """PERS name -> (type, array size or None, initial value text) declared in a module (default:
    WeldcellServer.mod as shipped)."""
    text = RAPID_MODULE.read_text() if text is None else text
    return {m[2]: (m[1], int(m[3]) if m[3] else None, re.sub(r"\s+", "", m[4])) for m in _PERS.finditer(text)}


class SimController:
    """The controller: panel state, RAPID execution, PERS variables, and an arm moved by 'RAPID'."""

    def __init__(self, model: str = "abb-irb2600") -> None:
        self.model = get_model(model)
        self.lock = threading.RLock()
        self.q = np.array(self.model.home, dtype=float)
        self.ctrlstate = "motoron"
        self.opmode = "AUTO"
        self.execution = "stopped"
        self.decls = module_variables()
        self.vars = {k: v[2] for k, v in self.decls.items()}
        self.job = None
        self.egm_target: tuple[float, np.ndarray] | None = None
        self.egm_frame_offset = np.zeros(3)  # a misconfigured EGM frame (mm), for the frame check
        self.writes: list[tuple[str, str]] = []
        self.mci_running = False
        self.files: dict[str, bytes] = {}
        self.mastership: str | None = None
        self.loads: list[str] = []

    def unload(self) -> None:
        """A controller without the module: every WeldcellServer symbol is unknown."""
        with self.lock:
            self.decls, self.vars = {}, {}

    def loadmod(self, path: str, session: str) -> str | None:
        """RWS loadmod: needs RAPID mastership and stopped execution; declares the file's PERS variables."""
        if self.mastership != session:
            return "RAPID mastership is not held by this client"
        if self.execution != "stopped":
            return "RAPID execution is running"
        if path not in self.files:
            return f"file {path} not found"
        text = self.files[path].decode()
        if not re.search(r"^\s*MODULE\s+WeldcellServer\b", text, re.M):
            return "not a WeldcellServer module"
        with self.lock:
            self.decls = module_variables(text)
            self.vars = {k: v[2] for k, v in self.decls.items()}
            self.loads.append(path)
        return None

    # -- state seen by RWS and EGM -----------------------------------------------------------------
    def flange(self) -> np.ndarray:
        return self.model.fk(self.q)

    def num(self, name: str) -> float:
        return float(self.vars[name])

    def set_num(self, name: str, v: float) -> None:
        self.vars[name] = f"{v:g}"

    def write(self, name: str, value: str) -> str | None:
        """RWS write of a PERS variable: None when accepted, else the error text."""
        if name not in self.decls:
            return f"symbol {name} not found"
        typ, size, _ = self.decls[name]
        value = re.sub(r"\s+", "", value)
        try:
            parsed = V.parse_value(value)
        except Exception as e:  # noqa: BLE001 - reported to the client as RAPID would
            return f"value error: {e}"
        if size is not None and (not isinstance(parsed, list) or len(parsed) != size):
            return f"{name} is an array of {size}"
        if typ == "num" and not isinstance(parsed, (int, float)):
            return f"{name} is a num"
        with self.lock:
            self.writes.append((name, value))
            old = self.vars[name]
            self.vars[name] = value
            if name == "wc_stop" and value != old and self.execution == "running":
                self._trap_stop()
        return None

    # -- RAPID emulation ---------------------------------------------------------------------------
    def start(self) -> str | None:
        if self.opmode != "AUTO":
            return "start is not allowed in manual mode from RWS"
        if self.ctrlstate != "motoron":
            return "motors are off"
        with self.lock:
            self.execution = "running"
            self.job = None
            self.vars["wc_done"] = self.vars["wc_seq"]  # main(): wc_done := wc_seq
        return None

    def stop_program(self) -> None:
        with self.lock:
            self.execution = "stopped"
            self.job = None
            self.mci_running = False

    def emergency_stop(self) -> None:
        with self.lock:
            self.ctrlstate = "emergencystop"
        self.stop_program()

    def motors_off(self) -> None:
        with self.lock:
            self.ctrlstate = "motoroff"
        self.stop_program()

    def _trap_stop(self) -> None:
        self.job = None
        self.mci_running = False
        self.set_num("wc_status", 1)
        self.vars["wc_done"] = self.vars["wc_seq"]

    def _finish(self, status: int = 0, errno: int = 0) -> None:
        self.job = None
        self.mci_running = False
        self.set_num("wc_status", status)
        self.set_num("wc_errno", errno)
        self.vars["wc_done"] = self.vars["wc_seq"]

    def _begin(self) -> None:
        cmd = int(self.num("wc_cmd"))
        speed = V.parse_value(self.vars["wc_speed"])
        if cmd == 1:
            n = int(self.num("wc_n"))
            targets = [V.robtarget_to_T(t) for t in V.parse_value(self.vars["wc_path"])[:n]]
            self.job = {
                "cmd": 1,
                "targets": targets,
                "v": speed[0] / 1000.0,
                "w": np.radians(speed[1]),
                "T0": self.flange(),
                "s": 0.0,
            }
        elif cmd == 2:
            q1 = np.radians(V.parse_value(self.vars["wc_jtarget"])[0])
            qs = self.q + np.linspace(0, 1, 33)[:, None] * (q1 - self.q)
            path = float(
                np.sum(np.linalg.norm(np.diff([self.model.fk(x)[:3, 3] for x in qs], axis=0), axis=1))
            )
            self.job = {
                "cmd": 2,
                "q0": self.q.copy(),
                "q1": q1,
                "w": np.radians(speed[1]),
                "s": 0.0,
                "t_tcp": path / (speed[0] / 1000.0),
            }  # MoveAbsJ also obeys v_tcp
        elif cmd == 3:
            self.job = {"cmd": 3, "still": 0.0, "last": time.monotonic()}
            self.mci_running = True
            self.egm_target = None
        else:
            self._finish(2, -1)

    def tick(self, dt: float) -> None:
        with self.lock:
            if self.execution != "running":
                return
            if self.job is None and self.vars["wc_seq"] != self.vars["wc_done"]:
                self._begin()
            job = self.job
            if job is None:
                return
            if job["cmd"] == 1:
                self._tick_path(job, dt)
            elif job["cmd"] == 2:
                self._tick_joint(job, dt)
            else:
                self._tick_egm(job, dt)

    def _tick_path(self, job, dt: float) -> None:
        T0, T1 = job["T0"], job["targets"][0]
        dist = float(np.linalg.norm(T1[:3, 3] - T0[:3, 3]))
        ang = rotation_angle(T0[:3, :3].T @ T1[:3, :3])
        duration = max(dist / job["v"], ang / job["w"], 1e-9)
        job["s"] = min(1.0, job["s"] + dt / duration)
        T = interpolate_poses(T0, T1, np.array([job["s"]]))[0]
        try:
            self.q = self.model.ik(T, self.q)
        except Exception:  # noqa: BLE001 - RAPID stops with an error on an unreachable target
            self._finish(2, ERRNO_REACH)
            return
        if job["s"] >= 1.0:
            job["targets"].pop(0)
            job["T0"], job["s"] = T1, 0.0
            if not job["targets"]:
                self._finish()

    def _tick_joint(self, job, dt: float) -> None:
        dq = job["q1"] - job["q0"]
        duration = max(float(np.max(np.abs(dq))) / job["w"], job["t_tcp"], 1e-9)
        job["s"] = min(1.0, job["s"] + dt / duration)
        self.q = job["q0"] + job["s"] * dq
        if job["s"] >= 1.0:
            self._finish()

    def _tick_egm(self, job, dt: float) -> None:
        now = time.monotonic()
        if self.egm_target is None or now - self.egm_target[0] > 1.0:
            if now - job["last"] > 1.0:  # EGM's communication timeout
                self._finish(2, 50377)
            return
        job["last"] = self.egm_target[0]
        T = self.egm_target[1]
        moved = float(np.linalg.norm(T[:3, 3] - self.flange()[:3, 3]))
        try:
            self.q = self.model.ik(T, self.q)
        except Exception:  # noqa: BLE001
            self._finish(2, ERRNO_REACH)
            return
        job["still"] = job["still"] + dt if moved < 5e-4 else 0.0
        if job["still"] >= self.num("wc_egm_time"):
            self._finish()

    def on_sensor(self, msg) -> None:
        if msg.planned.HasField("cartesian"):
            c = msg.planned.cartesian
            T = V.T_from_abb(
                [c.pos.x, c.pos.y, c.pos.z], [c.orient.u0, c.orient.u1, c.orient.u2, c.orient.u3]
            )
            with self.lock:
                self.egm_target = (time.monotonic(), T)

    def feedback(self, seqno: int) -> bytes:
        with self.lock:
            q, T = self.q.copy(), self.flange()
            running, motors, mci = self.execution == "running", self.ctrlstate == "motoron", self.mci_running
        m = egm_pb2.EgmRobot()
        m.header.seqno = seqno
        m.header.tm = int(time.monotonic() * 1000) & 0xFFFFFFFF
        m.header.mtype = egm_pb2.EgmHeader.MSGTYPE_DATA
        m.feedBack.joints.joints.extend(np.degrees(q).tolist())
        p, quat = V.T_to_abb(T)
        p = p + self.egm_frame_offset
        m.feedBack.cartesian.pos.x, m.feedBack.cartesian.pos.y, m.feedBack.cartesian.pos.z = p.tolist()
        o = m.feedBack.cartesian.orient
        o.u0, o.u1, o.u2, o.u3 = quat.tolist()
        m.motorState.state = m.motorState.MOTORS_ON if motors else m.motorState.MOTORS_OFF
        m.mciState.state = m.mciState.MCI_RUNNING if mci else m.mciState.MCI_STOPPED
        m.rapidExecState.state = m.rapidExecState.RAPID_RUNNING if running else m.rapidExecState.RAPID_STOPPED
        return m.SerializeToString()


class EgmPeer:
    """The controller's EGM side: EgmRobot to the PC's UDP port at ``rate`` Hz while RAPID runs."""

    def __init__(self, ctrl: SimController, pc_port: int, rate: float = 250.0) -> None:
        self.ctrl, self.pc = ctrl, ("127.0.0.1", pc_port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.period = 1.0 / rate
        self.sent = 0
        self.corrections = 0
        self.paused = False
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        nxt = time.monotonic()
        while not self._stop.is_set():
            nxt += self.period
            self.ctrl.tick(self.period)
            while True:
                try:
                    buf = self.sock.recv(65536)
                except (BlockingIOError, OSError):
                    break
                msg = egm_pb2.EgmSensor()
                msg.ParseFromString(buf)
                self.corrections += 1
                self.ctrl.on_sensor(msg)
            if self.ctrl.execution == "running" and not self.paused:
                self.sent += 1
                try:
                    self.sock.sendto(self.ctrl.feedback(self.sent), self.pc)
                except OSError:
                    pass
            time.sleep(max(0.0, nxt - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        self.thread.join(timeout=1.0)
        self.sock.close()


class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True  # header and body in one segment: no 40 ms delayed-ACK stalls
    wbufsize = 65536
    server: _RwsServer

    def log_message(self, *a) -> None:  # quiet
        pass

    def _send(self, code: int, body: dict | None = None, headers: dict | None = None) -> None:
        data = b"" if body is None else json.dumps(body).encode()
        self.send_response(code)
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        if body is not None:
            self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        self.wfile.write(data)

    def _error(self, code: int, err: int, msg: str) -> None:
        self._send(code, {"_embedded": {"status": {"code": err, "msg": msg}}})

    def _state(self, **fields) -> None:
        self._send(200, {"_links": {}, "_embedded": {"_state": [fields]}})

    def _cookies(self) -> dict[str, str]:
        cookies = {}
        for part in (self.headers.get("Cookie") or "").split(";"):
            if "=" in part:
                k, v = part.strip().split("=", 1)
                cookies[k] = v
        return cookies

    def _session_id(self) -> str:
        new = [c.split(";")[0].split("=", 1)[1] for c in self._new_cookies if c.startswith("-http-session-")]
        return new[0] if new else self._cookies().get("-http-session-", "")

    def _authorized(self) -> bool:
        srv = self.server
        if self._cookies().get("-http-session-") in srv.sessions:
            return True
        auth = self.headers.get("Authorization") or ""
        if auth.startswith("Digest ") and srv.check_digest(self.command, auth[7:]):
            sid, abbcx = secrets.token_hex(8), secrets.token_hex(4)
            srv.sessions.add(sid)
            srv.logins += 1
            self._new_cookies = [f"-http-session-={sid}; Path=/; httponly", f"ABBCX={abbcx}; Path=/"]
            return True
        nonce = secrets.token_hex(16)
        srv.nonces.add(nonce)
        srv.challenges += 1
        page = b"<html><body>401 Unauthorized</body></html>"
        self.send_response(401)
        self.send_header(
            "WWW-Authenticate",
            f'Digest realm="{REALM}", domain="/", qop="auth", nonce="{nonce}", algorithm=MD5, stale=FALSE',
        )
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(page)))
        self.end_headers()
        self.wfile.write(page)
        return False

    def _dispatch(self) -> None:
        self._new_cookies: list[str] = []
        length = int(self.headers.get("Content-Length") or 0)
        raw = self.rfile.read(length) if length else b""
        body = raw.decode(errors="replace")
        srv = self.server
        if srv.offline:
            self.close_connection = True
            self.connection.shutdown(socket.SHUT_RDWR)
            return
        if not self._authorized():
            return
        url = urllib.parse.urlsplit(self.path)
        q = {k: v[0] for k, v in urllib.parse.parse_qs(url.query).items()}
        form = {k: v[0] for k, v in urllib.parse.parse_qs(body).items()}
        srv.requests.append((self.command, url.path, q.get("action")))
        if self.command == "PUT" and url.path.startswith("/fileservice/"):
            srv.ctrl.files[urllib.parse.unquote(url.path[len("/fileservice/") :])] = raw
            return self._send(201)
        self.session = self._session_id()
        if q.get("json") != "1":
            self._error(400, ERR_NOT_ALLOWED, "this peer only answers json=1")
            return
        srv.route(self, self.command, url.path.strip("/"), q, form)

    def end_headers(self) -> None:
        for c in getattr(self, "_new_cookies", []):
            self.send_header("Set-Cookie", c)
        self._new_cookies = []
        super().end_headers()

    do_GET = _dispatch
    do_POST = _dispatch
    do_PUT = _dispatch


class _RwsServer(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, ctrl: SimController, user: str, password: str) -> None:
        super().__init__(("127.0.0.1", 0), _Handler)
        self.ctrl, self.user, self.password = ctrl, user, password
        self.sessions: set[str] = set()
        self.nonces: set[str] = set()
        self.logins = self.challenges = 0
        self.requests: list[tuple[str, str, str | None]] = []
        self.offline = False

    def check_digest(self, method: str, header: str) -> bool:
        f = dict(re.findall(r'(\w+)="?([^",]*)"?', header))
        if f.get("username") != self.user or f.get("nonce") not in self.nonces:
            return False

        def h(s: str) -> str:
            return hashlib.md5(s.encode()).hexdigest()

        ha1 = h(f"{self.user}:{REALM}:{self.password}")
        ha2 = h(f"{method}:{f.get('uri')}")
        want = h(f"{ha1}:{f['nonce']}:{f.get('nc')}:{f.get('cnonce')}:{f.get('qop')}:{ha2}")
        return secrets.compare_digest(want, f.get("response", ""))

    def route(self, r: _Handler, method: str, path: str, q: dict, form: dict) -> None:  # noqa: C901
        c = self.ctrl
        sym = "rw/rapid/symbol/data/RAPID/T_ROB1/WeldcellServer/"
        if method == "GET" and path == "rw/panel/ctrlstate":
            return r._state(_type="pnl-ctrlstate", ctrlstate=c.ctrlstate)
        if method == "GET" and path == "rw/panel/opmode":
            return r._state(_type="pnl-opmode", opmode=c.opmode)
        if method == "GET" and path == "rw/rapid/execution":
            return r._state(_type="rap-execution", ctrlexecstate=c.execution, cycle="forever")
        if method == "GET" and path == "rw/rapid/tasks":
            task = {
                "_type": "rap-task-li",
                "name": "T_ROB1",
                "type": "normal",
                "taskstate": "started",
                "excstate": "started" if c.execution == "running" else "ready",
                "active": "On",
                "motiontask": "TRUE",
            }
            return r._send(200, {"_embedded": {"_state": [task]}})
        if method == "GET" and path == "rw/motionsystem/mechunits/ROB_1/jointtarget":
            with c.lock:
                d = np.degrees(c.q)
            return r._state(
                _type="ms-jointtarget",
                **{f"rax_{i + 1}": f"{d[i]:.6f}" for i in range(6)},
                **{f"eax_{a}": "9E+09" for a in "abcdef"},
            )
        if method == "GET" and path == "rw/motionsystem/mechunits/ROB_1/robtarget":
            if (q.get("tool"), q.get("wobj"), q.get("coordinate")) != ("tool0", "wobj0", "Base"):
                return r._error(400, ERR_NOT_ALLOWED, "peer serves tool0/wobj0/Base only")
            with c.lock:
                p, quat = V.T_to_abb(c.flange())
            return r._state(
                _type="ms-robtargets",
                x=f"{p[0]:.4f}",
                y=f"{p[1]:.4f}",
                z=f"{p[2]:.4f}",
                q1=f"{quat[0]:.8f}",
                q2=f"{quat[1]:.8f}",
                q3=f"{quat[2]:.8f}",
                q4=f"{quat[3]:.8f}",
                cf1="0",
                cf4="0",
                cf6="0",
                cfx="0",
                **{f"eax{a}": "9E+09" for a in "abcdef"},
            )
        if path.startswith(sym):
            name = path[len(sym) :]
            if method == "GET":
                if name not in c.vars:
                    return r._error(400, ERR_NOT_FOUND, f"symbol {name} not found")
                with c.lock:
                    return r._state(_type="rap-data", value=c.vars[name])
            if q.get("action") == "set":
                err = c.write(name, form.get("value", ""))
                return r._send(204) if err is None else r._error(400, ERR_NOT_FOUND, err)
        if method == "POST" and path == "rw/mastership/rapid":
            if q.get("action") == "request":
                if c.mastership not in (None, r.session):
                    return r._error(400, ERR_NOT_ALLOWED, "mastership held by another client")
                c.mastership = r.session
                return r._send(204)
            if q.get("action") == "release":
                c.mastership = None
                return r._send(204)
        if method == "POST" and path == "rw/rapid/tasks/T_ROB1" and q.get("action") == "loadmod":
            if form.get("replace") != "true":
                return r._error(400, ERR_NOT_ALLOWED, "module exists: replace=true needed")
            err = c.loadmod(form.get("modulepath", ""), r.session)
            return r._send(204) if err is None else r._error(400, ERR_NOT_ALLOWED, err)
        if method == "POST" and path == "rw/rapid/execution":
            action = q.get("action")
            if action == "start":
                err = c.start()
                return r._send(204) if err is None else r._error(400, ERR_NOT_ALLOWED, err)
            if action == "stop":
                c.stop_program()
                return r._send(204)
            if action == "resetpp":
                return r._send(204) if c.execution == "stopped" else r._error(400, ERR_NOT_ALLOWED, "running")
        if method == "POST" and path == "rw/rapid/tasks/T_ROB1" and q.get("action") in ("activate",):
            return r._send(204)
        if method == "POST" and path == "rw/panel/ctrlstate" and q.get("action") == "setctrlstate":
            if c.opmode != "AUTO" or c.ctrlstate not in ("motoroff", "emergencystopreset", "motoron"):
                return r._error(400, ERR_NOT_ALLOWED, f"cannot switch motors on in {c.ctrlstate}/{c.opmode}")
            c.ctrlstate = form.get("ctrl-state", c.ctrlstate)
            return r._send(204)
        if method == "GET" and path == "logout":
            return r._send(204)
        return r._error(404, ERR_NOT_FOUND, f"no resource {method} {path}")


class AbbPeer:
    """A simulated IRC5: RWS on http://127.0.0.1:<port>, EGM to the PC's UDP port."""

    def __init__(self, pc_egm_port: int, user: str = "Default User", password: str = "robotics") -> None:
        self.ctrl = SimController()
        self.rws = _RwsServer(self.ctrl, user, password)
        self.url = f"http://127.0.0.1:{self.rws.server_address[1]}"
        self._http = threading.Thread(
            target=self.rws.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True
        )
        self._http.start()
        self.egm = EgmPeer(self.ctrl, pc_egm_port)

    def reset(self) -> None:
        c = self.ctrl
        with c.lock:
            c.q = np.array(c.model.home, dtype=float)
            c.ctrlstate, c.opmode, c.job, c.mci_running = "motoron", "AUTO", None, False
            c.egm_frame_offset = np.zeros(3)
            c.writes.clear()
            c.decls = module_variables()
            c.vars = {k: v[2] for k, v in c.decls.items()}
            c.mastership = None
        c.stop_program()
        self.rws.offline = False
        self.egm.paused = False

    def drop_sessions(self) -> None:
        """A controller restart: every session cookie and nonce becomes invalid."""
        self.rws.sessions.clear()
        self.rws.nonces.clear()

    def close(self) -> None:
        self.egm.close()
        self.rws.shutdown()
        self.rws.server_close()


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port
