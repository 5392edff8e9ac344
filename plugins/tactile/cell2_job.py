"""The ``calibrate-and-track`` job: cell 2 of paper 003 from scratch, in one run.

1. **Calibrate** the fixed depth camera (eye-on-base) with the flange method: the registered
   ``calibrate`` job (looked up by name in the plugin registry; its settings are
   :class:`weldcell.sdk.calibration.CalibrateSettings`) runs on a sub-context whose run folder is
   ``calibrate/`` (its captures, ``handeye.json``, report and resume state live there).
2. **Plan** the seam by vision with the ESTIMATED ``T_base_camera``: park the robot, scan the part,
   map the scan to the robot base with the estimate, denoise, find the seams (the profile's ``seam``
   stage, ``seam.edge-intensity`` by default) and keep the one with a side wall. The planned path so
   carries the real calibration error plus the vision error.
3. **Track** the seam with the SRM tool (:func:`weldcell.plugins.tactile.tracking.track`): Algorithm 2 at
   camera rate through the HAL safety gate; the wall, not the plan, sets the path.
4. **Report** both phases: ``summary.txt`` and ``result.json`` figures (calibration error vs truth,
   vision-planned path error, refined path RMS vs the true seam in the simulated cell), the calibration
   plots (``calibrate/report/``: residuals, cost and error against samples as Figs. 10-11) and the
   tracking plots (``fig13_paths.png``, ``deformation_over_time.png``, ``error_along_seam.png``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from pydantic import Field
from weldcell.hal.sim import true_camera_mount
from weldcell.sdk.artifacts import save_figure
from weldcell.sdk.calibration import CALIBRATE_JOB, CalibrateSettings
from weldcell.sdk.errors import JobError
from weldcell.sdk.geometry import pose_error
from weldcell.sdk.settings import Settings

from .track_results import device_truth, refined_weld_path, summary_text
from .track_settings import ScanSettings, TrackSettings
from .tracking import track
from .vision_plan import read_T_base_camera, scan_for_seam, true_seams


class CalibrateAndTrackSettings(Settings):
    """Settings of ``calibrate-and-track``: one table per phase."""

    calibrate: CalibrateSettings = Field(
        description="the hand-eye calibration phase (settings of the 'calibrate' job)"
    )
    scan: ScanSettings = Field(default_factory=ScanSettings, description="the vision step (scan + seams)")
    track: TrackSettings = Field(default_factory=TrackSettings, description="the tactile tracking phase")


class _CalibrationContext:
    """The run context as the ``calibrate`` job sees it: its settings, its stage, its own run folder.

    The job is the one registered as ``calibrate`` (:data:`~weldcell.sdk.calibration.CALIBRATE_JOB`),
    whichever plugin provides it."""

    def __init__(self, ctx, settings: CalibrateSettings) -> None:
        from weldcell.sdk.jobs import RunContext

        self.spec = ctx.pm.registry.get("job", CALIBRATE_JOB)
        resolved = dataclasses.replace(
            ctx.resolved,
            job_spec=self.spec,
            job=settings,
            stages={"handeye": ctx.resolved.stages["handeye"]},
        )
        sub = RunContext(ctx.loaded, resolved, ctx.pm, ctx.run_dir / "calibrate", ctx.reporter)
        sub.devices, sub.shared = ctx.devices, ctx.shared
        self.sub = sub

    def run(self) -> dict[str, Any]:
        (self.sub.run_dir).mkdir(parents=True, exist_ok=True)
        return self.spec.run(self.sub) or {}


def calibration_error_vs_samples(run_dir, truth: np.ndarray, feature) -> list[dict[str, float]]:
    """Error of the all-data fit (eqs. 9-12) against the true mount, for the first n samples (Figs. 10-11)."""
    from weldcell.sdk.handeye_files import read_samples
    from weldcell.sdk.pointfit import scaled_svd_fit

    path = run_dir / "samples.json"
    if not path.is_file():
        return []
    samples = read_samples(path).samples
    f = np.asarray(feature, dtype=float).reshape(3)
    rows = []
    for n in range(4, len(samples) + 1):
        c = np.array([s.p_cam for s in samples[:n]])
        d = np.array([(s.T_base_flange @ np.r_[f, 1.0])[:3] for s in samples[:n]])
        dt, dr = pose_error(scaled_svd_fit(c, d).T, truth)
        rows.append({"n": n, "translation_mm": 1e3 * dt, "rotation_deg": float(np.degrees(dr))})
    return rows


def run(ctx) -> dict[str, Any]:
    """The ``calibrate-and-track`` job."""
    s: CalibrateAndTrackSettings = ctx.settings
    if ctx.profile.devices["camera"].mount.parent not in ("world", "base"):
        raise JobError(
            "calibrate-and-track calibrates a camera fixed in the cell (eye-on-base); the camera is "
            f"mounted on '{ctx.profile.devices['camera'].mount.parent}'",
            "mount [devices.camera] on 'world' (a stand looking at the robot and the part)",
        )
    figures: dict[str, Any] = {}

    # 1. calibration ------------------------------------------------------------------------------
    cal = _CalibrationContext(ctx, s.calibrate)
    cal_fig = cal.run()
    ctx.timings.update({f"calibrate: {k}": v for k, v in cal.sub.timings.items()})
    T_est = read_T_base_camera(cal.sub.run_dir / "handeye.json")
    truth = true_camera_mount(ctx)
    figures["calibration"] = {k: v for k, v in cal_fig.items() if not isinstance(v, dict)}
    if truth is not None:
        dt, dr = pose_error(T_est, truth)
        figures["calibration"]["error_translation_mm"] = round(1e3 * dt, 4)
        figures["calibration"]["error_rotation_deg"] = round(float(np.degrees(dr)), 5)
        feature = getattr(ctx.stage_settings("handeye"), "feature", (0.0, 0.0, 0.0))
        rows = calibration_error_vs_samples(cal.sub.run_dir, truth, feature)
        if rows:
            ctx.write_json("calibration_error_vs_samples.json", rows)
            _plot_error_vs_samples(ctx, rows)
    ctx.figures.update(figures)

    # 2. vision plan with the ESTIMATED hand-eye --------------------------------------------------
    S = ctx.stage_settings("servo")
    plan = scan_for_seam(
        ctx, ctx.device("camera"), T_est, s.scan, S.wall_side, true_seams(ctx), prefix="plan: "
    )
    figures["plan"] = {
        "source": "vision with the estimated hand-eye",
        **{k: v for k, v in plan.info.items() if k != "candidates"},
    }
    from weldcell.sdk.weldpath import SeamPath, WeldPath

    poses = refined_weld_path(plan.points, S.wall_side).seams[0].poses
    WeldPath(
        [SeamPath("vision", str(plan.info.get("joint", "fillet")), plan.points, poses)],
        frame="base",
        metrics={k: v for k, v in plan.info.items() if k.startswith("vision")},
    ).write(ctx.path("planned_path.json"))
    ctx.figures.update(figures)

    # 3. tactile tracking -------------------------------------------------------------------------
    try:
        figures["tactile"] = track(ctx, plan.points, s.track)
    finally:
        ctx.write_text("summary.txt", _summary(ctx, figures))
        _report_html(ctx, figures, plan.points)
    ctx.write_text("summary.txt", _summary(ctx, figures))
    return figures


def _summary(ctx, figures: dict[str, Any]) -> str:
    head = ["calibrate-and-track: hand-eye calibration, vision plan, tactile seam tracking", ""]
    c, p = figures.get("calibration", {}), figures.get("plan", {})
    t = figures.get("tactile") or ctx.figures.get("tactile") or {}
    key = [
        (
            "calibration error vs truth",
            f"{c.get('error_translation_mm', 'n/a')} mm, {c.get('error_rotation_deg', 'n/a')} deg",
        ),
        (
            "vision-planned path RMS vs true seam",
            f"{_fmt(p.get('vision_plan_rms_mm'))} mm (max {_fmt(p.get('vision_plan_max_mm'))} mm)",
        ),
        (
            "refined path RMS vs true seam",
            f"{_fmt(t.get('refined_seam_rms_mm'))} mm (max {_fmt(t.get('refined_seam_max_mm'))} mm)",
        ),
        ("tracking stop", f"{t.get('stop_reason', 'n/a')} ({t.get('final_state', 'n/a')})"),
    ]
    lines = head + [f"{k:<38} {v}" for k, v in key] + [""]
    body = summary_text(
        {"calibration": c, "plan": p, "tactile": {k: v for k, v in t.items() if k != "files"}},
        "calibrate-and-track details",
    )
    files = [
        "calibrate/handeye.json",
        "calibrate/report/",
        "planned_path.json",
        "refined_path.json",
        "tactile_track.json",
        "fig13_paths.png",
        "deformation_over_time.png",
        "error_along_seam.png",
        "calibration_error_vs_samples.png",
    ]
    present = [f for f in files if (ctx.run_dir / f).exists()]
    return "\n".join(lines) + body + "\nfiles: " + ", ".join(present) + "\n"


def _fmt(v) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def _plot_error_vs_samples(ctx, rows: list[dict[str, float]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["n"] for r in rows]
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    ax[0].plot(n, [r["translation_mm"] for r in rows], "o-")
    ax[0].set_ylabel("translation error [mm]")
    ax[1].plot(n, [r["rotation_deg"] for r in rows], "o-", color="tab:orange")
    ax[1].set_ylabel("rotation error [deg]")
    for a in ax:
        a.set_xlabel("samples used (flange centres)")
        a.set_ylim(bottom=0)
        a.grid(alpha=0.3)
    fig.suptitle("How close is the hand-eye to the true camera mount as samples are added? (simulated cell)")
    fig.tight_layout()
    save_figure(fig, ctx.path("calibration_error_vs_samples.png"), dpi=110)
    plt.close(fig)


def _words(key: str) -> str:
    """A figure's key as words with its unit: ``error_translation_mm`` -> ``error translation [mm]``."""
    for suffix, unit in (("_mm", " [mm]"), ("_deg", " [°]"), ("_s", " [s]")):
        if key.endswith(suffix):
            return key[: -len(suffix)].replace("_", " ") + unit
    return key.replace("_", " ")


def _report_html(ctx, figures: dict[str, Any], plan_points: np.ndarray) -> None:
    """``report/report.html``: the tracking report (plugins/tactile/report.py) with the calibration and
    the vision plan ahead of it; written also after a safe stop (from what was recorded)."""
    from weldcell.sdk.artifacts import read_json

    from . import report as tactile_report

    track_file = ctx.run_dir / "tactile_track.json"
    tactile = figures.get("tactile") or ctx.figures.get("tactile")
    if not track_file.is_file() or not tactile:
        return
    truth = device_truth(ctx, np.asarray(plan_points, dtype=float), ctx.stage_settings("servo"))
    data = tactile_report.TrackData.from_document(
        read_json(track_file), None if truth is None else truth["seam"]
    )
    c, p = figures.get("calibration", {}), figures.get("plan", {})
    found, attention = [], []
    if "error_translation_mm" in c:
        found.append(
            f"hand-eye: {c['error_translation_mm']:.3f} mm, {c['error_rotation_deg']:.4f}° from the true "
            "camera mount (simulated cell)"
        )
    if p.get("vision_plan_rms_mm") is not None:
        found.append(f"vision plan: {p['vision_plan_rms_mm']:.2f} mm RMS from the true seam")

    def before(rep) -> None:
        sec = rep.section(
            "Calibration of the fixed camera (eye-on-base)",
            "The hand-eye found by the calibration phase; its own report with every sample is in "
            "calibrate/report/.",
        )
        sec.table(
            ["figure", "value"], [[_words(k), v] for k, v in c.items() if not isinstance(v, list | dict)]
        )
        png = ctx.run_dir / "calibration_error_vs_samples.png"
        if png.is_file():
            sec.figure(png, "How close is the hand-eye to the true mount as samples are added?")
        rep.section("Vision plan", "The seam planned from one scan with the estimated hand-eye.").table(
            ["figure", "value"], [[_words(k), v] for k, v in p.items() if not isinstance(v, list | dict)]
        )

    tactile_report.write_html(
        ctx, data, tactile, title="Calibrate and track", before=before, extra_verdict=(found, [], attention)
    )
