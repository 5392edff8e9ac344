"""The localize-and-weld report: pictures a welding engineer looks at, summary.txt and report.md.

* ``localization.png`` (Fig. 11): the template at its planned (dotted) and found (blue) position over
  the edge points (red), with the re-planned welds;
* ``inspection.png`` (Figs. 7, 8): the inspection pattern over the planned part, the latency pass marked;
* ``scan.png``: the measured heights (the point cloud seen from above);
* ``members.png``: each member's own offset after the rigid fit against the tolerance;
* ``summary.txt``: x, y, theta, fit error, covariance, member notes, failures -- and what to do.

Every picture is written atomically (``ctx.save_figure``).
"""

from __future__ import annotations

import math

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _outline(ax, P: np.ndarray, **kw) -> None:
    Q = np.vstack([P, P[:1]]) * 1e3
    ax.plot(Q[:, 0], Q[:, 1], **kw)


def fig_localization(template, edges, loc, truth=None):
    from weldcell.plugins.localize.pose import apply_xy

    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 7))
    for i, m in enumerate(template.members):
        _outline(ax, m.outline, color="0.4", ls=":", lw=1.2, label="planned" if i == 0 else None)
        _outline(
            ax,
            apply_xy(loc.pose, loc.center, m.outline),
            color="tab:blue",
            lw=1.4,
            label="found" if i == 0 else None,
        )
    if truth is not None:
        for i, P in enumerate(truth.outlines):
            _outline(
                ax, P, color="tab:green", lw=0.8, alpha=0.7, label="true (simulated)" if i == 0 else None
            )
    xy = edges.xy * 1e3
    ax.plot(xy[:, 0], xy[:, 1], ".", ms=1.5, color="tab:red", label=f"edge points ({len(xy)})")
    for w in loc.welds:
        P = np.asarray(w["points"]) * 1e3
        ax.plot(P[:, 0], P[:, 1], "-", color="darkorange", lw=3, alpha=0.8)
    ax.plot([], [], "-", color="darkorange", lw=3, label="re-planned welds")
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm] (robot base)")
    ax.set_ylabel("y [mm]")
    ax.set_title(
        f"{loc.status}: x {loc.pose[0] * 1e3:.2f} mm, y {loc.pose[1] * 1e3:.2f} mm, "
        f"theta {math.degrees(loc.pose[2]):.3f} deg, mean error {loc.fit_error_mean * 1e3:.3f} mm"
    )
    ax.legend(loc="best", fontsize=8)
    return fig


def fig_inspection(template, plan):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 7))
    for m in template.members:
        Q = np.vstack([m.outline, m.outline[:1]]) * 1e3
        ax.fill(Q[:, 0], Q[:, 1], color="0.85", ec="0.3")
        c = m.outline.mean(axis=0) * 1e3
        ax.text(c[0], c[1], m.id, fontsize=7, ha="center", va="center")
    for ln, kind in zip(plan.lines, plan.kinds, strict=True):
        P = ln * 1e3
        style = {"latency-fwd": ("tab:red", 2.0), "latency-back": ("tab:red", 2.0), "transit": ("0.6", 0.6)}
        color, lw = style.get(kind, ("tab:blue", 0.8))
        ax.plot(P[:, 0], P[:, 1], "-", color=color, lw=lw)
    ax.plot(
        [],
        [],
        "-",
        color="tab:blue",
        label=f"{plan.kind} inspection ({plan.length:.2f} m, {plan.duration:.1f} s)",
    )
    ax.plot([], [], "-", color="tab:red", lw=2, label="latency pass (forward + back)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_title("inspection pattern over the planned part")
    ax.legend(loc="best", fontsize=8)
    return fig


def fig_scan(scan):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 7))
    ok = np.isfinite(scan.xyz[:, 2])
    step = max(1, int(len(ok) // 30000))
    P = scan.xyz[::step][ok[::step]]
    sc = ax.scatter(P[:, 0] * 1e3, P[:, 1] * 1e3, c=P[:, 2] * 1e3, s=0.5, cmap="viridis", rasterized=True)
    bad = scan.xyz[::step][~ok[::step]]
    ax.plot(bad[:, 0] * 1e3, bad[:, 1] * 1e3, ",", color="tab:red")
    fig.colorbar(sc, ax=ax, label="z [mm] (red: no reading)")
    ax.set_aspect("equal")
    ax.set_title(f"laser readings: {len(scan)} ({(~ok).mean():.1%} without a value)")
    return fig


def fig_members(loc, tolerance: float):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4))
    ids = [m.id for m in loc.members]
    off = [np.linalg.norm(m.offset) * 1e3 if m.status != "not_observed" else np.nan for m in loc.members]
    colors = [
        "tab:red" if m.status == "outside_tolerance" else "0.5" if m.status == "not_observed" else "tab:blue"
        for m in loc.members
    ]
    ax.bar(ids, off, color=colors)
    ax.axhline(tolerance * 1e3, color="tab:red", ls="--", label=f"tolerance {tolerance * 1e3:.1f} mm")
    ax.set_ylabel("member offset after the rigid fit [mm]")
    ax.set_title("per-member residuals (grey: not observed)")
    ax.legend(fontsize=8)
    fig.autofmt_xdate()
    return fig


def summary_text(template, plan, scan, edges, loc, path, truth, figures: dict) -> str:
    sig = loc.to_json()["sigma"]
    lines = [
        "localize-and-weld (paper 002)",
        f"status: {loc.status}",
        f"message: {loc.message}",
        f"x: {loc.pose[0] * 1e3:.3f} mm   y: {loc.pose[1] * 1e3:.3f} mm   "
        f"theta: {math.degrees(loc.pose[2]):.4f} deg"
        "   (about the template centroid "
        f"({loc.center[0] * 1e3:.1f}, {loc.center[1] * 1e3:.1f}) mm)",
        f"fit error (mean): {loc.fit_error_mean * 1e3:.3f} mm   "
        f"inliers: {loc.inlier_fraction:.1%} of {loc.n_points}",
        "sigma x/y/theta: "
        + " / ".join(
            "n/a"
            if sig[k] is None
            else (f"{sig[k] * 1e3:.3f} mm" if k != "theta" else f"{math.degrees(sig[k]):.4f} deg")
            for k in ("x", "y", "theta")
        ),
        "covariance (x [m], y [m], theta [rad]):",
        *("  " + "  ".join(f"{v: .3e}" for v in row) for row in np.asarray(loc.covariance)),
        "",
        f"inspection: {plan.kind}, {len(plan.lines)} lines, {plan.length:.2f} m, "
        f"{plan.duration:.1f} s planned; "
        f"{len(scan)} readings, {len(edges)} edge points",
        f"latency: {figures.get('acquisition', {}).get('latency_s')}",
        "members:",
    ]
    for m in loc.members:
        lines.append(
            f"  {m.id}: {m.status}, {m.points} points, offset "
            f"{np.linalg.norm(m.offset) * 1e3:.2f} mm, {math.degrees(m.dtheta):.3f} deg"
        )
    if truth is not None:
        e = figures.get("localization", {}).get("error_vs_truth", {})
        lines.append(
            f"simulated truth: x {truth.pose[0] * 1e3:.2f} mm, y {truth.pose[1] * 1e3:.2f} mm, "
            f"theta {math.degrees(truth.pose[2]):.3f} deg; error "
            + ", ".join(f"{k} {v:.3f}" for k, v in e.items())
        )
    if path is not None:
        lines.append(
            f"weld path: {len(path.seams)} seams; "
            + (
                f"against the true seams: mean {path.metrics['mean_mm']:.3f} mm, "
                f"max {path.metrics['max_mm']:.3f} mm"
                if "max_mm" in path.metrics
                else "no ground truth"
            )
        )
    if not loc.ok:
        lines += [
            "",
            "FAILED: no weld was started. Weld this workpiece by hand, or re-place it and run again.",
        ]
    return "\n".join(lines) + "\n"


def write_report(ctx, template, plan, scan, edges, loc, path, truth) -> None:
    plt = _plt()
    for name, fig in (
        ("localization.png", fig_localization(template, edges, loc, truth)),
        ("inspection.png", fig_inspection(template, plan)),
        ("scan.png", fig_scan(scan)),
        ("members.png", fig_members(loc, ctx.stage_settings("localize").member_tolerance)),
    ):
        ctx.save_figure(fig, name, dpi=90)
        plt.close(fig)
    text = summary_text(template, plan, scan, edges, loc, path, truth, ctx.figures)
    ctx.write_text("summary.txt", text)
    md = ["# localize-and-weld", "", "```", text.rstrip(), "```", ""]
    for name, title in (
        ("localization.png", "Planned (dotted) and found (blue) template over the edge points"),
        ("inspection.png", "Inspection pattern"),
        ("scan.png", "Laser readings"),
        ("members.png", "Per-member residuals"),
    ):
        md += [f"## {title}", "", f"![{title}]({name})", ""]
    ctx.write_text("report.md", "\n".join(md))
