"""The scan-and-plan report: ``summary.txt`` (what an operator reads on the terminal), and in ``report/``:
``report.html`` (one self-contained page: verdict first, an interactive 3-D view of the model, seams
and torch frames, a table per seam, cross-sections with the torch drawn), ``report.md`` and the PNGs
for people who read files in a terminal. Each picture answers one question (report_figures.py).
``weldcell seam --report DIR`` writes the same pages for one cloud (:func:`write_pages`, no
reconstruction section).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.plugins.scan_plan.report_figures import (
    SEAM_COLOURS,
    SeamMeasures,
    correction_sizes,
    cross_section_figure,
    fitness_figure,
    overview_figure,
    point_spacing,
    seam_error_figure,
    seam_measures,
)
from weldcell.sdk.artifacts import write_bytes, write_text
from weldcell.sdk.html_report import figure_png

SEAM_ERROR_ATTENTION = 0.002
"""A found seam whose line strays more than this from the true one (simulation) is flagged [m]: about
half the leg of a small fillet or the gap of a thin-plate groove, beyond which the wire can miss the
joint root."""


@dataclass
class Verdict:
    """What the job concluded: ``status`` ok / attention / failed, a headline and the three lists."""

    status: str
    headline: str
    found: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    attention: list[str] = field(default_factory=list)


@dataclass
class ReportPage:
    """Where a seam report is written and what its page says around the results: the folder (``report/``
    of a run, or ``weldcell seam --report DIR``), the page's title and subtitle, the rows of its files
    table ``[file, what it is]``, what the cloud is called in the 3-D view, and whether the scan was
    reconstructed from views (the job) or read as one cloud (the command)."""

    out_dir: Path
    title: str
    subtitle: str
    files: list[list[str]] = field(default_factory=list)
    cloud_label: str = "denoised model"
    md_title: str = "Scan-and-plan report"


def _deg(a) -> float:
    return float(np.degrees(np.nanmean(a))) if len(a) else float("nan")


def _spread(a, scale: float) -> str:
    """'mean' or 'mean (min..max)' when the values vary."""
    if not len(a):
        return "-"
    lo, mid, hi = (_f1(scale * f(a)) for f in (np.nanmin, np.nanmean, np.nanmax))
    return mid if float(hi) - float(lo) < 0.5 else f"{mid} ({lo}..{hi})"


def _f1(x: float) -> str:
    """One decimal, without a '-0.0'."""
    s = f"{x:.1f}"
    return "0.0" if s == "-0.0" else s


def verdict(ctx, rec, path, gt, measures: list[SeamMeasures]) -> Verdict:
    """The verdict of a scan-and-plan run from what it computed and what was refused along the way."""
    return verdict_of(ctx.figures, rec, path, gt, measures)


def verdict_of(fig: dict, rec, path, gt, measures: list[SeamMeasures]) -> Verdict:
    """The verdict from the run's ``figures`` (refusals, notes, execution), the reconstruction ``rec``
    (None for a single cloud), the path, the ground truth (simulation) and the seam measures."""
    v = Verdict("ok", "")
    m = path.metrics
    for s in measures:
        line = f"seam {s.id}: {s.joint}, {1e3 * s.length:.0f} mm, {s.poses} torch poses"
        if s.error:
            line += f", {1e3 * s.error['translation_m']:.2f} mm RMS from the true seam ({s.truth})"
        v.found.append(line)
    if gt and m.get("seams_true", 0) > len(path.seams):
        v.attention.append(
            f"{m['seams_true'] - len(path.seams)} of {m['seams_true']} true seams were not found: check the "
            "scan covers every joint"
        )
    for s in measures:
        if s.error and s.error.get("translation_max_m", 0.0) > SEAM_ERROR_ATTENTION:
            v.attention.append(
                f"seam {s.id} strays up to {1e3 * s.error['translation_max_m']:.1f} mm from the true seam "
                f"(flagged above {1e3 * SEAM_ERROR_ATTENTION:g} mm): check its cross-sections"
            )
    acc = list(getattr(rec, "accepted", None) or [])
    for i, ok in enumerate(acc):
        if not ok:
            v.refused.append(
                f"view {i}: the ICP correction was rejected; its kinematic pose (robot + hand-eye) kept"
            )
    for note in fig.get("reconstruction_notes", []) or []:
        if not any(note in r for r in v.refused):
            v.attention.append(f"reconstruction: {note}")
    refused_targets = (fig.get("scan") or {}).get("refused_targets", 0)
    if refused_targets:
        v.refused.append(
            f"{refused_targets} gesture target(s) during the scan: the safety gate refused the camera move "
            "(expected when the hand asks for a pose outside the workspace or too fast; the camera stayed)"
        )
    for name, reason in (fig.get("programs_refused") or {}).items():
        v.refused.append(f"program {name} not written: {reason}")
    ex = fig.get("execute") or {}
    if ex.get("status") == "refused":
        v.refused.append(f"execution: {ex.get('reason')} (nothing was sent to the robot)")
        v.attention.append("the weld path was not executed: fix the reach or the workspace, then run again")
    if "hand_eye_source" in fig and "nominal" in str(fig["hand_eye_source"]):
        v.attention.append(
            "the hand-eye is the camera mount's nominal value, not a calibration: calibrate the cell "
            "(weldcell run profiles/cell1-calibrate-*.toml) before welding a real part"
        )
    n = len(path.seams)
    done = {"done": "executed" + (" (dry run)" if ex.get("dry_run") else ""), "refused": "execution refused"}
    tail = f"; {done[ex['status']]}" if ex.get("status") in done else ""
    v.headline = f"{n} seam{'s' if n != 1 else ''} found and planned{tail}"
    v.status = "attention" if (v.attention or ex.get("status") == "refused") else "ok"
    return v


def _seam_table(measures: list[SeamMeasures], sim: bool) -> tuple[list[str], list[list], list[str]]:
    cols = [
        "seam",
        "joint",
        "length [mm]",
        "seam points",
        "torch poses",
        "work angle [°]",
        "travel angle [°] (+ push)",
        "standoff [mm]",
    ]
    if sim:
        cols += ["true seam", "position RMS [mm]", "position max [mm]", "orientation RMS [°]"]
    rows, marks = [], []
    for s in measures:
        row = [
            s.id,
            s.joint + (" (closed)" if s.closed else ""),
            round(1e3 * s.length, 1),
            s.points,
            s.poses,
            _spread(s.work_angle, 180 / np.pi),
            _spread(s.travel_angle, 180 / np.pi),
            _spread(s.standoff, 1e3),
        ]
        mark = ""
        if sim:
            e = s.error
            if e:
                row += [
                    s.truth,
                    round(1e3 * e["translation_m"], 2),
                    round(1e3 * e["translation_max_m"], 2),
                    round(float(np.degrees(e["rotation_rad"])), 2),
                ]
                mark = "warn" if e["translation_max_m"] > SEAM_ERROR_ATTENTION else "ok"
            else:
                row += ["–", None, None, None]
        rows.append(row)
        marks.append(mark)
    return cols, rows, marks


def _md_table(cols: list[str], rows: list[list]) -> list[str]:
    from weldcell.sdk.html_report import format_value

    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(format_value(v) for v in r) + " |" for r in rows]
    return out


def _summary(ctx, scans, rec, clean, path, gt, notes) -> str:
    m = path.metrics
    lines = [f"weldcell scan-and-plan: {ctx.profile.name}", ""]
    lines.append(f"captures        {len(scans)}  (hand-eye: {ctx.figures.get('hand_eye_source')})")
    lines.append(f"model           {len(rec.cloud)} points, denoised {len(clean)} points")
    if len(rec.fitness):
        lines.append(
            f"ICP fitness     {np.mean(rec.fitness_before):.3f} -> {np.mean(rec.fitness):.3f} "
            "(mean over views)"
        )
    found = f"seams found     {len(path.seams)}" + (f" of {m.get('seams_true')} true" if gt else "")
    coverage = m.get("coverage") or []
    if coverage:  # "1 of 1" must not hide a seam found over a quarter of its length
        found += "; covered " + ", ".join(
            f"{c['found_mm']:.0f} of {c['length_mm']:.0f} mm ({100 * c['fraction']:.0f} %)" for c in coverage
        )
    lines.append(found)
    for seam in path.seams:
        lines.append(
            f"  {seam.id:>4}  {seam.joint:<8} {seam.length * 1000:7.1f} mm  {len(seam.poses)} torch poses"
            + ("  closed" if seam.closed else "")
        )
    if gt and "f1" in m:
        lines.append(f"F1 (eq. 21)     {m['f1']['f1']:.3f}")
        lines.append(
            f"pose RMSE       {m['translation_rmse_mm']:.2f} mm, {m['rotation_rmse_deg']:.2f} deg (eq. 22)"
        )
    timings = ", ".join(
        f"{k.split(' (')[0]} {v:.2f}s" for k, v in ctx.timings.items() if not k.startswith("open")
    )
    lines.append(f"timings         {timings}")
    lines.append("")
    lines.append(
        "files           weld_path.json, model.ply, model_denoised.ply, programs/, "
        "report/report.html (open it in a browser), report/report.md"
    )
    for note in notes or []:
        lines += ["", note]
    return "\n".join(lines) + "\n"


def _fitness_rows(rec) -> list[list]:
    t, r = correction_sizes(rec)
    acc = list(getattr(rec, "accepted", [True] * len(rec.fitness)))
    return [
        [
            i,
            round(float(rec.fitness_before[i]), 3),
            round(float(rec.fitness[i]), 3),
            round(1e3 * float(t[i]), 2),
            round(float(np.degrees(r[i])), 2),
            "yes" if acc[i] else "rejected",
        ]
        for i in range(len(rec.fitness))
    ]


FITNESS_COLUMNS = ["view", "fitness before", "fitness after", "correction [mm]", "correction [°]", "kept"]
FITNESS_TEXT = (
    "Fitness (eq. 20) is the share of a view's points that lie within the fitness distance of the model "
    "merged from the views before it. It is bounded by overlap: a view that sees new parts of the work "
    "scores low without being wrong, so judge ICP by the change, not the level. Good: fitness after ≥ "
    "before (a correction that lowers it by more than 0.02 is rejected automatically) and a correction "
    "of a few mm and under a degree, i.e. the robot's kinematics and the hand-eye were already close. "
    "A large correction on many views points at a wrong hand-eye calibration."
)


def write_report(ctx, scans, rec, clean, extraction, path, gt, notes: list[str] | None = None) -> None:
    """summary.txt (with ``notes`` at its end), report/report.html, report/report.md and its pictures:
    every file written whole, atomically and durably (never appended in place)."""
    measures = seam_measures(path, gt)
    v = verdict(ctx, rec, path, gt, measures)
    summary = _summary(ctx, scans, rec, clean, path, gt, notes)
    ctx.write_text("summary.txt", summary)
    sim = bool(gt)
    page = ReportPage(
        ctx.path("report/report.html").parent,
        f"Scan-and-plan: {ctx.profile.name}",
        f"run folder {ctx.run_dir.name}" + (" · simulated cell (ground truth known)" if sim else ""),
        files=[
            ["weld_path.json", "seams and torch poses (weldcell/weld-path@1)"],
            ["model.ply", "merged model"],
            ["model_denoised.ply", "the model after denoising"],
        ]
        + [[p, "robot program"] for p in ctx.figures.get("programs", [])],
    )
    write_pages(page, v, summary, rec, np.asarray(clean.points, dtype=float), path, gt, measures)


def write_pages(page: ReportPage, v: Verdict, summary: str, rec, pts, path, gt, measures) -> list[Path]:
    """``report.html``, ``report.md`` and the PNGs of a seam report into ``page.out_dir`` (``rec`` None:
    no reconstruction section). Returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim = bool(gt)
    spacing = point_spacing(pts)
    pictures: list[tuple[str, str, Any]] = []  # (file, caption, figure)
    pictures.append(
        (
            "seams.png",
            "Where on the part are the seams, and which way does each run? Top view, arrow = travel"
            + ("; the dashed green lines are the true seams." if sim else "."),
            overview_figure(pts, path, gt),
        )
    )
    gt_by_seam = {}
    for s in measures:
        name = str(s.truth).split("/")[0] if s.truth else None
        gt_by_seam[s.id] = next((g.points for n, g in gt or [] if n == name), None)
    for seam, s in zip(path.seams, measures, strict=True):
        pictures.append(
            (
                f"seam_{seam.id}.png",
                f"Seam {seam.id}: does the torch point into the joint at the right standoff and angle? Cuts "
                f"across the joint near its start, middle and end (the {page.cloud_label}'s points "
                f"{3 * 1e3 * spacing:.1f} mm thick), red x the seam found"
                + (", green + the true seam." if sim else "."),
                cross_section_figure(pts, seam, s, gt_by_seam.get(seam.id), spacing),
            )
        )
    if sim and any(s.error_along is not None for s in measures):
        pictures.append(
            (
                "seam_error.png",
                "Where along each seam is the found line off the true one, and by how much?",
                seam_error_figure(measures, SEAM_ERROR_ATTENTION),
            )
        )
    if _has_views(rec):
        pictures.append(
            (
                "fitness.png",
                "Did ICP improve each view's fit, and how far did it move the view?",
                fitness_figure(rec),
            )
        )
    page.out_dir.mkdir(parents=True, exist_ok=True)
    rendered, written = [], []  # each picture drawn once: the same PNG is the file and the HTML's data URI
    for name, caption, fig in pictures:
        png = figure_png(fig, dpi=110)
        plt.close(fig)
        written.append(write_bytes(page.out_dir / name, png))
        rendered.append((name, caption, png))
    written.insert(0, _write_html(page, v, summary, rec, pts, path, gt, measures, rendered))
    written.insert(1, _write_md(page, v, summary, rec, measures, sim, rendered))
    return written


def _has_views(rec) -> bool:
    return rec is not None and len(rec.fitness) > 0


def _write_md(page: ReportPage, v: Verdict, summary: str, rec, measures, sim: bool, pictures) -> Path:
    from weldcell.sdk.secrets import redact

    md = [f"# {page.md_title}", "", f"**{v.status.upper()}: {v.headline}**", ""]
    for title, items in (
        ("Found", v.found),
        ("Refused, and why", v.refused),
        ("Needs a person", v.attention),
    ):
        if items:
            md += [f"{title}:", ""] + [f"- {x}" for x in items] + [""]
    md += ["Open `report.html` (next to this file) in a browser for the interactive 3-D view.", ""]
    md += ["## Seams", ""] + _md_table(*_seam_table(measures, sim)[:2]) + [""]
    md += ["## Summary", "", "```", summary.rstrip(), "```", ""]
    if _has_views(rec):
        md += (
            ["## ICP per view", "", FITNESS_TEXT, ""] + _md_table(FITNESS_COLUMNS, _fitness_rows(rec)) + [""]
        )
    md += ["## Pictures", ""]
    for name, caption, _ in pictures:
        md += [f"![{caption}]({name})", "", f"*{caption}*", ""]
    return write_text(page.out_dir / "report.md", redact("\n".join(md)))


def _write_html(page: ReportPage, v: Verdict, summary, rec, pts, path, gt, measures, pictures) -> Path:
    from weldcell.sdk.html_report import HtmlReport, Scene3D

    sim = bool(gt)
    rep = HtmlReport(page.title, page.subtitle)
    rep.set_verdict(v.status, v.headline, found=v.found, refused=v.refused, attention=v.attention)
    cols, rows, marks = _seam_table(measures, sim)
    sec = rep.section(
        "Seams",
        "One row per seam, in the planned welding order. Angles and standoff are measured from the planned "
        "torch poses against the seam's own frame (work angle: tilt about the travel direction away "
        "from the joint's bisector; travel angle: lean towards travel, + push, − drag); a range is shown "
        "when they vary along the seam.",
    )
    sec.table(
        cols,
        rows,
        caption="Seams found"
        + (
            f" (error against the true seams; flagged above {1e3 * SEAM_ERROR_ATTENTION:g} mm)" if sim else ""
        ),
        row_status=marks,
    )
    scene = Scene3D(f"{page.cloud_label}, seams and torch frames [mm]")
    scene.cloud(pts, page.cloud_label, max_points=30000)
    for _, s in gt or []:
        scene.line(s.points, f"true seam {s.id}", color="#2ca02c", width=3, dash="dash")
    for k, seam in enumerate(path.seams):
        scene.line(
            seam.points,
            f"{seam.id} ({seam.joint})",
            color=SEAM_COLOURS[k % len(SEAM_COLOURS)],
            closed=seam.closed,
        )
        scene.frames(seam.poses, f"torch {seam.id}", length=0.01, max_frames=30)
    rep.section(
        "3-D view",
        "Drag to turn, scroll to zoom, click a legend entry to hide it. Torch frames: orange = travel (x), "
        "blue = torch axis towards the work (z).",
    ).scene(scene)
    by_name = {name: (name, caption) for name, caption, _ in pictures}
    cuts = rep.section("Cross-sections", "Per seam, three cuts across the joint with the torch as planned.")
    for name, caption, fig in pictures:
        if name.startswith("seam_s"):
            cuts.figure(fig, caption)
    if "seam_error.png" in by_name or "seams.png" in by_name:
        where = rep.section("Where the seams are")
        for name, caption, fig in pictures:
            if name in ("seams.png", "seam_error.png"):
                where.figure(fig, caption)
    if _has_views(rec):
        icp = rep.section("Reconstruction: ICP per view", FITNESS_TEXT)
        icp.table(
            FITNESS_COLUMNS,
            _fitness_rows(rec),
            row_status=["" if r[-1] == "yes" else "bad" for r in _fitness_rows(rec)],
        )
        for name, caption, fig in pictures:
            if name == "fitness.png":
                icp.figure(fig, caption)
    files = rep.section("Files and summary")
    if page.files:
        files.table(["file", "what it is"], page.files)
    files.preformatted(summary)
    return rep.write(page.out_dir / "report.html")
