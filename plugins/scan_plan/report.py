"""The scan-and-plan report: summary.txt (what an operator reads), report.md and pictures."""

from __future__ import annotations

import numpy as np


def plot_cloud_and_paths(ax, cloud_pts, path, gt, view, rng, max_points=30000, frame_every=6):
    idx = rng.choice(len(cloud_pts), size=min(max_points, len(cloud_pts)), replace=False)
    P = cloud_pts[idx] * 1000
    a, b = {"top": (0, 1), "front": (0, 2), "side": (1, 2)}[view]
    ax.scatter(P[:, a], P[:, b], s=0.2, c=P[:, 2], cmap="Greys", alpha=0.5, rasterized=True)
    if gt:
        for i, (_, s) in enumerate(gt):
            g = s.points * 1000
            ax.plot(
                g[:, a], g[:, b], "--", color="tab:green", lw=1.2, label="ground truth" if i == 0 else None
            )
    for i, seam in enumerate(path.seams):
        q = seam.points * 1000
        ax.plot(q[:, a], q[:, b], "-", color="tab:red", lw=1.6, label="seam found" if i == 0 else None)
        T = seam.poses[::frame_every]
        o = T[:, :3, 3] * 1000
        for axis, color in ((0, "tab:orange"), (2, "tab:blue")):
            d = T[:, :3, axis] * 8
            ax.quiver(
                o[:, a],
                o[:, b],
                d[:, a],
                d[:, b],
                color=color,
                angles="xy",
                scale_units="xy",
                scale=1,
                width=0.003,
            )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("xyz"[a] + " [mm]")
    ax.set_ylabel("xyz"[b] + " [mm]")
    ax.set_title(f"{view} view (torch x orange, z blue)")


def write_report(ctx, scans, rec, clean, extraction, path, gt, notes: list[str] | None = None) -> None:
    """summary.txt (with ``notes`` at its end), report/report.md and its pictures: every file written
    whole, atomically and durably (never appended in place)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    fig, axes = plt.subplots(1, 3, figsize=(18, 6))
    for ax, view in zip(axes, ("top", "front", "side"), strict=True):
        plot_cloud_and_paths(ax, clean.points, path, gt, view, rng)
    axes[0].legend(loc="upper right")
    fig.suptitle(f"{ctx.profile.name}: {len(path.seams)} seam(s) on the reconstructed part")
    fig.tight_layout()
    ctx.save_figure(fig, "report/seams.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    views = np.arange(len(rec.fitness))
    ax.plot(views, rec.fitness_before, "o--", label="before ICP (kinematics + hand-eye)")
    ax.plot(views, rec.fitness, "o-", label="after linear ICP")
    ax.set_xlabel("view")
    ax.set_ylabel("fitness (eq. 20)")
    ax.set_ylim(0, 1.05)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    ctx.save_figure(fig, "report/fitness.png", dpi=110)
    plt.close(fig)

    m = path.metrics
    lines = [f"weldcell scan-and-plan: {ctx.profile.name}", ""]
    lines.append(f"captures        {len(scans)}  (hand-eye: {ctx.figures.get('hand_eye_source')})")
    lines.append(f"model           {len(rec.cloud)} points, denoised {len(clean)} points")
    if len(rec.fitness):
        lines.append(
            f"ICP fitness     {np.mean(rec.fitness_before):.3f} -> {np.mean(rec.fitness):.3f} "
            "(mean over views)"
        )
    lines.append(f"seams found     {len(path.seams)}" + (f" of {m.get('seams_true')} true" if gt else ""))
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
    lines.append("files           weld_path.json, model.ply, model_denoised.ply, programs/, report/report.md")
    for note in notes or []:
        lines += ["", note]
    summary = "\n".join(lines) + "\n"
    ctx.write_text("summary.txt", summary)
    md = [
        "# Scan-and-plan report",
        "",
        "```",
        summary.rstrip(),
        "```",
        "",
        "![seams and torch frames](seams.png)",
        "",
        "![ICP fitness per view](fitness.png)",
        "",
    ]
    ctx.write_text("report/report.md", "\n".join(md))
