"""Property-based fuzzing of a robot's safety gate against an independent dense checker.

:func:`fuzz_robot` sends random and adversarial commands (malformed matrices, NaN/inf, huge targets,
scaled/sheared/mirrored rotations, negative durations, rotation-heavy twists, near-singular wrist lines,
random joint sweeps, bad blends) through a robot's **public** API with the driver methods replaced by a
spy that records what would have been sent (nothing moves). Every recorded command is re-checked by
:class:`DenseChecker`, written independently of :mod:`weldcell.hal.safety`: dense sampling of the motion
the driver executes, forward kinematics, its own continuous joint tracking, box, joint limits and joint
speed. The result lists unsafe commands that reached the driver and exceptions other than
:class:`~weldcell.sdk.errors.SafetyError`; both must be empty.

Used by ``tests/hal/test_safety_fuzz.py`` and by :class:`weldcell.testing.conformance.RobotConformance`
(so every adapter inherits it). Needs ``hypothesis`` (the ``test`` extra).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp
from weldcell.sdk.errors import SafetyError

DRIVER = ("_move_linear", "_move_joint", "_follow_path", "_speed_linear")
RATE_TOL = 1.1  # the checker's finite differences may differ from a peak joint speed by this factor
BOX_TOL = 1e-9  # m


def _rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation close to identity (Newton residuals: angles well below pi)."""
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    sn = np.linalg.norm(v)
    if sn < 1e-12:
        return v
    ang = math.atan2(sn, (np.trace(R) - 1.0) / 2.0)
    return v * (ang / sn)


def _expm(v: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues)."""
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


class Unsafe(Exception):
    """An accepted command that the dense checker finds unsafe."""


@dataclass
class FuzzReport:
    """Outcome of a fuzzing run: counts per command kind and outcome, and every problem found."""

    counts: Counter = field(default_factory=Counter)
    unsafe: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    cases: list[dict] = field(default_factory=list)
    """Each unsafe command with the start joints and the driver call, to reproduce it."""

    def summary(self) -> str:
        kinds = sorted({k for k, _ in self.counts})
        rows = [
            f"{k}: {self.counts[(k, 'accepted')]} accepted, {self.counts[(k, 'refused')]} refused"
            for k in kinds
        ]
        return "; ".join(rows) + f"; unsafe {len(self.unsafe)}, non-gate exceptions {len(self.errors)}"


# --------------------------------------------------------------------------------------------- checker
class DenseChecker:
    """Independent check of one command as the driver received it, from a robot at rest at ``q0``.

    Executed motions modelled: ``_move_linear``/``_follow_path``: the TCP on straight lines with slerped
    orientation (box also checked for a controller interpolating the flange instead); ``_move_joint``:
    a straight line in joint space; ``_speed_linear``: the flange origin moving at ``v`` while the
    orientation turns at ``w`` for ``duration``. Joint speeds use the commanded TCP speed (linear), the
    duration (servo); the limit is the model's hardware limit capped by the cell's ``max_joint_speed``.
    """

    def __init__(self, robot: Any) -> None:
        self.robot = robot
        self.model = robot.gate.model
        self.limits = robot.gate.limits
        self.lo = np.asarray(self.limits.workspace_min, dtype=float)
        self.hi = np.asarray(self.limits.workspace_max, dtype=float)
        self.T_ft = np.asarray(robot.T_flange_tcp, dtype=float)
        if self.model is not None:
            hw = np.asarray(getattr(self.model, "joint_speed_limits", np.full(self.model.dof, np.inf)))
            self.vmax = np.minimum(hw, self.limits.max_joint_speed)
            self.jl = np.asarray(self.model.joint_limits, dtype=float)

    # -- basic facts ----------------------------------------------------------------------------
    def _box(self, P: np.ndarray, what: str) -> None:
        P = np.atleast_2d(P)
        bad = np.any((P < self.lo - BOX_TOL) | (P > self.hi + BOX_TOL), axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise Unsafe(f"{what}: TCP {np.round(P[i], 4).tolist()} outside the box (sample {i}/{len(P)})")

    @staticmethod
    def _rigid(T: Any, what: str) -> np.ndarray:
        A = np.asarray(T, dtype=float)
        if A.shape != (4, 4) or not np.all(np.isfinite(A)):
            raise Unsafe(f"{what}: not a finite 4x4 transform: shape {A.shape}")
        R = A[:3, :3]
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-5 or abs(np.linalg.det(R) - 1) > 1e-5:
            raise Unsafe(f"{what}: rotation is not rigid")
        if np.abs(A[3] - [0, 0, 0, 1]).max() > 1e-8:
            raise Unsafe(f"{what}: last row {A[3].tolist()}")
        return A

    @staticmethod
    def _pos(x: Any, what: str, cap: float, nonneg: bool = False) -> float:
        v = float(x)
        ok = math.isfinite(v) and (v >= 0 if nonneg else v > 0) and v <= cap * (1 + 1e-12)
        if not ok:
            raise Unsafe(f"{what} = {x!r} reached the driver (allowed: (0, {cap}])")
        return v

    def _limits(self, q: np.ndarray, what: str) -> None:
        if np.any(q < self.jl[:, 0] - 1e-7) or np.any(q > self.jl[:, 1] + 1e-7):
            raise Unsafe(f"{what}: joints {np.round(np.degrees(q), 1).tolist()} deg outside the limits")

    # -- continuous joint tracking (own implementation) ------------------------------------------
    def _newton(self, F: np.ndarray, q: np.ndarray) -> np.ndarray | None:
        m = self.model
        for _ in range(25):
            C, J = m.fk_jacobian(q) if hasattr(m, "fk_jacobian") else (m.fk(q), m.jacobian(q))
            e = np.concatenate([F[:3, 3] - C[:3, 3], _rotvec(F[:3, :3] @ C[:3, :3].T)])
            if np.abs(e).max() < 1e-9:
                return q
            dq = J.T @ np.linalg.solve(J @ J.T + 1e-14 * np.eye(6), e)
            if np.abs(dq).max() > 0.3:
                return None
            q = q + dq
        return None

    def _track(self, flange_at, q0: np.ndarray, n: int, rate_per_unit: float, what: str) -> np.ndarray:
        """Joints along ``flange_at(s)``, s in [0, 1], from ``q0``: a grid of ``n`` steps, each refined
        (bisection, depth 16) until the joints move less than 0.02 rad, or 0.005 rad where a joint runs
        above 70 % of its speed limit and its speed varies by over 1 % of the limit per step; limits
        and speed at every step."""
        q, slope, prev = q0, np.zeros_like(q0), None
        grid = np.linspace(0.0, 1.0, n + 1)
        for a, b in zip(grid[:-1], grid[1:], strict=True):
            stack = [(a, b, 0)]
            while stack:
                s0, s1, depth = stack.pop()
                qn = self._newton(flange_at(s1), q + slope * (s1 - s0))
                dq = np.inf if qn is None else float(np.abs(qn - q).max())
                fast = False
                if qn is not None:  # fast joints whose speed varies: resolve the peak
                    r = np.abs(qn - q) / (s1 - s0) * rate_per_unit
                    varies = prev is None or np.max(np.abs(r - prev) / self.vmax) > 0.01
                    fast = varies and np.any(r > 0.7 * self.vmax)
                if dq > 0.02 or (fast and dq > 0.005):
                    if depth >= 16:
                        raise Unsafe(f"{what}: the joints cannot follow the motion near s = {s1:.6f}")
                    mid = 0.5 * (s0 + s1)
                    stack += [(mid, s1, depth + 1), (s0, mid, depth + 1)]
                    continue
                self._limits(qn, f"{what} at s = {s1:.4f}")
                rate = np.abs(qn - q) / (s1 - s0) * rate_per_unit
                if np.any(rate > RATE_TOL * self.vmax):
                    j = int(np.argmax(rate / self.vmax))
                    raise Unsafe(
                        f"{what} at s = {s1:.4f}: joint {j + 1} at {np.degrees(rate[j]):.0f} deg/s "
                        f"(limit {np.degrees(self.vmax[j]):.0f})"
                    )
                slope, prev = (qn - q) / (s1 - s0), rate
                q = qn
        return q

    # -- commands ---------------------------------------------------------------------------------
    def linear(self, q0, T0_tcp, F1, speed, accel, what="linear move") -> np.ndarray:
        lim = self.limits
        speed = self._pos(speed, f"{what} speed", lim.max_linear_speed)
        self._pos(accel, f"{what} accel", lim.max_linear_accel)
        F1 = self._rigid(F1, f"{what} target")
        T1 = F1 @ self.T_ft
        F0 = T0_tcp @ np.linalg.inv(self.T_ft)
        p0, p1 = T0_tcp[:3, 3], T1[:3, 3]
        L = float(np.linalg.norm(p1 - p0))
        rot = Rotation.from_matrix(np.stack([T0_tcp[:3, :3], T1[:3, :3]]))
        ang = float((rot[0].inv() * rot[1]).magnitude())
        n = int(np.clip(max(L / 0.0005, ang / 0.002, 1), 200, 20000))  # positions: cheap, very dense
        s = np.linspace(0.0, 1.0, n + 1)
        self._box((1 - s)[:, None] * p0 + s[:, None] * p1, what)  # the TCP line
        fslerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([F0[:3, :3], F1[:3, :3]])))(s)
        f_line = (1 - s)[:, None] * F0[:3, 3] + s[:, None] * F1[:3, 3]
        self._box(f_line + fslerp.apply(self.T_ft[:3, 3]), f"{what} (flange-line controller)")
        if self.model is None or (L < 1e-12 and ang < 1e-12):
            return q0
        rv = (rot[0].inv() * rot[1]).as_rotvec()
        inv_ft = np.linalg.inv(self.T_ft)

        def flange_at(x: float) -> np.ndarray:
            T = np.eye(4)
            T[:3, :3] = T0_tcp[:3, :3] @ _expm(x * rv)
            T[:3, 3] = (1 - x) * p0 + x * p1
            return T @ inv_ft

        w = float(getattr(self.model, "max_tcp_rot_speed", lim.max_angular_speed))
        sdot = min(speed / L if L > 1e-12 else np.inf, w / ang if ang > 1e-12 else np.inf)
        return self._track(flange_at, q0, n, sdot, what)

    def joint(self, q0, q1, speed, accel, what="joint move") -> None:
        lim = self.limits
        speed = self._pos(speed, f"{what} speed", lim.max_joint_speed)
        self._pos(accel, f"{what} accel", lim.max_joint_accel)
        q1 = np.asarray(q1, dtype=float)
        if self.model is None:
            return
        if q1.shape != (self.model.dof,) or not np.all(np.isfinite(q1)):
            raise Unsafe(f"{what}: joint target {q1!r}")
        self._limits(q1, f"{what} target")
        if speed > np.min(self.model.joint_speed_limits) * (1 + 1e-12):
            raise Unsafe(f"{what}: speed {speed} over a joint's hardware limit")
        n = int(np.clip(np.abs(q1 - q0).max() / 0.001, 50, 4000))
        s = np.linspace(0.0, 1.0, n + 1)
        F = self.model.fk(q0[None] + s[:, None] * (q1 - q0)[None])
        self._box((F @ self.T_ft)[:, :3, 3], what)

    def servo(self, q0, F0, twist, accel, duration, what="velocity command") -> None:
        lim = self.limits
        tw = np.asarray(twist, dtype=float)
        if tw.shape != (6,) or not np.all(np.isfinite(tw)):
            raise Unsafe(f"{what}: twist {tw!r}")
        self._pos(accel, f"{what} accel", lim.max_linear_accel)
        duration = self._pos(duration, f"{what} duration", np.inf)
        v, w = tw[:3], tw[3:]
        r = F0[:3, :3] @ self.T_ft[:3, 3]
        tcp_v = v + np.cross(w, r)  # the TCP's velocity at the start
        if np.linalg.norm(tcp_v) > lim.max_linear_speed * (1 + 1e-9) or np.linalg.norm(
            w
        ) > lim.max_angular_speed * (1 + 1e-9):
            raise Unsafe(f"{what}: twist over the caps")
        ang = float(np.linalg.norm(w)) * duration
        span = (np.linalg.norm(v) + np.linalg.norm(w) * np.linalg.norm(r)) * duration
        n = int(np.clip(max(ang / 0.002, span / 0.0005, 1), 200, 20000))
        t = np.linspace(0.0, duration, n + 1)
        R = Rotation.from_rotvec(t[:, None] * w[None]) * Rotation.from_matrix(F0[:3, :3])
        P = F0[:3, 3][None] + t[:, None] * v[None] + R.apply(self.T_ft[:3, 3])
        self._box(P, what)
        speed = np.linalg.norm(v[None] + np.cross(w[None], R.apply(self.T_ft[:3, 3])), axis=1)
        if speed.max() > lim.max_linear_speed * (1 + 1e-6):
            raise Unsafe(f"{what}: the TCP reaches {speed.max():.4g} m/s (the tool swings round)")
        if self.model is None or (not np.any(v) and not np.any(w)):
            return

        def flange_at(x: float) -> np.ndarray:
            T = np.eye(4)
            T[:3, :3] = _expm(x * duration * w) @ F0[:3, :3]
            T[:3, 3] = F0[:3, 3] + x * duration * v
            return T

        n = int(np.clip(max(ang / 0.02, span / 0.004, 1), 5, 1500))
        self._track(flange_at, q0, n, 1.0 / duration, what)

    def path(self, q0, T0_tcp, poses, speed, accel, blend) -> None:
        b = float(blend)
        if not (math.isfinite(b) and b >= 0):
            raise Unsafe(f"path blend {blend!r} reached the driver")
        P = np.asarray(poses, dtype=float)
        if P.ndim != 3 or len(P) == 0:
            raise Unsafe(f"path of shape {P.shape}")
        T_prev, q = T0_tcp, q0
        for i, F in enumerate(P):
            q = self.linear(q, T_prev, F, speed, accel, f"path segment {i}")
            T_prev = self._rigid(F, f"path pose {i}") @ self.T_ft

    def check(self, call: tuple[str, dict], q0: np.ndarray, T0_flange: np.ndarray) -> None:
        """Raise :class:`Unsafe` when the recorded driver call is not safe from the state (q0, T0)."""
        name, a = call
        T0_tcp = T0_flange @ self.T_ft
        if name == "_move_linear":
            self.linear(q0, T0_tcp, a["T_base_flange"], a["speed"], a["accel"])
        elif name == "_move_joint":
            self.joint(q0, a["q"], a["speed"], a["accel"])
        elif name == "_speed_linear":
            self.servo(q0, T0_flange, a["twist"], a["accel"], a["duration"])
        elif name == "_follow_path":
            self.path(q0, T0_tcp, a["poses"], a["speed"], a["accel"], a["blend"])
        else:  # pragma: no cover
            raise Unsafe(f"unknown driver call {name}")


# ---------------------------------------------------------------------------------------- strategies
def _bad_number(data, st):
    return data.draw(st.sampled_from([0.0, -1e-3, -1.0, float("nan"), float("inf"), -float("inf"), 1e300]))


def _speed(data, st, cap: float, what: str):
    if data.draw(st.integers(0, 9), label=f"{what} kind") < 8:
        return data.draw(st.floats(cap * 1e-3, cap * 1.05), label=what)
    return _bad_number(data, st)


def _rotation(data, st, max_angle: float) -> np.ndarray:
    axis = np.array(data.draw(st.tuples(*[st.floats(-1, 1)] * 3), label="axis"))
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.0, 0.0, 1.0])
    ang = data.draw(st.floats(0.0, max_angle), label="angle")
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * ang).as_matrix()


def _offset(data, st) -> np.ndarray:
    d = np.array(data.draw(st.tuples(*[st.floats(-1, 1)] * 3), label="direction"))
    if np.linalg.norm(d) < 1e-3:
        d = np.array([1.0, 0.0, 0.0])
    mag = 10 ** data.draw(st.floats(-5, 5.5), label="log10 distance")  # 10 um .. 300 km
    return d / np.linalg.norm(d) * mag


def _target(data, st, T0: np.ndarray, scale: float, malformed: bool = True, max_rot: float = math.pi) -> Any:
    """A TCP target near (or very far from) ``T0``; one time in four malformed (when allowed)."""
    T = np.array(T0, dtype=float)
    if not malformed or data.draw(st.integers(0, 3), label="small move") > 0:
        d = np.array(data.draw(st.tuples(*[st.floats(-scale, scale)] * 3), label="offset"))
    else:
        d = _offset(data, st)
    T[:3, 3] += d
    rot_range = min(max_rot, data.draw(st.sampled_from([0.0, 0.05, 0.05, 0.5, math.pi]), label="rot range"))
    T[:3, :3] = _rotation(data, st, rot_range) @ T[:3, :3]
    if not malformed:
        return T
    kind = data.draw(st.integers(0, 29), label="malformed kind")
    if kind == 0:
        T[data.draw(st.integers(0, 3)), data.draw(st.integers(0, 3))] = data.draw(
            st.sampled_from([float("nan"), float("inf"), -float("inf")])
        )
    elif kind == 1:
        T[:3, :3] *= data.draw(st.floats(0.5, 2.0).filter(lambda k: abs(k - 1) > 1e-5), label="scale")
    elif kind == 2:
        T[0, 1] += data.draw(st.floats(1e-4, 0.5), label="shear")
    elif kind == 3:
        T[:3, 0] *= -1.0  # mirrored
    elif kind == 4:
        T[3] = data.draw(st.sampled_from([[0, 0, 0, 2], [0.1, 0, 0, 1], [0, 0, 0, 0], [np.nan, 0, 0, 1]]))
    elif kind == 5:
        return T[:3]  # 3x4
    elif kind == 6:
        return data.draw(st.sampled_from([[[1, 2], [3]], "pose", None, np.eye(3), np.ones((4, 4, 1))]))
    return T


def _command(data, st, robot, model, q0: np.ndarray, T0: np.ndarray):
    """One public call: (kind, callable)."""
    lim = robot.gate.limits
    kind = data.draw(st.sampled_from(["linear", "joint", "servo", "path"]), label="command")
    if kind == "linear":
        T = _target(data, st, T0, 0.3)
        sp, ac = (
            _speed(data, st, lim.max_linear_speed, "speed"),
            _speed(data, st, lim.max_linear_accel, "accel"),
        )
        return kind, lambda: robot.move_linear(T, speed=sp, accel=ac)
    if kind == "joint":
        dof = model.dof if model is not None else 6
        span = data.draw(st.sampled_from([0.02, 0.2, 0.5, 1.0, 2.0, 6.0]), label="sweep")
        dq = np.array(data.draw(st.lists(st.floats(-span, span), min_size=dof, max_size=dof), label="dq"))
        q = q0 + dq if model is not None else dq
        bad = data.draw(st.integers(0, 19), label="joint malformed")
        if bad == 0:
            q = q[:-1]
        elif bad == 1:
            q = q.copy()
            q[0] = float("nan")
        elif bad == 2:
            q = q.copy()
            q[-1] = float("inf")
        sp, ac = (
            _speed(data, st, lim.max_joint_speed, "jspeed"),
            _speed(data, st, lim.max_joint_accel, "jaccel"),
        )
        return kind, lambda: robot.move_joint(q, speed=sp, accel=ac)
    if kind == "servo":
        vmax, wmax = lim.max_linear_speed, lim.max_angular_speed
        v = np.array(data.draw(st.tuples(*[st.floats(-vmax, vmax)] * 3), label="v")) / math.sqrt(3.0)
        heavy = data.draw(st.booleans(), label="rotation heavy")
        wr = wmax if heavy else 0.1 * wmax
        w = np.array(data.draw(st.tuples(*[st.floats(-wr, wr)] * 3), label="w")) / math.sqrt(3.0)
        if heavy and data.draw(st.booleans(), label="rotation only"):
            v[:] = 0.0
        tw: Any = np.concatenate([v, w])
        if data.draw(st.integers(0, 9), label="twist malformed") == 0:
            tw = data.draw(st.sampled_from([[np.nan] * 6, [0, 0, 0, np.inf, 0, 0], [0.01] * 5, "fast"]))
        if data.draw(st.integers(0, 4), label="duration kind") == 0:
            du = _bad_number(data, st)
        else:
            du = 10 ** data.draw(st.floats(-4, 0.5), label="log10 duration")
        ac = _speed(data, st, lim.max_linear_accel, "accel")
        return kind, lambda: robot.speed_linear(tw, accel=ac, duration=du)
    k = data.draw(st.integers(1, 5), label="path length")
    bad = data.draw(st.integers(-1, 3 * k), label="malformed pose")
    poses = [_target(data, st, T0, 0.1, malformed=(i == bad), max_rot=0.5) for i in range(k)]
    try:
        P: Any = np.stack([np.asarray(p, dtype=float) for p in poses])
    except (TypeError, ValueError):
        P = poses
    blend = data.draw(
        st.one_of(st.floats(0.0, 0.05), st.sampled_from([-0.01, float("nan"), float("inf"), 1.0])),
        label="blend",
    )
    sp = _speed(data, st, lim.max_linear_speed, "speed")
    return kind, lambda: robot.follow_path(P, speed=sp, blend=blend)


def _singular_start(data, st, model) -> np.ndarray | None:
    """A start configuration with the wrist near its singularity (joint 5 of a 6-axis arm near 0)."""
    if model is None or model.dof != 6:
        return None
    q = np.array(model.home, dtype=float)
    q[4] = data.draw(st.floats(-0.03, 0.03), label="wrist angle")
    q[3] += data.draw(st.floats(-1.0, 1.0), label="q4")
    return q


# --------------------------------------------------------------------------------------------- runner
def fuzz_robot(
    robot: Any,
    max_examples: int = 100,
    *,
    vary_start: bool = False,
    set_joints=None,
    report: FuzzReport | None = None,
) -> FuzzReport:
    """Fuzz an **active** robot's public motion API; the driver methods are replaced by recorders for the
    duration (nothing moves). With ``vary_start`` and ``set_joints(q)`` (a callable that puts the robot at
    rest at ``q``, e.g. for a simulated robot), start configurations are drawn too, including ones near the
    wrist singularity. Returns the report; callers assert ``unsafe == [] and errors == []``."""
    from hypothesis import HealthCheck, Phase, given, settings
    from hypothesis import strategies as st

    report = report or FuzzReport()
    model = robot.gate.model
    checker = DenseChecker(robot)
    calls: list[tuple[str, dict]] = []
    saved = {name: robot.__dict__.get(name) for name in DRIVER}
    params = {
        "_move_linear": ("T_base_flange", "speed", "accel"),
        "_move_joint": ("q", "speed", "accel"),
        "_follow_path": ("poses", "speed", "accel", "blend"),
        "_speed_linear": ("twist", "accel", "duration"),
    }
    for name in DRIVER:

        def record(*a, _n=name, **k):
            calls.append((_n, {**dict(zip(params[_n], a, strict=False)), **k}))

        setattr(robot, name, record)
    home = None if model is None else np.array(robot.state().q, dtype=float)

    @settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        database=None,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    @given(data=st.data())
    def one(data):
        if vary_start and set_joints is not None and home is not None:
            q_start = (
                _singular_start(data, st, model)
                if data.draw(st.integers(0, 3), label="singular") == 0
                else None
            )
            if q_start is None:
                q_start = home + np.array(
                    data.draw(
                        st.lists(st.floats(-0.4, 0.4), min_size=model.dof, max_size=model.dof), label="q0"
                    )
                )
            q_start = np.clip(q_start, model.joint_limits[:, 0], model.joint_limits[:, 1])
            set_joints(q_start)
        st0 = robot.state()
        if np.any(st0.T_base_tcp[:3, 3] < checker.lo) or np.any(st0.T_base_tcp[:3, 3] > checker.hi):
            return  # a start outside the box: every motion is refused, nothing to learn
        kind, fn = _command(data, st, robot, model, st0.q, st0.T_base_tcp)
        calls.clear()
        try:
            fn()
        except SafetyError:
            report.counts[(kind, "refused")] += 1
            if calls:
                report.unsafe.append(f"{kind}: refused but {calls[0][0]} was called")
            return
        except Exception as e:  # noqa: BLE001 - what the fuzzer hunts for
            report.errors.append(f"{kind}: {type(e).__name__}: {e}")
            return
        report.counts[(kind, "accepted")] += 1
        for call in calls:
            try:
                checker.check(call, st0.q, st0.T_base_flange)
            except Unsafe as u:
                report.unsafe.append(f"{kind}: {u}")
                report.cases.append({"kind": kind, "q0": st0.q.tolist(), "call": call[0], "args": call[1]})
            except SafetyError as e:  # the checker's own IK says the end is unreachable
                report.unsafe.append(f"{kind}: the end is unreachable: {e.message}")

    try:
        one()
    finally:
        for name, orig in saved.items():
            if orig is None:
                robot.__dict__.pop(name, None)
            else:
                setattr(robot, name, orig)
    return report
