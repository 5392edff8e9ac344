"""Report of the ``map`` job: report.md with the figures, trajectory and map pictures."""

from __future__ import annotations

import numpy as np
from weldcell.sdk import artifacts


def write_report(ctx, tr, rig, regions, figures: dict, A: np.ndarray | None) -> None:
    """report.md + trajectory.png (estimated vs truth, top view) + map.png (map with weld regions)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    est = tr.estimator
    _, T_kf = est.keyframe_trajectory()
    P = T_kf[:, :3, 3]
    if A is not None:
        P = P @ A[:3, :3].T + A[:3, 3]
    fig, ax = plt.subplots(figsize=(10, 4.5))
    if tr.truth_frames:
        G = np.array([T[:3, 3] for _, T in tr.truth_frames])
        ax.plot(G[:, 0], G[:, 1], "k-", lw=1, label="ground truth (camera)")
    ax.plot(
        P[:, 0],
        P[:, 1],
        "r.-",
        ms=2,
        lw=0.8,
        label="estimated key frames" + (" (aligned)" if A is not None else ""),
    )
    lost = [e["t"] for e in est.events if e["kind"] == "lost"]
    if lost:
        t_kf = np.array([k.t for k in est.keyframes])
        idx = np.clip(np.searchsorted(t_kf, lost), 0, len(P) - 1)
        ax.plot(P[idx, 0], P[idx, 1], "bx", label="tracking lost")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(f"trajectory (ATE {figures.get('ate_rmse_m', float('nan')):.3f} m)")
    fig.tight_layout()
    fig.savefig(ctx.path("report/trajectory.png"), dpi=110)
    plt.close(fig)

    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(ctx.path("map/map.ply")))
    M, C = np.asarray(pc.points), np.asarray(pc.colors)
    if A is not None and len(M):
        M = M @ A[:3, :3].T + A[:3, 3]
    fig, ax = plt.subplots(figsize=(10, 4.5))
    if len(M):
        sel = np.random.default_rng(0).choice(len(M), min(len(M), 60000), replace=False)
        ax.scatter(M[sel, 0], M[sel, 1], c=C[sel], s=0.3)
    for r in regions:
        c = r.center if A is None else A[:3, :3] @ r.center + A[:3, 3]
        col = {"rejected": "grey", "unconfirmed": "orange"}.get(r.decision, "red")
        ax.plot(c[0], c[1], "s", mfc="none", mec=col, ms=10)
        ax.annotate(f"{r.id} ({r.decision})", c[:2], fontsize=7, color=col)
    ax.set_aspect("equal")
    ax.set_title("map (top view) with weld regions")
    fig.tight_layout()
    fig.savefig(ctx.path("report/map.png"), dpi=110)
    plt.close(fig)

    lines = [f"# Map run: {ctx.profile.name}", "", "| figure | value |", "|---|---|"]
    for k, v in figures.items():
        if k != "time_per_stage":
            lines.append(f"| {k} | {v:.4f} |" if isinstance(v, float) else f"| {k} | {v} |")
    lines += [
        "",
        "## Time per frame and stage (this machine)",
        "",
        "| stage | mean ms | std ms | n |",
        "|---|---|---|---|",
    ]
    for k, v in figures.get("time_per_stage", {}).items():
        lines.append(f"| {k} | {v['mean_ms']:.1f} | {v['std_ms']:.1f} | {v['n']} |")
    lines += ["", "## Weld regions", "", "| id | decision | observations | points |", "|---|---|---|---|"]
    for r in regions:
        lines.append(f"| {r.id} | {r.decision} | {len(r.observations)} | {len(r.points)} |")
    lines += ["", "## Events", ""] + [f"- t={e['t']} s {e['kind']}: {e['message']}" for e in est.events]
    lines += ["", "![trajectory](trajectory.png)", "", "![map](map.png)", ""]
    artifacts.write_text(ctx.path("report/report.md"), "\n".join(lines))


_SEG_KEYS = (
    "segments",
    "segment_handovers",
    "first_segment_written_s",
    "map_complete_s",
    "fetch_ok",
    "fetch_segments",
    "fetch_first_segment_s",
    "ate_unsegmented_m",
    "ate_segmented_m",
    "ate_segmentation_change_pct",
    "ae_unsegmented_mm",
    "ae_segmented_mm",
    "ae_segmentation_change_pct",
)


def append_report(ctx, figures: dict) -> None:
    """The local maps (§II-D, Table III) and the second visit (§II-E) appended to report.md."""
    path = ctx.path("report/report.md")
    text = path.read_text(encoding="utf-8") if path.is_file() else f"# Map run: {ctx.profile.name}\n"
    lines = ["", "## Local maps (§II-D) and their transmission", "", "| figure | value |", "|---|---|"]
    for k in _SEG_KEYS:
        if k in figures:
            v = figures[k]
            lines.append(f"| {k} | {v:.4f} |" if isinstance(v, float) else f"| {k} | {v} |")
    v2 = figures.get("visit2")
    if v2:
        lines += [
            "",
            "## Second visit: relocalization and map update (§II-E)",
            "",
            "| figure | value |",
            "|---|---|",
        ]
        for k, v in v2.items():
            if isinstance(v, list) and k != "changes":
                v = ", ".join(map(str, v)) or "none"
            if isinstance(v, dict | list):
                continue
            lines.append(f"| {k} | {v:.4f} |" if isinstance(v, float) else f"| {k} | {v} |")
        for ch in v2.get("changes", []):
            lines.append(
                f"- {ch['kind']} structure: {ch['points']} points around {ch['center']} "
                f"(segment {ch['segment']})"
            )
        for name in ("visits.png", "changes.png"):
            if ctx.path(f"report/{name}").is_file():
                lines += ["", f"![{name[:-4]}]({name})"]
    from weldcell.sdk import artifacts

    artifacts.write_text(path, text.rstrip("\n") + "\n" + "\n".join(lines) + "\n")
