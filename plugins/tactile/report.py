"""The tactile-tracking report: pictures that each answer one question, and ``report/report.html`` (verdict
first, a table of the figures in plain words, the paths in 3-D, the pictures) built with
:mod:`weldcell.sdk.html_report`. The tracking method itself lives in job.py / servo.py.

Pictures (in the run folder, or under the job's prefix):

* ``fig13_paths.png`` - did the path found by touch follow the seam where the vision plan was off?
* ``deformation_over_time.png`` - did the finger hold the set deformation while it tracked?
* ``error_along_seam.png`` (simulated cell) - how far from the true seam was each path, along the seam?
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk.artifacts import write_bytes
from weldcell.sdk.html_report import HtmlReport, Scene3D, Section, figure_png

from .paths import Polyline, left_normal

NORMAL_ENDS = ("contact lost", "end of planned path")
"""Stop reasons of a tracking run that ended as planned (the tool left the part or the plan ended)."""


@dataclass
class TrackData:
    """What a tracking run recorded, as the report draws it (base frame, metres, seconds).

    ``plan``, ``refined`` (SRM tip ``P_s``) and ``seam_est`` are at the tip height; ``tcp`` and ``torch``
    are per camera frame; ``truth_seam`` is the true seam in the simulated cell (else None).
    """

    t: np.ndarray
    tcp: np.ndarray
    torch: np.ndarray
    twist: np.ndarray
    delta_n: np.ndarray
    delta_t: np.ndarray
    delta_d: np.ndarray
    lost: np.ndarray
    plan: np.ndarray
    refined: np.ndarray
    seam_est: np.ndarray
    truth_seam: np.ndarray | None = None

    @classmethod
    def from_record(
        cls, rec: dict[str, np.ndarray], plan, refined, seam_est, truth: dict | None
    ) -> TrackData:
        """From the job's in-memory record (``TrackRecord.arrays()``) and paths."""
        return cls(
            rec["t"],
            rec["tcp"],
            rec["torch"],
            rec["twist"],
            rec["delta_n"],
            rec["delta_t"],
            rec["delta_d"],
            np.asarray(rec["lost"], dtype=bool),
            np.asarray(plan, dtype=float),
            np.asarray(refined, dtype=float).reshape(-1, 3),
            np.asarray(seam_est, dtype=float).reshape(-1, 3),
            None if truth is None else np.asarray(truth["seam"], dtype=float),
        )

    @classmethod
    def from_document(cls, doc: dict[str, Any], truth_seam: np.ndarray | None = None) -> TrackData:
        """From a ``weldcell/tactile-track@1`` document (``tactile_track.json``)."""
        f = doc["frames"]

        def arr(v, shape=(-1,)):  # JSON lists to float arrays (null -> NaN)
            a = [np.nan if x is None else x for x in v] if shape == (-1,) else v
            return np.asarray(a, dtype=float).reshape(shape)

        tip = float(doc.get("settings", {}).get("track", {}).get("tip_height", 0.0))
        seam = arr(doc.get("seam_estimate", []), (-1, 3))
        return cls(
            arr(f["t"]),
            arr(f["tcp"], (-1, 3)),
            arr(f["torch"], (-1, 3)),
            arr(f["twist"], (-1, 6)),
            arr(f["delta_n"]),
            arr(f["delta_t"]),
            arr(f["delta_d"]),
            np.asarray(f["marker_lost"], dtype=bool),
            arr(doc["planned_path"], (-1, 3)),
            arr(doc.get("refined_path", []), (-1, 3)),
            seam + [0.0, 0.0, tip] if len(seam) else seam,
            truth_seam,
        )


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _lost_spans(t: np.ndarray, lost: np.ndarray) -> list[tuple[float, float]]:
    spans, start = [], None
    for i, flag in enumerate(lost):
        if flag and start is None:
            start = t[i]
        if not flag and start is not None:
            spans.append((start, t[i]))
            start = None
    if start is not None:
        spans.append((start, t[-1]))
    return spans


def paths_figure(d: TrackData):
    """Paths seen from above in a seam-aligned frame (along, across the seam, mm) so mm offsets show."""
    plt = _plt()
    ref = d.truth_seam if d.truth_seam is not None else d.plan
    o = ref[0, :2]
    u = (ref[-1, :2] - o) / max(np.linalg.norm(ref[-1, :2] - o), 1e-9)
    v = left_normal(u)

    def uv(P):
        P = np.asarray(P, dtype=float).reshape(-1, 3)[:, :2] - o
        return 1e3 * (P @ u), 1e3 * (P @ v)

    fig, ax = plt.subplots(figsize=(10, 4.2))
    if d.truth_seam is not None:
        ax.plot(*uv(d.truth_seam), "k-", lw=2, label="true seam")
    ax.plot(*uv(d.plan), "--", color="tab:orange", label="planned by vision")
    ax.plot(*uv(d.tcp), "-", color="tab:blue", lw=1, label="robot TCP")
    if len(d.refined):
        ax.plot(*uv(d.refined), "-", color="tab:green", lw=1, label="finger tip (path found by touch)")
        ax.plot(*uv(d.seam_est), ":", color="tab:red", lw=1.5, label="seam from touch")
    ax.plot(*uv(d.torch), "-", color="tab:purple", lw=0.8, alpha=0.7, label="torch")
    ax.set_xlabel("along the seam [mm]")
    ax.set_ylabel("across the seam [mm]")
    ax.set_title("Did touch find the seam where the vision plan was off? (seen from above)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return fig


def deformation_figure(d: TrackData):
    """Measured finger deformation against the set value over time (marker-lost frames shaded red),
    with the robot's speeds below."""
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    t = d.t
    axes[0].plot(t, 1e3 * d.delta_n, label="pressed into the wall (measured)")
    axes[0].plot(t, 1e3 * d.delta_t, label="dragged along the seam (measured)", alpha=0.8)
    axes[0].plot(t, 1e3 * d.delta_d, "k--", label="set deformation")
    for k, (a, b) in enumerate(_lost_spans(t, d.lost)):
        axes[0].axvspan(a, b, color="#cf222e", alpha=0.2, lw=0, label="marker not seen" if k == 0 else None)
    axes[0].set_ylabel("finger deformation [mm]")
    axes[0].legend(fontsize=8)
    axes[0].grid(alpha=0.3)
    axes[0].set_title("Did the finger hold the set deformation while it tracked?")
    axes[1].plot(t, 1e3 * np.linalg.norm(d.twist[:, :2], axis=1), label="robot speed in the plane [mm/s]")
    axes[1].plot(t, np.degrees(d.twist[:, 5]), label="turn rate [°/s]")
    axes[1].set_xlabel("time [s]")
    axes[1].legend(fontsize=8)
    axes[1].grid(alpha=0.3)
    fig.tight_layout()
    return fig


def error_figure(d: TrackData):
    """Distance to the true seam along it: the vision plan and the seam found by touch (log scale)."""
    plt = _plt()
    line = Polyline(d.truth_seam)
    fig, ax = plt.subplots(figsize=(10, 3.5))
    s_p = np.array([line.project(p).s for p in d.plan])
    ax.plot(1e3 * s_p, 1e3 * line.distances(d.plan), color="tab:orange", label="planned by vision")
    s_r = np.array([line.project(p).s for p in d.seam_est])
    ax.plot(1e3 * s_r, 1e3 * line.distances(d.seam_est), color="tab:red", label="seam from touch")
    ax.set_xlabel("along the seam [mm]")
    ax.set_ylabel("distance to the true seam [mm]")
    ax.set_yscale("log")
    ax.set_title("How far from the true seam was each path, along the seam?")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


PICTURES = {
    "fig13": (
        "fig13_paths.png",
        "Did touch find the seam where the vision plan was off? Paths seen from above, "
        "in a frame along the seam so millimetre offsets show.",
    ),
    "deformation": (
        "deformation_over_time.png",
        "Did the finger hold the set deformation while it tracked? "
        "Red bands: frames where the in-finger camera did not see the marker.",
    ),
    "error_along_seam": (
        "error_along_seam.png",
        "How far from the true seam was each path, along the seam? (simulated cell; log scale)",
    ),
}


def pictures(ctx, d: TrackData, prefix: str = "") -> dict[str, str]:
    """Draw and write the report's pictures; returns {key: file in the run folder}."""
    plt = _plt()
    out = {}
    makers: list[tuple[str, Callable]] = [("fig13", paths_figure), ("deformation", deformation_figure)]
    if d.truth_seam is not None and len(d.seam_est) >= 2:
        makers.append(("error_along_seam", error_figure))
    for key, make in makers:
        fig = make(d)
        name = f"{prefix}{PICTURES[key][0]}"
        write_bytes(ctx.path(name), figure_png(fig, dpi=110))
        plt.close(fig)
        out[key] = name
    return out


def verdict(fig: dict[str, Any]) -> tuple[str, str, list[str], list[str], list[str]]:
    """(status, headline, found, refused, attention) of a tracking run from its figures."""
    found, refused, attention = [], [], []
    length = fig.get("refined_length_mm", 0.0) or 0.0
    found.append(
        f"seam followed by touch for {length:.0f} mm in {fig.get('duration_s', 0.0):.1f} s "
        f"({int(fig.get('refined_points', 0))} points); the run ended: {fig.get('stop_reason')}"
    )
    if fig.get("refined_seam_rms_mm") is not None:
        found.append(
            f"seam from touch: {fig['refined_seam_rms_mm']:.2f} mm RMS "
            f"(max {fig.get('refined_seam_max_mm', 0):.2f} mm) from the true seam; "
            f"the vision plan: {fig.get('plan_rms_mm', float('nan')):.2f} mm RMS"
        )
    if fig.get("safe_stop"):
        refused.append(f"safe stop: {fig['safe_stop']} (the robot stopped; everything recorded is kept)")
    lost = int(fig.get("marker_lost_frames", 0) or 0)
    if lost:
        attention.append(
            f"the in-finger camera lost the marker in {lost} of {int(fig.get('frames', 0))} frames: check "
            "lighting and focus"
        )
    cov = fig.get("refined_coverage")
    if cov is not None and cov < 0.9:
        attention.append(
            f"the touch path covers {100 * cov:.0f} % of the seam: check the rest before welding it from "
            "the vision plan"
        )
    if fig.get("stop_reason") not in NORMAL_ENDS and not fig.get("safe_stop"):
        attention.append(f"tracking ended early: {fig.get('stop_reason')}")
    status = "failed" if refused else ("attention" if attention else "ok")
    head = {
        "ok": "seam tracked by touch",
        "attention": "seam tracked by touch, with points to check",
        "failed": "tracking stopped safely before the end",
    }[status]
    return status, head, found, refused, attention


FIGURE_WORDS = [
    ("refined_length_mm", "length of seam found by touch", "mm"),
    ("refined_coverage", "share of the seam covered by the touch path", ""),
    ("refined_seam_rms_mm", "seam from touch: RMS distance to the true seam", "mm"),
    ("refined_seam_max_mm", "seam from touch: largest distance to the true seam", "mm"),
    ("refined_seam_height_rms_mm", "seam from touch: RMS height error", "mm"),
    ("refined_tip_rms_mm", "finger tip: RMS distance to the true tip position", "mm"),
    ("plan_rms_mm", "vision plan: RMS distance to the true seam", "mm"),
    ("delta_n_mean_mm", "finger pressed into the wall, mean", "mm"),
    ("delta_n_std_mm", "finger pressed into the wall, spread (std)", "mm"),
    ("delta_d_mm", "set deformation", "mm"),
    ("duration_s", "tracking time", "s"),
    ("frames", "camera frames", ""),
    ("marker_lost_frames", "frames without the marker", ""),
]


def _scene(d: TrackData, poses: np.ndarray | None) -> Scene3D:
    sc = Scene3D("paths [mm]")
    if d.truth_seam is not None:
        sc.line(d.truth_seam, "true seam", color="#111", width=4, dash="dash")
    sc.line(d.plan, "planned by vision", color="#ff7f0e", width=3, dash="dot")
    sc.line(d.tcp, "robot TCP", color="#1f77b4", width=2)
    if len(d.refined):
        sc.line(d.refined, "finger tip (touch)", color="#2ca02c", width=3)
    if len(d.seam_est):
        sc.line(d.seam_est, "seam from touch", color="#d62728", width=4)
    if poses is not None and len(poses):
        sc.frames(poses, "torch on the refined seam", length=0.01, max_frames=25)
    return sc


def write_html(
    ctx,
    d: TrackData,
    fig: dict[str, Any],
    prefix: str = "",
    *,
    title: str = "Tactile seam tracking",
    before: Callable[[HtmlReport], None] | None = None,
    extra_verdict: tuple[list[str], list[str], list[str]] | None = None,
) -> Path:
    """``{prefix}report/report.html``: verdict, figures in plain words, the paths in 3-D, the pictures.

    ``before(report)`` adds sections ahead of the tracking ones (e.g. the calibration of
    calibrate-and-track); ``extra_verdict`` (found, refused, attention) joins the verdict's lists.
    """
    status, head, found, refused, attention = verdict(fig)
    if extra_verdict is not None:
        found = extra_verdict[0] + found
        refused = extra_verdict[1] + refused
        attention = extra_verdict[2] + attention
        if status == "ok" and attention:
            status = "attention"
    rep = HtmlReport(f"{title}: {ctx.profile.name}", f"run folder {ctx.run_dir.name}")
    rep.set_verdict(status, head, found=found, refused=refused, attention=attention)
    if before is not None:
        before(rep)
    sec: Section = rep.section("Tracking figures", "What the tracking measured, in plain words.")
    counts = ("frames", "marker_lost_frames", "refined_points")
    rows = [
        [what, int(fig[k]) if k in counts else fig[k], unit]
        for k, what, unit in FIGURE_WORDS
        if fig.get(k) is not None
    ]
    sec.table(["figure", "value", "unit"], rows)
    poses = None
    rp = (fig.get("files") or {}).get("refined_path")
    if rp and (ctx.run_dir / rp).is_file():
        from weldcell.sdk.weldpath import WeldPath

        poses = WeldPath.from_json(ctx.run_dir / rp).seams[0].poses
    rep.section(
        "Paths in 3-D",
        "Drag to turn, scroll to zoom, click a legend entry to hide it.",
    ).scene(_scene(d, poses))
    pics = rep.section("Pictures")
    for key, (name, caption) in PICTURES.items():
        f = ctx.run_dir / f"{prefix}{name}"
        if key in (fig.get("files") or {}) and f.is_file():
            pics.figure(f, caption)
    return rep.write(ctx.path(f"{prefix}report/report.html"))
