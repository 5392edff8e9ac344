"""What a tactile tracking run recorded, its figures against the truth, and the files it writes.

``tactile_track.json`` (``weldcell/tactile-track@1``), ``refined_path.json`` (the seam found by touch,
``weldcell/weld-path@1``), the pictures and the HTML report (plugins/tactile/report.py), ``summary.txt``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from weldcell.sdk.errors import JobError
from weldcell.sdk.geometry import frame_from_axes
from weldcell.sdk.weldpath import SeamPath, WeldPath

from . import report as tactile_report
from .paths import Polyline, left_normal
from .servo import ServoCommand, ServoSettings, TactileSeamServo, seam_from_tip_path
from .track_settings import TrackSettings

SCHEMA = "weldcell/tactile-track@1"


@dataclass
class TrackRecord:
    """What one tracking run recorded (base frame, SI)."""

    t: list[float] = field(default_factory=list)
    tcp: list[np.ndarray] = field(default_factory=list)
    torch: list[np.ndarray] = field(default_factory=list)
    twist: list[np.ndarray] = field(default_factory=list)
    delta_n: list[float] = field(default_factory=list)
    delta_t: list[float] = field(default_factory=list)
    delta_d: list[float] = field(default_factory=list)
    in_contact: list[bool] = field(default_factory=list)
    lost: list[bool] = field(default_factory=list)
    state: list[str] = field(default_factory=list)

    def add(self, t: float, T: np.ndarray, cmd: ServoCommand, measured: bool) -> None:
        """One control step: time since the first frame, the TCP pose, the servo's command, and whether
        the deflection was measured (the marker seen) in this frame."""
        self.t.append(t)
        self.tcp.append(T[:3, 3].copy())
        self.torch.append(cmd.P_t)
        self.twist.append(cmd.twist)
        self.delta_n.append(cmd.delta_n if measured else np.nan)
        self.delta_t.append(cmd.delta_t if measured else np.nan)
        self.delta_d.append(cmd.delta_d)
        self.in_contact.append(bool(cmd.in_contact))
        self.lost.append(not measured)
        self.state.append(cmd.state)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) for k, v in self.__dict__.items()}


@dataclass
class TrackOutcome:
    """How a tracking run ended: the servo (with its refined path), the record and the stop."""

    servo: TactileSeamServo
    record: TrackRecord
    stop_reason: str
    final_state: str
    safe_stop: str
    notes: list[str] = field(default_factory=list)


def device_truth(ctx, plan: np.ndarray, S: ServoSettings) -> dict | None:
    """The simulated tactile device's ground truth, its seam in the plan's travel direction, or None."""
    dev = ctx.devices.get("tactile")
    if not hasattr(dev, "truth"):
        return None
    tr = dev.truth()
    if tr.get("seam") is None:
        return None
    seam = np.asarray(tr["seam"], dtype=float)
    seam_line = Polyline(seam, "true seam")
    # same travel direction as the plan
    if float(seam_line.at(seam_line.length)[0][:2] @ (plan[-1, :2] - plan[0, :2])) < float(
        seam_line.at(0.0)[0][:2] @ (plan[-1, :2] - plan[0, :2])
    ):
        seam = seam[::-1].copy()
    tr["seam"] = seam
    return tr


def _metrics(
    rec: dict[str, np.ndarray],
    refined: np.ndarray,
    refined_t: np.ndarray,
    seam_est: np.ndarray,
    plan: np.ndarray,
    truth: dict | None,
    S: ServoSettings,
    tip_height: float,
) -> dict[str, float]:
    m: dict[str, float] = {}
    contact = rec["in_contact"] & ~np.isnan(rec["delta_n"]) if len(rec["t"]) else np.zeros(0, bool)
    if contact.any():
        m["delta_n_mean_mm"] = 1e3 * float(np.nanmean(rec["delta_n"][contact]))
        m["delta_n_std_mm"] = 1e3 * float(np.nanstd(rec["delta_n"][contact]))
    m["delta_d_mm"] = 1e3 * S.delta_d
    m["frames"] = float(len(rec["t"]))
    m["duration_s"] = float(rec["t"][-1]) if len(rec["t"]) else 0.0
    m["marker_lost_frames"] = float(np.sum(rec["lost"])) if len(rec["t"]) else 0.0
    m["refined_points"] = float(len(refined))
    m["refined_length_mm"] = 1e3 * (Polyline(refined).length if len(refined) >= 2 else 0.0)
    if truth is None or len(seam_est) < 2:
        return m
    seam_line = Polyline(truth["seam"], "true seam")
    inside = np.array([not (p.before_start or p.past_end) for p in map(seam_line.project, seam_est)])
    if inside.any():
        d = seam_line.distances(seam_est[inside])
        m["refined_seam_rms_mm"] = 1e3 * float(np.sqrt(np.mean(d**2)))
        m["refined_seam_max_mm"] = 1e3 * float(d.max())
        dz = (
            seam_est[inside, 2]
            - tip_height
            - np.array([seam_line.project(p).point[2] for p in seam_est[inside]])
        )
        m["refined_seam_height_rms_mm"] = 1e3 * float(np.sqrt(np.mean(dz**2)))
    m["refined_coverage"] = float(Polyline(refined).length / seam_line.length)
    inside_p = np.array([not (p.before_start or p.past_end) for p in map(seam_line.project, plan)])
    if inside_p.any():
        dp = seam_line.distances(plan[inside_p])
        m["plan_rms_mm"] = 1e3 * float(np.sqrt(np.mean(dp**2)))
    return m


def refined_weld_path(seam_line_pts: np.ndarray, wall_side: str) -> WeldPath:
    """The seam found by touch as a weld path: torch z bisects the wall and the floor, x along travel."""
    P = np.asarray(seam_line_pts, dtype=float)
    line = Polyline(P, "refined seam")
    sign = 1.0 if wall_side == "left" else -1.0
    poses = []
    for s_ in line.s:
        t = line.smooth_tangent(float(s_), 0.003)
        n_in = sign * left_normal(t)
        approach = np.array([n_in[0], n_in[1], -1.0]) / np.sqrt(2.0)
        poses.append(frame_from_axes([t[0], t[1], 0.0], approach, line.points[len(poses)]))
    return WeldPath([SeamPath("tactile", "fillet", line.points, np.stack(poses))], frame="base")


def finish(ctx, out: TrackOutcome, plan: np.ndarray, s: TrackSettings, S: ServoSettings, prefix: str) -> dict:
    """Figures and files of a finished tracking run; raises :class:`JobError` after writing them when the
    stop was a safe stop and ``fail_on_safe_stop`` is set."""
    rec = out.record.arrays()
    refined, refined_t = out.servo.refined.points, out.servo.refined.times  # refined_t: absolute stamps
    seam_est = (
        seam_from_tip_path(refined, S.tip_radius, S.wall_side, S.tangent_window) if len(refined) else refined
    )
    truth = device_truth(ctx, plan, S)
    metrics = _metrics(rec, refined, refined_t, seam_est, plan - [0, 0, s.tip_height], truth, S, s.tip_height)
    if truth is not None and "t" in truth and len(refined_t):
        # recorded tip P_s against the true tip at the capture it was recorded from (same simulated clock)
        idx = np.clip(np.searchsorted(truth["t"], refined_t - 1e-9), 0, len(truth["t"]) - 1)
        e = np.linalg.norm(refined[:, :2] - truth["tip"][idx, :2], axis=1)
        metrics["refined_tip_rms_mm"] = 1e3 * float(np.sqrt(np.mean(e**2)))
    seam_line = seam_est - np.array([0.0, 0.0, s.tip_height]) if len(seam_est) else seam_est
    files = {"track": f"{prefix}tactile_track.json"}
    ctx.write_json(files["track"], _track_document(out, rec, plan, seam_line, metrics, s, S))
    if len(seam_line) >= 2:
        wp = refined_weld_path(seam_line, S.wall_side)
        wp.metrics = {k: v for k, v in metrics.items() if k.startswith("refined")}
        files["refined_path"] = f"{prefix}refined_path.json"
        wp.write(ctx.path(files["refined_path"]))
    report_data = tactile_report.TrackData.from_record(rec, plan, refined, seam_est, truth)
    if s.plots and len(rec["t"]):
        files.update(tactile_report.pictures(ctx, report_data, prefix))
    figures = {
        "stop_reason": out.stop_reason,
        "final_state": out.final_state,
        "safe_stop": out.safe_stop or None,
        **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in metrics.items()},
        "files": files,
    }
    if len(rec["t"]):
        files["report"] = f"{prefix}report/report.html"
        tactile_report.write_html(ctx, report_data, figures, prefix)
    ctx.write_text(f"{prefix}summary.txt", summary_text(figures, "tactile tracking"))
    ctx.state.data["notes"][f"{prefix}tactile figures"] = figures  # a resume returns these, moving nothing
    ctx.state.save()
    if out.safe_stop and s.fail_on_safe_stop:
        ctx.figures.update({"tactile": figures})
        where = (
            f"after {metrics.get('refined_length_mm', 0.0):.0f} mm of seam, t = {metrics['duration_s']:.2f} s"
        )
        raise JobError(
            f"tactile tracking made a safe stop {where}: {out.safe_stop}",
            fix_for(out.safe_stop) + f"; what was recorded is in {ctx.run_dir}",
        )
    return figures


def _track_document(
    out: TrackOutcome,
    rec: dict[str, np.ndarray],
    plan: np.ndarray,
    seam_line: np.ndarray,
    metrics: dict[str, float],
    s: TrackSettings,
    S: ServoSettings,
) -> dict[str, Any]:
    """The ``weldcell/tactile-track@1`` document of a run."""
    refined, refined_t = out.servo.refined.points, out.servo.refined.times
    return {
        "schema": SCHEMA,
        "frame": "base",
        "units": "m",
        "stop_reason": out.stop_reason,
        "final_state": out.final_state,
        "safe_stop": out.safe_stop or None,
        "settings": {"servo": S.model_dump(mode="json"), "track": s.model_dump(mode="json")},
        "planned_path": np.round(plan, 7).tolist(),
        "refined_path": np.round(refined, 7).tolist(),
        "refined_times": np.round(refined_t, 5).tolist(),
        "seam_estimate": np.round(seam_line, 7).tolist(),
        "frames": {
            "t": np.round(rec["t"], 5).tolist(),
            "tcp": np.round(rec["tcp"], 7).tolist(),
            "torch": np.round(rec["torch"], 7).tolist(),
            "twist": np.round(rec["twist"], 7).tolist(),
            "delta_n": [None if np.isnan(v) else round(float(v), 8) for v in rec["delta_n"]],
            "delta_t": [None if np.isnan(v) else round(float(v), 8) for v in rec["delta_t"]],
            "delta_d": np.round(rec["delta_d"], 8).tolist(),
            "in_contact": rec["in_contact"].tolist(),
            "marker_lost": rec["lost"].tolist(),
            "state": rec["state"].tolist(),
        },
        "metrics": metrics,
        "notes": out.notes,
    }


def fix_for(reason: str) -> str:
    """What to do about a safe stop, from its reason."""
    if reason.startswith("safety"):
        return (
            "check the planned path against [cell.safety] workspace_min/max (the seam leaves the box) or "
            "shorten the plan"
        )
    if "marker" in reason:
        return "check the in-finger camera: lighting, focus, a torn or occluded tag, marker id and dictionary"
    if "overload" in reason:
        return "the finger was pressed beyond its range: lower delta_d / k_p or check the plan's height"
    return "see tactile_track.json for the recorded frames"


def summary_text(fig: dict[str, Any], title: str) -> str:
    """``summary.txt``: one line a figure (one level of nesting), then the files."""
    lines = [f"weldcell {title}", ""]
    for k, v in fig.items():
        if k == "files":
            continue
        if isinstance(v, dict):
            lines.append(f"{k}:")
            lines += [f"  {k2:<28} {v2}" for k2, v2 in v.items() if not isinstance(v2, dict | list)]
        else:
            lines.append(f"{k:<30} {v}")
    if "files" in fig:
        lines += ["", "files: " + ", ".join(str(v) for v in fig["files"].values())]
    return "\n".join(lines) + "\n"
