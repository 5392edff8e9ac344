"""Hand-eye reports: the operator's summary (shared by the job and the CLI), summary.txt, report.md
and plots (error against the number of samples like paper 003 Fig. 10/11, residual per sample)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from weldcell.sdk.artifacts import save_figure, write_text
from weldcell.sdk.geometry import T_to_rpy, pose_error
from weldcell.sdk.handeye_files import HandEyeResult


def summary_lines(result: HandEyeResult, truth: np.ndarray | None = None) -> list[str]:
    """What an operator reads: the transform, residuals, inliers/outliers with reasons, diversity
    warnings and the confidence (bootstrap), one fact per line."""
    m = result.metrics
    T = np.asarray(result.T)
    rpy = np.degrees(T_to_rpy(T))
    res = np.asarray(result.residuals, float) * 1e3
    inl = np.asarray(result.inliers, bool)
    idx = sample_labels(result)
    to, frm = result.name.split("_")[1], result.name.split("_")[-1]
    lines = [
        f"{result.name:<15} xyz [{T[0, 3] * 1e3:.2f}, {T[1, 3] * 1e3:.2f}, {T[2, 3] * 1e3:.2f}] mm   "
        f"rpy [{rpy[0]:.3f}, {rpy[1]:.3f}, {rpy[2]:.3f}] deg",
        f"configuration   {result.config}, method {result.method}",
        f"convention      p_{to} = {result.name} @ p_{frm} (metres)",
    ]
    lines += _sample_lines(result, res, inl, idx)
    lines += _online_lines(m)
    q = result.extra.get("feature_base")
    if q is not None:
        q = np.asarray(q, float) * 1e3
        lines.append(f"feature         in the base frame [{q[0]:.2f}, {q[1]:.2f}, {q[2]:.2f}] mm (estimated)")
    lines += _confidence_lines(m, idx)
    intr = m.get("intrinsics")
    if intr:
        how = f", RMS {intr['rms_px']:.3f} px over {intr['images']} photos" if intr.get("rms_px") else ""
        K = intr["K"]
        lines.append(f"intrinsics      {intr['source']}: fx {K[0][0]:.1f} fy {K[1][1]:.1f} px{how}")
    for b in m.get("board_not_found", []):
        lines.append(f"  no board      sample {b}")
    if truth is not None:
        dt, dr = pose_error(T, truth)
        lines.append(f"vs ground truth {dt * 1e3:.3f} mm, {np.degrees(dr):.4f} deg (simulated camera mount)")
    for w in result.warnings:
        if not w.startswith("skipped "):
            lines.append(f"warning         {w}")
    return lines


def _sample_lines(result: HandEyeResult, res: np.ndarray, inl: np.ndarray, idx: list[str]) -> list[str]:
    """Samples kept and left out (residuals in mm), each outlier with its reason."""
    m = result.metrics
    lines: list[str] = []
    ok = np.isfinite(res)
    if ok.any():
        r_in = res[inl & ok]
        it = result.method == "flange-iterative"
        kept, other = ("in Algorithm 1's pool", "others") if it else ("inliers", "outliers")
        board = "intrinsics" in m or "board_not_found" in m
        lines.append(
            f"samples         {len(res)} ({int(inl.sum())} {kept}, {int((~inl & ok).sum())} "
            f"{other}, {int((~ok).sum())} without {'the board' if board else 'a flange'})"
        )
        if len(r_in):
            lines.append(
                f"residuals       inliers rms {np.sqrt(np.mean(r_in**2)):.3f} mm, median "
                f"{np.median(r_in):.3f} mm, max {r_in.max():.3f} mm"
            )
    thr = m.get("inlier_threshold")
    if result.method == "flange-iterative":
        rest = np.flatnonzero(~inl & ok)
        if len(rest):
            k = rest[np.argmax(res[rest])]
            lines.append(
                f"  not in pool   {len(rest)} samples: residual median {np.median(res[rest]):.3f} mm, max "
                f"{res[k]:.2f} mm (sample {idx[k] if k < len(idx) else k})"
            )
    else:
        for j in np.flatnonzero(~inl):
            why = (
                "no flange centre"
                if not ok[j]
                else f"residual {res[j]:.2f} mm > threshold {thr * 1e3:.2f} mm"
                if thr
                else f"residual {res[j]:.2f} mm"
            )
            lines.append(f"  outlier       sample {idx[j] if j < len(idx) else j}: {why}")
    return lines


def _online_lines(m: dict) -> list[str]:
    """Algorithm 1's pool and the online run of the ``calibrate`` job (poses visited, why it stopped)."""
    lines: list[str] = []
    if "pool" in m and "online" not in m:
        lines.append(
            f"Algorithm 1     pool {m['pool']}, cost {m['cost'] * 1e3:.3f} mm, "
            f"{'converged' if m.get('converged') else 'not converged'}"
        )
    on = m.get("online")
    if on:
        lines.append(
            f"poses           {on['visited']} of {on['planned']} visited, {on['centres']} centres, "
            f"{on['refused']} refused by the safety gate, {on['no_flange']} without a flange"
        )
        if "pool" in on:
            lines.append(
                f"Algorithm 1     cost {on['pool_cost_m'] * 1e3:.3f} mm, pool = poses {on['pool']}; "
                f"stopped: {on['stop']}"
            )
        else:
            lines.append(
                f"estimate        predicted error (1 sigma) {on['predicted_error_m'] * 1e3:.3f} mm; "
                f"stopped: {on['stop']}"
            )
    return lines


def sample_labels(result: HandEyeResult) -> list[str]:
    """The user's sample names (``metrics["sample_ids"]``: file stems, timestamps), else the indices."""
    m = result.metrics
    n = len(np.atleast_1d(result.residuals))
    ids = m.get("sample_ids") or m.get("sample_index") or list(range(n))
    ids = [str(i) for i in ids]
    return ids if len(ids) == n else [str(i) for i in range(n)]


def _confidence_lines(m: dict, ids: list[str]) -> list[str]:
    """The confidence the summary quotes: the analytic covariance or the bootstrap (whichever
    :func:`~weldcell.plugins.handeye.diagnostics.point_confidence` chose, with why), and the sample
    whose removal moves the answer most."""
    conf = m.get("confidence") or {}
    src = conf.get(conf.get("method", ""), {}) if conf else {}
    label = conf.get("method", "bootstrap")
    if not src:
        src, label = m.get("bootstrap") or {}, "bootstrap"
    if "t_std" not in src:
        return []
    t = np.asarray(src["t_std"]) * 1e3
    how = f"{src['n']} resamples" if label == "bootstrap" else conf.get("why", "")
    lines = [
        f"confidence      1 sigma t [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] mm "
        f"(|t| {src['t_std_norm'] * 1e3:.3f} mm), rotation {np.degrees(src['rot_std']):.3f} deg; "
        f"{label}: {how}"
    ]
    loo = conf.get("leave_one_out_m") or []
    vals = [(i, v) for i, v in enumerate(loo) if v is not None]
    if vals:
        i, v = max(vals, key=lambda p: p[1])
        name = ids[i] if i < len(ids) else str(i)
        lines.append(f"leave-one-out   largest shift {v * 1e3:.3f} mm without sample {name}")
    return lines


def _plots(folder: Path, result: HandEyeResult, track: list[dict], truth) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    res = np.asarray(result.residuals, float) * 1e3
    inl = np.asarray(result.inliers, bool)
    idx = sample_labels(result)
    fig, ax = plt.subplots(figsize=(7, 3.8))
    _residual_bars(ax, result, res, inl, idx)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    save_figure(fig, folder / "residuals.png", dpi=110)
    plt.close(fig)
    written.append("residuals.png")

    if track:
        n = np.array([t["n"] for t in track])
        fig, axes = plt.subplots(
            1, 3 if truth is not None else 1, figsize=(15 if truth is not None else 6, 4)
        )
        axes = np.atleast_1d(axes)
        cost = np.array([t["cost"] for t in track]) * 1e3
        axes[0].semilogy(n[np.isfinite(cost)], cost[np.isfinite(cost)], "o-")
        axes[0].set_xlabel("samples collected")
        in_hand = result.config == "eye-in-hand"
        axes[0].set_ylabel("predicted error, 1 sigma [mm]" if in_hand else "Algorithm 1 cost [mm]")
        axes[0].set_title("uncertainty of the fit so far" if in_hand else "cost of the 4-pair pool")
        axes[0].grid(alpha=0.3, which="both")
        if truth is not None:
            for k, (key, label) in enumerate(
                (
                    ("pool_error", "Algorithm 1 (pool)"),
                    ("all_data_error", "all data (X c = inv(B) q)" if in_hand else "all data (eqs. 9-12)"),
                )
            ):
                rows = [(t["n"], *t[key]) for t in track if key in t]
                if not rows:
                    continue
                a = np.array(rows, float)
                axes[1].plot(a[:, 0], a[:, 1] * 1e3, "o-", label=label, color=f"C{k}")
                axes[2].plot(a[:, 0], np.degrees(a[:, 2]), "o-", label=label, color=f"C{k}")
            axes[1].set_ylabel("translation error vs truth [mm]")
            axes[2].set_ylabel("rotation error vs truth [deg]")
            for ax in axes[1:]:
                ax.set_xlabel("samples collected")
                ax.set_yscale("log")
                ax.grid(alpha=0.3, which="both")
                ax.legend()
            axes[1].set_title("error against the number of samples (cf. Fig. 10/11)")
        fig.tight_layout()
        save_figure(fig, folder / "convergence.png", dpi=110)
        plt.close(fig)
        written.append("convergence.png")
    return written


#: colours of the residual plot, one per kind of sample (an outlier never shares the inlier colour)
COLOURS = {"inlier": "tab:blue", "outlier": "tab:red", "missing": "tab:gray"}


def _residual_bars(ax, result: HandEyeResult, res: np.ndarray, inl: np.ndarray, idx: list[str]) -> None:
    """Bars of the residual per sample, coloured by kind; the legend lists only the kinds present."""
    from matplotlib.patches import Patch

    x = np.arange(len(res))
    ok = np.isfinite(res)
    it = result.method == "flange-iterative"
    names = {
        "inlier": "in Algorithm 1's pool" if it else "inlier (used in the fit)",
        "outlier": "not in the pool" if it else "outlier (left out)",
        "missing": "no flange found",
    }
    kinds = {"inlier": inl & ok, "outlier": ~inl & ok, "missing": ~ok}
    handles = []
    for kind, mask in kinds.items():
        if mask.any():
            ax.bar(x[mask], np.where(ok[mask], res[mask], 0.0), color=COLOURS[kind])
            handles.append(Patch(color=COLOURS[kind], label=f"{names[kind]} ({int(mask.sum())})"))
    thr = result.metrics.get("inlier_threshold")
    if thr:
        ax.axhline(thr * 1e3, color="k", ls="--", lw=0.8)
        handles.append(plt_line(f"inlier threshold {thr * 1e3:.2f} mm"))
    ax.set_xticks(x, idx, fontsize=7, rotation=90 if len(x) > 25 else 0)
    ax.set_xlabel("sample (your file/sample names)")
    ax.set_ylabel("error after calibration [mm]")
    ax.set_title(f"how far each flange centre lands from the robot's ({result.method})")
    ax.legend(handles=handles, fontsize=8)


def plt_line(label: str):
    from matplotlib.lines import Line2D

    return Line2D([0], [0], color="k", ls="--", lw=0.8, label=label)


RESIDUAL_CAPTION = (
    "Each bar is one sample: the distance between where the calibrated camera puts the flange centre and "
    "where the robot says it is (mm). Blue bars were used for the fit; red bars were left out as "
    "outliers (a false segmentation or a bad robot reading); grey marks a scan with no flange found. "
    "Good calibrations keep blue bars near the scanner's noise (a few tenths of a mm)."
)


def write_report(ctx, result: HandEyeResult, track: list[dict], notes: list[str], truth, stop: str) -> None:
    """summary.txt, report/report.md and report/*.png of the calibrate job."""
    folder = ctx.path("report/x").parent
    pictures = _plots(folder, result, track, truth)
    lines = [f"weldcell calibrate: {ctx.profile.name}", ""]
    lines += summary_lines(result, truth)
    for n in notes[:20]:
        lines.append(f"  skipped       {n}")
    if len(notes) > 20:
        lines.append(f"  ... and {len(notes) - 20} more (state.json notes)")
    timings = ", ".join(
        f"{k.split(' (')[0]} {v:.2f}s" for k, v in ctx.timings.items() if not k.startswith("open")
    )
    lines.append(f"timings         {timings}")
    lines.append("")
    lines.append("files           handeye.json, samples.json, captures/, report/report.md")
    summary = "\n".join(lines) + "\n"
    ctx.write_text("summary.txt", summary)
    ctx.write_text("report/report.md", _markdown(summary, pictures))
    try:
        write_html(
            ctx.path("report/report.html"),
            result,
            summary.rstrip().splitlines(),
            {p: folder / p for p in pictures},
        )
    except ImportError:
        pass


CONVERGENCE_CAPTION = (
    "How the calibration improved as samples were collected: the cost Algorithm 1 keeps (or the predicted "
    "error), and in simulation the true error, against the number of samples (cf. paper 003 Fig. 10/11)."
)


def _markdown(text: str, pictures: list[str]) -> str:
    captions = {"residuals.png": RESIDUAL_CAPTION, "convergence.png": CONVERGENCE_CAPTION}
    md = ["# Hand-eye calibration report", "", "```", text.rstrip(), "```", ""]
    for p in pictures:
        md += [f"![{p[:-4]}]({p})", "", captions.get(p, ""), ""]
    return "\n".join(md) + "\n"


def write_html(path: Path, result: HandEyeResult, summary: list[str], pictures: dict[str, Path]) -> Path:
    """report.html (self-contained, :mod:`weldcell.sdk.html_report`): verdict, the transform, the
    per-sample table (user's names, outliers marked) and the plots with their captions."""
    from weldcell.sdk.html_report import HtmlReport

    T = np.asarray(result.T)
    res = np.asarray(result.residuals, float) * 1e3
    inl = np.asarray(result.inliers, bool)
    ids = sample_labels(result)
    warn = [w for w in result.warnings if not w.startswith("skipped ")]
    out = [ids[j] for j in np.flatnonzero(~inl & np.isfinite(res))]
    rep = HtmlReport("Hand-eye calibration", subtitle=f"{result.name}: {result.config}, {result.method}")
    rep.set_verdict(
        "attention" if warn else "ok",
        f"{result.name} found from {int(inl.sum())} of {len(res)} samples",
        found=[f"{result.name} translation {np.round(T[:3, 3] * 1e3, 2).tolist()} mm"],
        refused=[f"sample {i}: left out as an outlier" for i in out],
        attention=warn,
    )
    sec = rep.section("Result", "The transform and what it is worth.")
    sec.preformatted("\n".join(summary))
    rows, marks = [], []
    for j, name in enumerate(ids):
        kind = "no flange" if not np.isfinite(res[j]) else ("inlier" if inl[j] else "outlier")
        rows.append([name, None if not np.isfinite(res[j]) else float(res[j]), kind])
        marks.append({"inlier": "", "outlier": "outlier", "no flange": "bad"}[kind])
    sec = rep.section("Samples", "One row per sample, named as in your data.")
    sec.table(["sample", "error after calibration [mm]", "used"], rows, row_status=marks)
    captions = {"residuals.png": RESIDUAL_CAPTION, "convergence.png": CONVERGENCE_CAPTION}
    for name, png in pictures.items():
        sec.figure(png, captions.get(name, name))
    return rep.write(path)


def write_offline_report(folder: Path, result: HandEyeResult, summary: list[str]) -> list[str]:
    """The CLI's ``--report DIR``: summary.txt, report.md, report.html and the plots."""
    folder.mkdir(parents=True, exist_ok=True)
    pictures = _plots(folder, result, [], None)
    text = "\n".join(summary) + "\n"
    write_text(folder / "summary.txt", text)
    write_text(folder / "report.md", _markdown(text, pictures))
    written = ["summary.txt", "report.md", *pictures]
    try:
        write_html(folder / "report.html", result, summary, {p: folder / p for p in pictures})
        written.insert(2, "report.html")
    except ImportError:  # the HTML builder is optional; report.md stays complete
        pass
    return written
