"""Acquisition (paper 002, §III-D): 1-D laser readings synchronised with the robot's streamed pose.

The sensor streams distances (1.5 kHz, time-stamped; out of range = no value) while the robot follows
the inspection plan line by line and streams its flange pose (EGM: 250 Hz). Each line's raw streams
are saved to the run folder at once (``inspection/line_NNNN.npz``: laser stamps and distances, pose
stamps and flange poses) and recorded in ``state.json``, so nothing captured is lost when a device
drops and ``--resume`` continues with the next line.

Synchronisation: every reading's stamp, minus the sensor-robot latency, is placed on the pose stream
by SE(3) interpolation (linear translation, slerp rotation between the bracketing poses); the point is
``T_base_flange(t) @ T_flange_sensor @ [0, 0, d]``. Readings outside the pose stream or inside one of
its gaps (a dropped stream) are discarded and counted; out-of-range readings stay gaps (NaN z), never
zeros. The latency is estimated from the plan's latency pass: the same line forward and back crosses
the same edges, which appear shifted by ``2 v latency`` when the latency is wrong.
"""

from __future__ import annotations

import io
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation
from weldcell.sdk import artifacts
from weldcell.sdk.errors import DataError, DeviceError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration, Frequency

RECORDING_SCHEMA = "weldcell/laser-recording@1"


class AcquisitionSettings(Settings):
    """Synchronising the laser with the robot's pose stream."""

    pose_rate: Frequency = Field(250.0, gt=0, description="rate of the robot's pose stream (EGM) [Hz]")
    latency: Duration | None = Field(
        None, description="sensor-robot latency [s]; default: estimated from the plan's latency pass"
    )
    max_pose_gap: Duration = Field(
        0.05, gt=0, description="a pose-stream gap longer than this drops the readings inside it [s]"
    )
    settle: Duration = Field(2.0, gt=0, description="how long to wait for a line's last readings [s]")


# ------------------------------------------------------------------------------------------- records
@dataclass
class LineRecord:
    """The raw streams of one inspection line (sensor and robot clocks, seconds)."""

    index: int
    kind: str
    t_start: float
    t_end: float
    laser_t: np.ndarray
    laser_d: np.ndarray
    pose_t: np.ndarray
    pose_T: np.ndarray

    def save(self, path: Path) -> Path:
        buf = io.BytesIO()
        np.savez(
            buf,
            index=self.index,
            kind=self.kind,
            t_range=np.array([self.t_start, self.t_end]),
            laser_t=self.laser_t,
            laser_d=self.laser_d,
            pose_t=self.pose_t,
            pose_T=self.pose_T,
        )
        return artifacts.write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: Path) -> LineRecord:
        with np.load(path) as z:
            return cls(
                int(z["index"]),
                str(z["kind"]),
                float(z["t_range"][0]),
                float(z["t_range"][1]),
                z["laser_t"],
                z["laser_d"],
                z["pose_t"],
                z["pose_T"],
            )


@dataclass
class Recording:
    """Every line of an inspection, the sensor's mount and the latency used (or None: estimate it)."""

    lines: list[LineRecord]
    T_flange_sensor: np.ndarray
    latency: float | None = None
    notes: dict = field(default_factory=dict)

    def streams(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """All laser (t, d) and pose (t, T) samples in time order, duplicates removed."""
        lt = np.concatenate([ln.laser_t for ln in self.lines]) if self.lines else np.zeros(0)
        ld = np.concatenate([ln.laser_d for ln in self.lines]) if self.lines else np.zeros(0)
        pt = np.concatenate([ln.pose_t for ln in self.lines]) if self.lines else np.zeros(0)
        pT = np.concatenate([ln.pose_T for ln in self.lines]) if self.lines else np.zeros((0, 4, 4))
        i = np.argsort(lt, kind="stable")
        j = np.argsort(pt, kind="stable")
        pt, pT = pt[j], pT[j]
        keep = np.r_[True, np.diff(pt) > 0] if len(pt) else np.zeros(0, bool)
        return lt[i], ld[i], pt[keep], pT[keep]

    def manifest(self) -> dict:
        return {
            "schema": RECORDING_SCHEMA,
            "T_flange_sensor": np.round(self.T_flange_sensor, 9).tolist(),
            "latency": self.latency,
            "lines": [
                {"index": ln.index, "kind": ln.kind, "file": line_file(ln.index), "t": [ln.t_start, ln.t_end]}
                for ln in self.lines
            ],
            **self.notes,
        }


def line_file(index: int) -> str:
    return f"inspection/line_{index:04d}.npz"


def load_recording(run_dir: str | Path) -> Recording:
    """A run folder's raw recording (``inspection/recording.json`` + the line files)."""
    run = Path(run_dir)
    man = run / "inspection" / "recording.json"
    if not man.is_file():
        raise DataError(
            f"{run} holds no laser recording (no inspection/recording.json)",
            "give the folder of a localize-and-weld run, or a weldcell/laser-scan@1 CSV",
        )
    data = artifacts.read_json(man)
    if data.get("schema") != RECORDING_SCHEMA:
        raise DataError(f"{man}: schema {data.get('schema')!r}, expected {RECORDING_SCHEMA!r}", "re-record")
    lines = []
    for rec in data["lines"]:
        f = run / rec["file"]
        if not f.is_file():
            raise DataError(f"{man} lists {rec['file']}, which is missing", "resume the run to scan it again")
        lines.append(LineRecord.load(f))
    extra = {k: v for k, v in data.items() if k not in ("schema", "T_flange_sensor", "latency", "lines")}
    return Recording(lines, np.asarray(data["T_flange_sensor"], float), data.get("latency"), extra)


def save_manifest(run_dir: Path, rec: Recording) -> Path:
    return artifacts.write_json(Path(run_dir) / "inspection" / "recording.json", rec.manifest())


# ------------------------------------------------------------------------------------ synchronisation
def interpolate_se3(t: np.ndarray, pose_t: np.ndarray, pose_T: np.ndarray) -> np.ndarray:
    """Poses (N, 4, 4) at times ``t`` (inside ``pose_t``): linear translation, slerp rotation."""
    i = np.clip(np.searchsorted(pose_t, t, side="right") - 1, 0, len(pose_t) - 2)
    dt = pose_t[i + 1] - pose_t[i]
    a = np.clip((t - pose_t[i]) / np.where(dt > 0, dt, 1.0), 0.0, 1.0)
    r0 = Rotation.from_matrix(pose_T[i, :3, :3])
    r1 = Rotation.from_matrix(pose_T[i + 1, :3, :3])
    rel = (r0.inv() * r1).as_rotvec()
    R = (r0 * Rotation.from_rotvec(rel * a[:, None])).as_matrix()
    out = np.tile(np.eye(4), (len(t), 1, 1))
    out[:, :3, :3] = R
    out[:, :3, 3] = (1 - a)[:, None] * pose_T[i, :3, 3] + a[:, None] * pose_T[i + 1, :3, 3]
    return out


@dataclass
class Synchronised:
    """Readings placed in the base frame: times (sensor time minus latency), points, line index."""

    t: np.ndarray
    xyz: np.ndarray
    line: np.ndarray
    dropped_outside: int = 0
    dropped_gaps: int = 0
    gaps: list = field(default_factory=list)


def synchronise(rec: Recording, latency: float, max_pose_gap: float = 0.05) -> Synchronised:
    """Place every reading on the pose stream (``latency`` s subtracted from its stamp)."""
    lt, ld, pt, pT = rec.streams()
    if len(pt) < 2:
        raise DataError(
            "the robot's pose stream has fewer than 2 samples", "check the robot's pose stream (EGM)"
        )
    t = lt - latency
    inside = (t >= pt[0]) & (t <= pt[-1])
    gap_idx = np.flatnonzero(np.diff(pt) > max_pose_gap)
    in_gap = np.zeros(len(t), bool)
    gaps = []
    for g in gap_idx:
        sel = (t > pt[g]) & (t < pt[g + 1])
        in_gap |= sel
        gaps.append({"t": float(pt[g]), "length_s": float(pt[g + 1] - pt[g]), "readings": int(sel.sum())})
    keep = inside & ~in_gap
    t, d = t[keep], ld[keep]
    T = interpolate_se3(t, pt, pT) @ rec.T_flange_sensor
    xyz = T[:, :3, 3] + np.where(np.isfinite(d), d, 0.0)[:, None] * T[:, :3, 2]
    xyz[~np.isfinite(d), 2] = np.nan  # a gap, never a zero; x, y stay under the sensor
    starts = np.array([ln.t_start for ln in rec.lines])
    order = np.argsort(starts)
    line_of = np.array([rec.lines[k].index for k in order])
    k = np.clip(np.searchsorted(starts[order], t, side="right") - 1, 0, len(order) - 1)
    return Synchronised(t, xyz, line_of[k], int((~inside).sum()), int(in_gap.sum()), gaps)


def scan_from_run(run_dir: str | Path, levels: np.ndarray | None = None, max_pose_gap: float = 0.05):
    """The :class:`LaserScan` of a run folder's raw recording (for ``weldcell localize TEMPLATE RUN_DIR``):
    the latency the run used, else estimated from its latency pass with the template's ``levels``."""
    rec = load_recording(run_dir)
    latency = rec.latency
    if latency is None:
        latency = estimate_latency(rec, levels, max_pose_gap)[0] if levels is not None else 0.0
    return to_laser_scan(synchronise(rec, latency, max_pose_gap))


def to_laser_scan(sync: Synchronised):
    """H4's :class:`LaserScan` of the synchronised readings."""
    from weldcell.plugins.localize.scan_io import LaserScan

    return LaserScan(sync.t, sync.xyz, sync.line)


# ------------------------------------------------------------------------------------------- latency
def _mid_crossings(s: np.ndarray, z: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Positions along the line where the profile crosses the middle between adjacent CAD levels."""
    ok = np.isfinite(z)
    s, z = s[ok], z[ok]
    out = []
    for lo, hi in zip(levels[:-1], levels[1:], strict=True):
        mid = 0.5 * (lo + hi)
        a = z - mid
        i = np.flatnonzero(np.sign(a[:-1]) * np.sign(a[1:]) < 0)
        w = a[i] / (a[i] - a[i + 1])
        out.append(s[i] + w * (s[i + 1] - s[i]))
    return np.sort(np.concatenate(out)) if out else np.zeros(0)


def latency_mismatch(rec: Recording, latency: float, levels: np.ndarray, max_pose_gap: float) -> float | None:
    """Median shift (m, along the line) between the edges of the forward and the backward latency pass."""
    fwd = [ln for ln in rec.lines if ln.kind == "latency-fwd"]
    back = [ln for ln in rec.lines if ln.kind == "latency-back"]
    if not fwd or not back:
        return None
    f, b = fwd[0].index, back[0].index
    part = Recording([ln for ln in rec.lines if ln.index <= max(f, b) + 1], rec.T_flange_sensor)
    sync = synchronise(part, latency, max_pose_gap)
    pf, pb = sync.xyz[sync.line == f], sync.xyz[sync.line == b]
    if len(pf) < 10 or len(pb) < 10:
        return None
    d = pf[-1, :2] - pf[0, :2]
    d = d / max(np.linalg.norm(d), 1e-12)
    ef = _mid_crossings(pf[:, :2] @ d, pf[:, 2], levels)
    eb = _mid_crossings(pb[:, :2] @ d, pb[:, 2], levels)
    if len(ef) == 0 or len(eb) == 0:
        return None
    j = np.argmin(np.abs(ef[:, None] - eb[None, :]), axis=1)
    diff = ef - eb[j]
    diff = diff[np.abs(diff) < 0.01]
    return float(np.median(diff)) if len(diff) else None


def estimate_latency(rec: Recording, levels: np.ndarray, max_pose_gap: float = 0.05) -> tuple[float, dict]:
    """The sensor-robot latency (s) that makes the forward and backward pass see the same edges.

    The shift is linear in the latency (``2 v tau`` at the crossing speed): evaluated at two latencies,
    solved, then refined by one secant step. Returns (latency, info); latency 0 with a reason when the
    plan had no latency pass or it crossed no edge.
    """
    levels = np.unique(np.asarray(levels, float))
    m0 = latency_mismatch(rec, 0.0, levels, max_pose_gap)
    if m0 is None or len(levels) < 2:
        return 0.0, {"estimated": False, "reason": "no latency pass with edges in the recording"}
    t0, t1 = 0.0, 0.01
    m1 = latency_mismatch(rec, t1, levels, max_pose_gap)
    for _ in range(3):
        if m1 is None or abs(m1 - m0) < 1e-9:
            return 0.0, {"estimated": False, "reason": "edge shift does not change with the latency"}
        t2 = t1 - m1 * (t1 - t0) / (m1 - m0)
        t2 = float(np.clip(t2, -0.2, 0.2))
        t0, m0, t1 = t1, m1, t2
        m1 = latency_mismatch(rec, t1, levels, max_pose_gap)
        if m1 is not None and abs(m1) < 2e-5:
            break
    return t1, {"estimated": True, "latency_s": t1, "residual_shift_mm": None if m1 is None else m1 * 1e3}


# ----------------------------------------------------------------------------------------- pose streams
class PolledPoseStream:
    """A pose stream for robots without a streamed pose: a thread polls ``robot.state()`` at ``rate``.

    Only as good as the adapter's state reading while a motion runs (EGM-class adapters answer from their
    stream; an adapter whose ``state()`` blocks during motion gives gaps, which synchronisation reports).
    """

    def __init__(self, robot, rate: float) -> None:
        self.robot, self.period = robot, 1.0 / rate
        self._buf: list[tuple[float, np.ndarray]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, daemon=True, name="pose-poll")
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            st = self.robot.state()
            with self._lock:
                self._buf.append((st.stamp, st.T_base_flange))

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            buf, self._buf = self._buf, []
        if not buf:
            return np.zeros(0), np.zeros((0, 4, 4))
        return np.array([b[0] for b in buf]), np.stack([b[1] for b in buf])

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)


def pose_stream_for(robot, rate: float):
    """The robot's pose stream: the simulated robot's timed trajectory, an adapter's own
    ``pose_stream(rate)`` (EGM), or :class:`PolledPoseStream`."""
    if hasattr(robot, "timed"):
        from weldcell.hal.sim.trajectory import SimPoseStream

        return SimPoseStream(robot, rate)
    own = getattr(robot, "pose_stream", None)
    if callable(own):
        return own(rate)
    return PolledPoseStream(robot, rate)


# ------------------------------------------------------------------------------------------ one line
def collect_laser(laser, until: float, settle: float) -> tuple[np.ndarray, np.ndarray]:
    """Laser readings from the stream until one stamped at or after ``until`` arrives (or ``settle`` s)."""
    t, d = [], []
    deadline = time.monotonic() + settle
    while True:
        try:
            got = laser.read_available(timeout=0.05)
        except DeviceError as e:  # the readings received before the failure go with the error
            e.partial = (np.asarray(t, float), np.asarray(d, float))
            raise
        for r in got:
            t.append(r.stamp)
            d.append(np.nan if r.distance is None else r.distance)
        if (t and t[-1] >= until) or time.monotonic() > deadline:
            break
    return np.asarray(t, float), np.asarray(d, float)


def scan_line(
    robot, laser, poses, line: LineSpec, plan, s: AcquisitionSettings, latency_guess: float
) -> LineRecord:
    """Follow one line of the plan (every command through the safety gate) and return its raw streams:
    everything both streams delivered since the previous line (so a transit before it is kept too).

    ``line.t_start`` is where the line's motion starts on the robot's clock (the previous line's end).
    """
    speed = plan.speed if line.speed is None else line.speed
    robot.follow_path(line.tcp_poses, speed=speed, accel=plan.accel, blend=line.blend)
    pt, pT = poses.read()
    if len(pt) == 0:
        raise DeviceError(
            f"the robot's pose stream gave nothing during inspection line {line.index}",
            "check the robot's pose stream (EGM) and its network link",
        )
    t_start = float(pt[0]) if line.t_start is None else line.t_start
    try:
        lt, ld = collect_laser(laser, float(pt[-1]) + latency_guess, s.settle)
    except DeviceError as e:
        lt, ld = getattr(e, "partial", (np.zeros(0), np.zeros(0)))
        e.partial_line = LineRecord(line.index, line.kind, t_start, float(pt[-1]), lt, ld, pt, pT)
        raise
    return LineRecord(line.index, line.kind, t_start, float(pt[-1]), lt, ld, pt, pT)


@dataclass
class LineSpec:
    """One line to scan: its index and kind in the plan, the TCP poses (K, 4, 4), the corner blend (m)
    and where its motion starts on the robot clock (None: at its first pose sample)."""

    index: int
    kind: str
    tcp_poses: np.ndarray
    blend: float = 0.0
    t_start: float | None = None
    speed: float | None = None
