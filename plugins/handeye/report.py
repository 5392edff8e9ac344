"""Hand-eye reports: the operator's summary (shared by the job and the CLI), summary.txt, report.md
and plots (error against the number of samples like paper 003 Fig. 10/11, residual per sample)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from weldcell.plugins.handeye.result import HandEyeResult
from weldcell.sdk.artifacts import save_figure, write_text
from weldcell.sdk.geometry import T_to_rpy, pose_error


def summary_lines(result: HandEyeResult, truth: np.ndarray | None = None) -> list[str]:
    """What an operator reads: the transform, residuals, inliers/outliers with reasons, diversity
    warnings and the confidence (bootstrap), one fact per line."""
    m = result.metrics
    T = np.asarray(result.T)
    rpy = np.degrees(T_to_rpy(T))
    res = np.asarray(result.residuals, float) * 1e3
    inl = np.asarray(result.inliers, bool)
    idx = m.get("sample_index") or list(range(len(res)))
    to, frm = result.name.split("_")[1], result.name.split("_")[-1]
    lines = [
        f"{result.name:<15} xyz [{T[0, 3] * 1e3:.2f}, {T[1, 3] * 1e3:.2f}, {T[2, 3] * 1e3:.2f}] mm   "
        f"rpy [{rpy[0]:.3f}, {rpy[1]:.3f}, {rpy[2]:.3f}] deg",
        f"configuration   {result.config}, method {result.method}",
        f"convention      p_{to} = {result.name} @ p_{frm} (metres)",
    ]
    ok = np.isfinite(res)
    if ok.any():
        r_in = res[inl & ok]
        it = result.method == "flange-iterative"
        kept, other = ("in Algorithm 1's pool", "others") if it else ("inliers", "outliers")
        lines.append(
            f"samples         {len(res)} ({int(inl.sum())} {kept}, {int((~inl & ok).sum())} "
            f"{other}, {int((~ok).sum())} without a flange)"
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
    q = result.extra.get("feature_base")
    if q is not None:
        q = np.asarray(q, float) * 1e3
        lines.append(f"feature         in the base frame [{q[0]:.2f}, {q[1]:.2f}, {q[2]:.2f}] mm (estimated)")
    b = m.get("bootstrap") or {}
    if "t_std" in b:
        t = np.asarray(b["t_std"]) * 1e3
        lines.append(
            f"confidence      bootstrap std t [{t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}] mm, rotation "
            f"{np.degrees(b['rot_std']):.3f} deg ({b['n']} resamples)"
        )
    if truth is not None:
        dt, dr = pose_error(T, truth)
        lines.append(f"vs ground truth {dt * 1e3:.3f} mm, {np.degrees(dr):.4f} deg (simulated camera mount)")
    for w in result.warnings:
        if not w.startswith("skipped "):
            lines.append(f"warning         {w}")
    return lines


def _plots(folder: Path, result: HandEyeResult, track: list[dict], truth) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    res = np.asarray(result.residuals, float) * 1e3
    inl = np.asarray(result.inliers, bool)
    idx = result.metrics.get("sample_index") or list(range(len(res)))
    fig, ax = plt.subplots(figsize=(7, 3.8))
    x = np.arange(len(res))
    ax.bar(x[inl], np.nan_to_num(res[inl]), color="tab:blue", label="inlier")
    ax.bar(x[~inl], np.nan_to_num(res[~inl]), color="tab:red", label="outlier")
    ax.set_xticks(x, [str(i) for i in idx], fontsize=7, rotation=90 if len(x) > 25 else 0)
    ax.set_xlabel("sample (pose index)")
    ax.set_ylabel("residual |T p_cam - p_base| [mm]")
    ax.set_title(f"residual per sample ({result.method})")
    ax.legend()
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
    md = ["# Hand-eye calibration report", "", "```", summary.rstrip(), "```", ""]
    md += [f"![{p[:-4]}]({p})" for p in pictures]
    ctx.write_text("report/report.md", "\n".join(md) + "\n")


def write_offline_report(folder: Path, result: HandEyeResult, summary: list[str]) -> list[str]:
    """The CLI's ``--report DIR``: summary.txt, report.md and the residual plot."""
    folder.mkdir(parents=True, exist_ok=True)
    pictures = _plots(folder, result, [], None)
    text = "\n".join(summary) + "\n"
    write_text(folder / "summary.txt", text)
    write_text(
        folder / "report.md",
        "\n".join(
            [
                "# Hand-eye calibration report",
                "",
                "```",
                text.rstrip(),
                "```",
                "",
                *[f"![{p[:-4]}]({p})" for p in pictures],
            ]
        )
        + "\n",
    )
    return ["summary.txt", "report.md", *pictures]
