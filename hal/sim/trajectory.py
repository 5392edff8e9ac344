"""The simulated robot's timed trajectory: where the flange was at any past simulated time.

:class:`~weldcell.hal.sim.devices.SimRobot` executes a motion at once and advances the simulated clock
by the motion time; it also appends the motion here as a timed segment. Sensors that sample while the
robot moves (the 1.5 kHz laser displacement sensor, an EGM-like 250 Hz pose stream) ask
:meth:`TimedTrajectory.poses` for the flange pose at their own sample times.

* a linear move follows the straight TCP line with the trapezoidal speed profile of
  :meth:`RobotModel.linear_move_time` (translation along the line, slerp for the rotation, both on the
  same normalised profile);
* a joint move follows the synchronised joint-space trapezoid of :meth:`RobotModel.sample_joint_move`;
* between motions the flange rests where the last motion ended.

Velocity-servo motions (``speed_linear``) and the true joint zero offsets (``q_error``) are not
recorded in linear segments: a query after the last segment returns the pose the robot holds now.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from weldcell.hal.kinematics import trapezoid_position, trapezoid_time
from weldcell.sdk.geometry import interpolate_poses, rotation_angle


@dataclass(frozen=True)
class Segment:
    """One motion: ``t0`` start (s, simulated clock), ``duration`` (s), and how to pose it."""

    t0: float
    duration: float
    kind: str  # "linear" | "joint"
    T0: np.ndarray
    T1: np.ndarray
    q0: np.ndarray | None = None
    q1: np.ndarray | None = None
    speed: float = 0.0
    accel: float = 0.0

    @property
    def t1(self) -> float:
        return self.t0 + self.duration


class TimedTrajectory:
    """Timed flange segments of one simulated robot (base frame), queried at arbitrary times."""

    def __init__(self, fk: Callable[[np.ndarray], np.ndarray], now: Callable[[], np.ndarray]) -> None:
        self._fk = fk
        self._now = now
        self.segments: list[Segment] = []

    def add_linear(self, t0: float, duration: float, T0, T1, speed: float, accel: float) -> None:
        """Record a straight-line flange move ``T0 -> T1`` that starts at ``t0`` and lasts ``duration``."""
        self.segments.append(
            Segment(
                float(t0),
                float(duration),
                "linear",
                np.array(T0, float),
                np.array(T1, float),
                speed=float(speed),
                accel=float(accel),
            )
        )

    def add_joint(self, t0: float, duration: float, q0, q1) -> None:
        """Record a synchronised joint move ``q0 -> q1``."""
        q0, q1 = np.array(q0, float), np.array(q1, float)
        self.segments.append(Segment(float(t0), float(duration), "joint", self._fk(q0), self._fk(q1), q0, q1))

    @property
    def end_time(self) -> float:
        return self.segments[-1].t1 if self.segments else 0.0

    def poses(self, t: np.ndarray) -> np.ndarray:
        """Flange poses (N, 4, 4) at simulated times ``t`` (N,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.tile(self._now(), (len(t), 1, 1))
        if not self.segments:
            return out
        starts = np.array([s.t0 for s in self.segments])
        idx = np.searchsorted(starts, t, side="right") - 1
        first = self.segments[0]
        before = idx < 0
        out[before] = first.T0
        for k in np.unique(idx[~before]):
            seg = self.segments[int(k)]
            sel = idx == k
            out[sel] = self._segment_poses(seg, t[sel])
        return out

    def _segment_poses(self, seg: Segment, t: np.ndarray) -> np.ndarray:
        tau = np.clip(t - seg.t0, 0.0, seg.duration)
        if seg.duration <= 0:
            return np.tile(seg.T1, (len(t), 1, 1))
        if seg.kind == "joint":
            s = _profile(tau, seg.duration)
            return np.asarray(self._fk(seg.q0[None] + s[:, None] * (seg.q1 - seg.q0)[None])).reshape(-1, 4, 4)
        L = float(np.linalg.norm(seg.T1[:3, 3] - seg.T0[:3, 3]))
        if L > 1e-9 and float(trapezoid_time(L, seg.speed, seg.accel)) >= seg.duration - 1e-9:
            s = trapezoid_position(tau, L, seg.speed, seg.accel) / L  # translation decides the timing
        else:
            s = _profile(tau, seg.duration)  # rotation decides: the same shape, stretched to the duration
        return interpolate_poses(seg.T0, seg.T1, s)


def _profile(tau: np.ndarray, duration: float) -> np.ndarray:
    """A normalised rest-to-rest trapezoid (1/4 ramp up, 1/2 cruise, 1/4 ramp down) lasting ``duration``."""
    v = 1.0 / (0.75 * duration)  # area of the trapezoid = 1
    a = v / (0.25 * duration)
    return np.clip(trapezoid_position(tau, 1.0, v, a), 0.0, 1.0)


def linear_duration(T0: np.ndarray, T1: np.ndarray, speed: float, accel: float, rot_speed: float) -> float:
    """The duration of a linear move as :meth:`RobotModel.linear_move_time` computes it (for planners)."""
    L = float(np.linalg.norm(np.asarray(T1)[:3, 3] - np.asarray(T0)[:3, 3]))
    th = rotation_angle(np.asarray(T0)[:3, :3].T @ np.asarray(T1)[:3, :3])
    return float(
        max(trapezoid_time(L, speed, accel), trapezoid_time(th, rot_speed, accel * rot_speed / speed))
    )


class SimPoseStream:
    """A robot's streamed flange pose (EGM-like, ``rate`` Hz on the simulated clock).

    ``read()`` returns every sample since the last call: stamps (N,) and ``T_base_flange`` (N, 4, 4), the
    poses the robot *reports* (the coupling error of a carried sensor is not in them).
    """

    def __init__(self, robot, rate: float = 250.0) -> None:
        self.robot = robot
        self.rate = float(rate)
        self._next_k: int | None = None

    def start(self) -> None:
        self._next_k = int(np.ceil(self.robot.world.clock.t * self.rate - 1e-9))

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        if self._next_k is None:
            self.start()
        k = np.arange(self._next_k, int(np.floor(self.robot.world.clock.t * self.rate + 1e-9)) + 1)
        if len(k):
            self._next_k = int(k[-1]) + 1
        t = k / self.rate
        return t, self.robot.timed.poses(t) if len(t) else np.zeros((0, 4, 4))

    def stop(self) -> None:
        self._next_k = None
