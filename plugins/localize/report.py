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


def _latency_line(acquisition: dict) -> str:
    lat = acquisition.get("latency_s")
    if lat is None:
        return "latency: n/a"
    how = acquisition.get("latency", {})
    src = "estimated from the scan" if how.get("estimated", True) else how.get("reason", "from the settings")
    return f"sensor-robot latency: {lat * 1e3:.2f} ms ({src})"


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
        "covariance (x, y in m; theta in rad):",
        *("  " + "  ".join(f"{v: .3e}" for v in row) for row in np.asarray(loc.covariance)),
        "",
        f"inspection: {plan.kind}, {len(plan.lines)} lines, {plan.length:.2f} m, "
        f"{plan.duration:.1f} s planned; "
        f"{len(scan)} readings, {len(edges)} edge points",
        _latency_line(figures.get("acquisition", {})),
        "members:",
    ]
    for m in loc.members:
        lines.append(
            f"  {m.id}: {m.status}, {m.points} points, offset "
            f"{np.linalg.norm(m.offset) * 1e3:.2f} mm, {math.degrees(m.dtheta):.3f} deg"
        )
    if truth is not None:
        e = {"x_mm": math.nan, "y_mm": math.nan, "theta_deg": math.nan}
        e.update(figures.get("localization", {}).get("error_vs_truth", {}))
        lines.append(
            f"simulated truth: x {truth.pose[0] * 1e3:.2f} mm, y {truth.pose[1] * 1e3:.2f} mm, "
            f"theta {math.degrees(truth.pose[2]):.3f} deg; localization error x {e['x_mm']:.3f} mm, "
            f"y {e['y_mm']:.3f} mm, theta {e['theta_deg']:.4f} deg (against the placement; the members are "
            "off CAD, so part of it is theirs)"
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
    md += ["The interactive report (verdict, tables, 3-D view): `report/report.html`.", ""]
    ctx.write_text("report.md", "\n".join(md))
    write_html(ctx, template, plan, scan, edges, loc, path, truth)


# ------------------------------------------------------------------------------------ report/report.html
_MEMBER_WORDS = {
    "ok": "within tolerance",
    "outside_tolerance": "OUT OF TOLERANCE",
    "not_observed": "not observed",
}


def _verdict(loc, path, truth, figures: dict, tolerance: float) -> tuple[str, str, list, list, list]:
    """(status, headline, found, refused, attention) of the run, in the words a welding engineer uses."""
    found, refused, attention = [], [], []
    x, y, th = loc.pose
    if not loc.ok:
        refused.append(f"placement {loc.status}: {loc.message}")
        attention.append("no weld was started: weld this workpiece by hand, or re-place it and run again")
        return "failed", f"Localization {loc.status}: nothing welded", found, refused, attention
    found.append(
        f"placement offset x {x * 1e3:+.2f} mm, y {y * 1e3:+.2f} mm, θ {math.degrees(th):+.3f}° "
        f"(mean fit error {loc.fit_error_mean * 1e3:.2f} mm, {loc.inlier_fraction:.0%} of "
        f"{loc.n_points} edge points inliers)"
    )
    for m in loc.members:
        if m.status == "outside_tolerance":
            attention.append(
                f"member {m.id} is {np.linalg.norm(m.offset) * 1e3:.1f} mm / "
                f"{math.degrees(m.dtheta):.2f}° off the rigid fit (tolerance {tolerance * 1e3:.1f} mm): "
                "check it before welding its seams"
            )
        elif m.status == "not_observed":
            attention.append(f"member {m.id} was not observed (missing, or outside the inspected area)")
    for w in loc.welds:
        if w.get("status") == "uncertain":
            attention.append(
                f"weld {w['id']}: the scan places it only to ±{w['sigma'] * 1e3:.1f} mm "
                "(re-scan across its members, or weld it by hand)"
            )
    if path is not None:
        found.append(f"{len(path.seams)} weld seams re-planned to the found placement")
        if "max_mm" in path.metrics and path.metrics["max_mm"] > tolerance * 1e3:
            attention.append(
                f"a re-planned seam strays {path.metrics['max_mm']:.2f} mm from the true seam (simulation)"
            )
    ex = figures.get("execute")
    if ex:
        dry = " (dry run: nothing sent)" if ex.get("dry_run") else ""
        found.append(f"{ex['seams']} seams welded{dry}")
    elif path is not None:
        refused.append("the welds were not executed (the job's `execute` setting is off)")
    status = "attention" if attention else "ok"
    head = f"Part localized, {0 if path is None else len(path.seams)} welds re-planned"
    return status, head + ("; check the items below" if attention else ""), found, refused, attention


def _pose_section(rep, loc, figures: dict) -> None:
    sig = loc.to_json()["sigma"]
    sec = rep.section(
        "Placement",
        "The rigid offset of the part from where the template puts it (about the template's centroid), in "
        "the robot base frame; σ from the fit's covariance (how well the edge points pin each direction).",
    )
    x, y, th = loc.pose
    err = figures.get("localization", {}).get("error_vs_truth")
    cols = ["", "x [mm]", "y [mm]", "θ [°]"]
    rows = [
        ["found", x * 1e3, y * 1e3, math.degrees(th)],
        [
            "σ",
            *((None if sig[k] is None else sig[k] * 1e3) for k in ("x", "y")),
            None if sig["theta"] is None else math.degrees(sig["theta"]),
        ],
    ]
    if err:
        rows.append(["error against truth (simulation)", err["x_mm"], err["y_mm"], err["theta_deg"]])
    sec.table(cols, rows, caption="Placement found", digits=3)
    sec.keyvalues(
        {
            "status": loc.status,
            "mean fit error [mm]": loc.fit_error_mean * 1e3,
            "inliers": f"{loc.inlier_fraction:.1%} of {loc.n_points} edge points",
            "centroid (rotation centre) [mm]": f"{loc.center[0] * 1e3:.1f}, {loc.center[1] * 1e3:.1f}",
        }
    )
    C = np.asarray(loc.covariance, dtype=float)
    sec.table(
        ["", "x [m]", "y [m]", "θ [rad]"],
        [[k, *(f"{v:.3e}" for v in row)] for k, row in zip(("x", "y", "θ"), C, strict=False)],
        caption="Covariance of (x, y, θ)",
    )


def _members_section(rep, loc, tolerance: float):
    sec = rep.section(
        "Members",
        f"Each member's own offset from the rigid fit (its as-built error); over {tolerance * 1e3:.1f} mm "
        "is out of tolerance (red), a member no edge point fell on is amber.",
    )
    rows, marks = [], []
    for m in loc.members:
        seen = m.status != "not_observed"
        rows.append(
            [
                m.id,
                _MEMBER_WORDS.get(m.status, m.status),
                m.points,
                np.linalg.norm(m.offset) * 1e3 if seen else None,
                math.degrees(m.dtheta) if seen else None,
                m.rms * 1e3 if seen and m.rms is not None else None,
            ]
        )
        marks.append({"outside_tolerance": "bad", "not_observed": "warn"}.get(m.status, ""))
    sec.table(
        ["member", "status", "edge points", "offset [mm]", "rotation [°]", "RMS residual [mm]"],
        rows,
        row_status=marks,
        caption="Per-member residuals after the rigid fit",
    )
    return sec


def _welds_section(rep, loc, path) -> None:
    per = {p["seam"]: p for p in (path.metrics.get("per_seam", []) if path is not None else [])}
    planned = {s.id: s for s in (path.seams if path is not None else [])}
    sec = rep.section(
        "Welds",
        "One row per weld of the template: how far the fit and the members' own offsets moved it from the "
        "drawing, how sure the scan is of it (σ across the seam), and in simulation its distance to the true "
        "seam. Uncertain welds are amber.",
    )
    rows, marks = [], []
    for w in loc.welds:
        P, P0 = np.asarray(w["points"]), np.asarray(w["points_planned"])
        length = float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum())
        e = per.get(w["id"], {})
        seam = planned.get(w["id"])
        rows.append(
            [
                w["id"],
                "+".join(w.get("members", [])),
                w.get("status", ""),
                length * 1e3,
                float(np.linalg.norm(P - P0, axis=1).max()) * 1e3,
                w["shift_from_rigid"] * 1e3,
                w["sigma"] * 1e3,
                None if seam is None else len(seam.poses),
                e.get("mean_mm"),
                e.get("max_mm"),
            ]
        )
        marks.append("warn" if w.get("status") == "uncertain" else "")
    sec.table(
        [
            "weld",
            "members",
            "status",
            "length [mm]",
            "moved from drawing [mm]",
            "member correction [mm]",
            "σ across [mm]",
            "torch poses",
            "error vs truth mean [mm]",
            "max [mm]",
        ],
        rows,
        row_status=marks,
        caption="Per-weld status (errors against truth only in simulation)",
    )


def _joined(polylines: list[np.ndarray], closed: bool) -> np.ndarray:
    """Several (K, 3) polylines as one, with NaN breaks (one legend entry for a family of lines)."""
    out = []
    for P in polylines:
        P = np.asarray(P, dtype=float)
        out += [P, P[:1]] if closed else [P]
        out.append(np.full((1, 3), np.nan))
    return np.vstack(out) if out else np.empty((0, 3))


def _scene(template, edges, loc, path, truth):
    from weldcell.plugins.localize.pose import apply_xy
    from weldcell.sdk.html_report import Scene3D

    sc = Scene3D("part, edge points and welds [mm]")
    if len(edges.xy):
        pts = np.column_stack([edges.xy, edges.top])
        sc.cloud(pts, "edge points", color="#d62728", size=2.5, opacity=0.9, max_points=15000)

    def at_top(xy_list):
        return [np.column_stack([np.asarray(P)[:, :2], np.full(len(P), m.top)]) for P, m in xy_list]

    members = template.members
    planned = at_top([(m.outline, m) for m in members])
    found = at_top([(apply_xy(loc.pose, loc.center, m.outline), m) for m in members])
    sc.line(_joined(planned, True), "template where drawn", color="#8c8c8c", width=2, dash="dot")
    sc.line(_joined(found, True), "template where found", color="#1c7ed6", width=3)
    if truth is not None:
        true = at_top(list(zip(truth.outlines, members, strict=False)))
        sc.line(_joined(true, True), "true members (simulation)", color="#2f9e44", width=1.5, dash="dash")
    if path is not None and path.seams:
        sc.line(_joined([s.points for s in path.seams], False), "re-planned welds", color="#e8590c", width=6)
        mids = np.array([s.points[len(s.points) // 2] for s in path.seams])
        sc.markers(mids, "weld ids", size=2, labels=[s.id for s in path.seams], color="#e8590c")
        poses = np.concatenate([s.poses for s in path.seams])
        sc.frames(poses, "torch frames", length=0.012, max_frames=8 * len(path.seams))
    return sc


def write_html(ctx, template, plan, scan, edges, loc, path, truth) -> object:
    """``report/report.html``: the verdict first, then the placement, members, welds, the 3-D view and the
    pictures. Returns the path written."""
    from weldcell.sdk.html_report import HtmlReport

    tol = ctx.stage_settings("localize").member_tolerance
    rep = HtmlReport(f"Localize and weld: {ctx.profile.name}", f"run folder {ctx.run_dir.name}")
    status, head, found, refused, attention = _verdict(loc, path, truth, ctx.figures, tol)
    rep.set_verdict(status, head, found=found, refused=refused, attention=attention)
    _pose_section(rep, loc, ctx.figures)
    if loc.members:
        sec = _members_section(rep, loc, tol)
        if ctx.path("members.png").is_file():
            sec.figure(ctx.path("members.png"), "Which members sit off the rigid fit, and by how much?")
    if loc.welds:
        _welds_section(rep, loc, path)
    rep.section(
        "3-D view",
        "Edge points the laser found (red), the template where it was drawn (grey dotted) and where it was "
        "found (blue), in simulation the true members (green dashed); the re-planned welds (orange) with "
        "torch frames (orange = travel, blue = torch axis).",
    ).scene(_scene(template, edges, loc, path, truth))
    pics = rep.section("Pictures", "The same pictures as in the run folder.")
    for name, caption in (
        ("localization.png", "Where was the part found against where it was drawn (top view)?"),
        ("inspection.png", "Which lines did the laser scan, and where was the latency pass?"),
        ("scan.png", "Did the laser read the whole part (red: no reading)?"),
    ):
        if ctx.path(name).is_file():
            pics.figure(ctx.path(name), caption)
    a = ctx.figures.get("acquisition", {})
    rep.section("Inspection", "").keyvalues(
        {
            "pattern": f"{plan.kind}, {len(plan.lines)} lines, {plan.length:.2f} m, {plan.duration:.1f} s",
            "laser readings": len(scan),
            "edge points": len(edges),
            "latency [ms]": None if a.get("latency_s") is None else a["latency_s"] * 1e3,
            "programs": ", ".join(map(str, ctx.figures.get("programs", {}) or [])) or "none",
        }
    )
    return rep.write(ctx.path("report/report.html"))
