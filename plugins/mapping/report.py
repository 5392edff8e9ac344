"""Report of the ``map`` job: report.md with the figures, trajectory and map pictures."""

from __future__ import annotations

import numpy as np
from weldcell.sdk import artifacts


def write_report(ctx, tr, rig, regions, figures: dict, A: np.ndarray | None) -> None:
    """report.md + trajectory.png (estimated vs truth, top view) + map.png (map with weld regions)."""
    import matplotlib

    matplotlib.use("Agg")
    _trajectory_png(ctx, tr, figures, A)
    _map_png(ctx, regions, A)
    lines = _report_md_lines(ctx, tr.estimator, regions, figures)
    artifacts.write_text(ctx.path("report/report.md"), "\n".join(lines))


def _trajectory_png(ctx, tr, figures: dict, A: np.ndarray | None) -> None:
    """report/trajectory.png: estimated key frames (aligned by ``A`` when given) over the truth, top view,
    with the places where tracking was lost."""
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


def _map_png(ctx, regions, A: np.ndarray | None) -> None:
    """report/map.png: the map's points (top view, coloured) with the weld regions and their decisions."""
    import matplotlib.pyplot as plt
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


def _report_md_lines(ctx, est, regions, figures: dict) -> list[str]:
    """report.md: the figures, the time per stage, the weld regions, the events and the pictures."""
    lines = [
        f"# Map run: {ctx.profile.name}",
        "",
        "The interactive report (verdict, tables, 3-D view): `report.html`.",
    ]
    lines += ["", "| figure | value |", "|---|---|"]
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
    return lines


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

    write_html(ctx, figures)


# ------------------------------------------------------------------------------------ report/report.html
_DECISION_WORDS = {
    "auto": "found (seen in several key frames)",
    "confirmed": "confirmed by the operator",
    "unconfirmed": "seen once: a person confirms or rejects it",
    "rejected": "rejected",
    "added": "added by the operator",
}


_SHORT = {"auto": "found", "unconfirmed": "to confirm"}
_V2_WORDS = {
    "scene_changes": "changes made to the scene (simulation)",
    "relocalization_s": "relocalization time [s]",
    "prepare_s": "map preparation time [s]",
    "relocalization_error_m": "relocalization error against truth [m]",
    "relocalization_error_deg": "relocalization error against truth [°]",
    "keyframes": "key frames",
}


def _read_json(path):
    import json

    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


def _read_tum(path) -> np.ndarray | None:
    """(t, x, y, z) rows of a TUM trajectory file, or None."""
    if not path.is_file():
        return None
    A = np.loadtxt(path, ndmin=2)
    return A[:, :4] if len(A) else None


def _rigid_fit(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The rigid 4x4 ``T`` minimising ``|T src - dst|`` (Kabsch, no scale)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    T = np.eye(4)
    T[:3, :3] = Vt.T @ D @ U.T
    T[:3, 3] = cd - T[:3, :3] @ cs
    return T


def _box_edges(center, R, extent) -> np.ndarray:
    """The 12 edges of an oriented box as one polyline with NaN breaks (for Scene3D.line)."""
    s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    C = np.asarray(center) + (s * np.asarray(extent) / 2.0) @ np.asarray(R).T
    out = []
    for i in range(8):
        for j in range(i + 1, 8):
            if np.sum(s[i] != s[j]) == 1:
                out += [C[i], C[j], [np.nan] * 3]
    return np.array(out)


def _map_verdict(figures: dict, regions: list, events: list) -> tuple[str, str, list, list, list]:
    found, refused, attention = [], [], []
    ate = figures.get("ate_rmse_m")
    found.append(
        f"map of {figures.get('keyframes', 0)} key frames, {figures.get('map_points', 0):,} points"
        + (f"; trajectory error (ATE) {ate:.3f} m against the truth (simulation)" if ate is not None else "")
    )
    by = {}
    for r in regions:
        by.setdefault(r["decision"], []).append(r["id"])
    found.append(
        f"{len(regions)} weld regions: "
        + (", ".join(f"{len(v)} {_SHORT.get(k, k)}" for k, v in sorted(by.items())) or "none")
    )
    if by.get("unconfirmed"):
        attention.append(
            "weld regions seen in one key frame only (confirm or reject them in the decisions file): "
            + ", ".join(by["unconfirmed"])
        )
    if by.get("rejected"):
        refused.append("weld regions rejected: " + ", ".join(by["rejected"]))
    lost = [e for e in events if e["kind"] == "lost"]
    if lost:
        attention.append(
            f"tracking was lost {len(lost)} time(s) (at t = "
            + ", ".join(f"{e['t']:.1f}" for e in lost)
            + " s): check the map there for doubled or bent structure"
        )
    if figures.get("segments"):
        found.append(
            f"{figures['segments']} local maps written" + (", all fetched" if figures.get("fetch_ok") else "")
        )
        if figures.get("fetch_ok") is False:
            attention.append("the local maps were not all received over the network (fetch failed)")
    for u in figures.get("ae_unmeasured") or []:
        refused.append(f"{u['plate']} not measured: {u['reason']} (left out of the AE)")
    v2 = figures.get("visit2") or {}
    if v2:
        st = v2.get("relocalization_status")
        if st == "ok":
            found.append(
                f"second visit relocalized on the map (overlap {v2.get('relocalization_overlap', 0):.2f}, "
                f"confidence {v2.get('relocalization_confidence', 0):.2f})"
            )
        else:
            refused.append(f"second visit: relocalization {st}: the map was not updated from it")
            attention.append(
                "relocalization failed: start the second visit nearer a mapped place, or give a prior"
            )
        ch = v2.get("changes", [])
        if ch:
            attention.append(
                f"{len(ch)} change(s) found against the map: "
                + "; ".join(
                    f"{c['kind']} structure near {tuple(round(v, 2) for v in c['center'])} m" for c in ch
                )
                + ": check them before welding there"
            )
        if v2.get("map_version"):
            found.append(f"map updated to version {v2['map_version']}")
    status = "failed" if not figures.get("keyframes") else ("attention" if attention else "ok")
    head = "Map built" + (" and updated on the second visit" if v2.get("map_version") else "")
    return status, head + ("; check the items below" if attention else ""), found, refused, attention


def _accuracy_rows(figures: dict) -> list:
    rows = []
    for key, label, scale, unit in (
        ("ate_rmse_m", "trajectory error, key frames (ATE RMSE)", 1, "m"),
        ("ate_frames_slerp_m", "trajectory error, every frame", 1, "m"),
        ("ae_mm", "plate-corner error (AE)", 1, "mm"),
        ("region_position_error_m", "weld-region position error", 1, "m"),
        ("ate_segmentation_change_pct", "ATE change from cutting into local maps", 1, "%"),
        ("frame_seconds_mean", "time per camera frame", 1, "s"),
    ):
        if figures.get(key) is not None:
            rows.append([label, figures[key] * scale, unit])
    for key, label in (
        ("regions_found", "true weld regions found"),
        ("regions_truth", "true weld regions"),
        ("keyframes", "key frames"),
        ("frames", "camera frames"),
        ("loop_closures", "loop closures"),
        ("tracking_lost_events", "tracking lost"),
        ("gnss_aligned", "GNSS aligned"),
    ):
        if key in figures:
            rows.append([label, figures[key], ""])
    return rows


def _segment_rows(manifest: dict) -> tuple[list, list]:
    rows, marks = [], []
    for e in manifest.get("segments", []):
        kf, ho = e.get("keyframes", []), e.get("handover") or {}
        q = e.get("quantisation") or {}
        rows.append(
            [
                e["id"],
                f"{kf[0]}–{kf[-1]}" if kf else "",
                e.get("points"),
                e.get("distance_m"),
                e.get("bytes", 0) / 1e6,
                None if not q.get("max_error_m") else q["max_error_m"] * 1e3,
                ho.get("method", "start"),
                ho.get("note", ""),
            ]
        )
        marks.append("" if ho.get("method", "verified") in ("verified", "orb-ndt") else "warn")
    return rows, marks


def _map_scene(ctx, regions: list, changes: list):
    from weldcell.sdk.cloudfile import quiet_native_output
    from weldcell.sdk.html_report import Scene3D

    sc = Scene3D("map, trajectory and weld regions [m]", scale=1.0, unit="m")
    ply = ctx.path("map/map.ply")
    if ply.is_file():
        import open3d as o3d

        with quiet_native_output():
            M = np.asarray(o3d.io.read_point_cloud(str(ply)).points)
        if len(M):
            sc.cloud(M, "map", max_points=25000, size=1.2, opacity=0.6)
    est, gt = _read_tum(ctx.path("trajectory_keyframes.tum")), _read_tum(ctx.path("truth_keyframes.tum"))
    if est is not None:
        sc.line(est[:, 1:], "trajectory (estimate)", color="#d62728", width=4)
        if gt is not None and len(gt) == len(est) and len(est) >= 3:
            T = _rigid_fit(gt[:, 1:], est[:, 1:])  # the truth brought onto the estimate (as for ATE)
            sc.line(
                gt[:, 1:] @ T[:3, :3].T + T[:3, 3],
                "trajectory (truth, aligned)",
                color="#111",
                width=3,
                dash="dash",
            )
    colours = {"auto": "#e8590c", "confirmed": "#2f9e44", "unconfirmed": "#f59f00", "rejected": "#868e96"}
    for r in regions:
        b = r.get("oriented_box")
        if b:
            sc.line(
                _box_edges(b["center"], b["R"], b["extent"]),
                f"region {r['id']} ({r['decision']})",
                color=colours.get(r["decision"], "#1c7ed6"),
                width=4,
            )
    for i, c in enumerate(changes):
        lo, hi = np.asarray(c["min"]), np.asarray(c["max"])
        sc.line(
            _box_edges((lo + hi) / 2, np.eye(3), hi - lo),
            f"change {i + 1}: {c['kind']}",
            color="#ae3ec9" if c["kind"] == "added" else "#1c7ed6",
            width=3,
            dash="dot",
        )
    return sc


def write_html(ctx, figures: dict):
    """``report/report.html`` from the run folder and the result figures: the verdict first (tracking lost,
    relocalization failed, changes found, regions to confirm), then accuracy, local maps, weld regions,
    the second visit, a 3-D view and the pictures. Returns the path written."""
    from weldcell.sdk.html_report import HtmlReport

    reg = _read_json(ctx.path("regions.json")) or {}
    regions = reg.get("regions", [])
    events = (_read_json(ctx.path("events.json")) or {}).get("events", [])
    manifest = _read_json(ctx.path("map/manifest.json")) or {}
    v2 = figures.get("visit2") or {}
    rep = HtmlReport(f"Map: {ctx.profile.name}", f"run folder {ctx.run_dir.name}")
    status, head, found, refused, attention = _map_verdict(figures, regions, events)
    rep.set_verdict(status, head, found=found, refused=refused, attention=attention)
    rep.section(
        "Accuracy", "Errors against the simulated truth (trajectory rigidly aligned, as for ATE)."
    ).table(["figure", "value", "unit"], _accuracy_rows(figures), caption="Map accuracy and run figures")
    if manifest.get("segments"):
        _local_maps_section(rep, manifest)
    _regions_section(rep, regions)
    changes = v2.get("changes", []) if v2 else []
    if v2:
        _second_visit_section(rep, v2, changes)
    rep.section(
        "3-D view",
        "The map (decimated evenly), the estimated camera path (red) and, in simulation, the true one "
        "(black dashed), the weld regions as boxes (orange found, amber to confirm, grey rejected) and "
        "changes found on the second visit (dotted).",
    ).scene(_map_scene(ctx, regions, changes))
    _events_and_pictures(ctx, rep, events)
    return rep.write(ctx.path("report/report.html"))


def _local_maps_section(rep, manifest: dict) -> None:
    rows, marks = _segment_rows(manifest)
    rep.section(
        "Local maps",
        "Each local map and how it was attached to the previous one. 'verified': the estimator's pose, "
        "confirmed by ORB + PnP at the cut (as designed; the note says which check refined it); another "
        "method is marked amber.",
    ).table(
        [
            "local map",
            "key frames",
            "points",
            "length [m]",
            "size [MB]",
            "max quantisation error [mm]",
            "hand-over",
            "note",
        ],
        rows,
        row_status=marks,
        caption="Local maps (segments)",
    )


def _regions_section(rep, regions: list) -> None:
    sec = rep.section("Weld regions", "Regions the detector found, with the decision on each.")
    sec.table(
        ["region", "label", "decision", "key frames", "score", "centre [m]", "box [m]", "points"],
        [
            [
                r["id"],
                r.get("label", ""),
                _DECISION_WORDS.get(r["decision"], r["decision"]),
                len(r.get("observations", [])),
                r.get("score"),
                ", ".join(f"{v:.2f}" for v in r["center"]),
                " × ".join(f"{v:.2f}" for v in (r.get("oriented_box") or {}).get("extent", [])),
                r.get("points"),
            ]
            for r in regions
        ],
        row_status=[{"unconfirmed": "warn", "rejected": "bad"}.get(r["decision"], "") for r in regions],
        caption="Weld regions",
    )


def _second_visit_section(rep, v2: dict, changes: list) -> None:
    s2 = rep.section("Second visit", "Relocalization on the map, then the map update (§II-E).")
    shown = [(k, v) for k, v in v2.items() if k != "changes" and not isinstance(v, dict)]
    s2.table(
        ["figure", "value"],
        [
            [_V2_WORDS.get(k, k.replace("_", " ")), ", ".join(map(str, v)) if isinstance(v, list) else v]
            for k, v in shown
        ],
        row_status=["bad" if k == "relocalization_status" and v != "ok" else "" for k, v in shown],
        caption="Relocalization and map update",
    )
    if changes:
        s2.table(
            ["change", "kind", "points", "centre [m]", "size [m]", "local map"],
            [
                [
                    i + 1,
                    c["kind"],
                    c["points"],
                    ", ".join(f"{v:.2f}" for v in c["center"]),
                    " × ".join(f"{v:.2f}" for v in np.subtract(c["max"], c["min"])),
                    c.get("segment"),
                ]
                for i, c in enumerate(changes)
            ],
            caption="Changes found against the map",
        )


def _events_and_pictures(ctx, rep, events: list) -> None:
    if events:
        rep.section("Events", "What the estimator reported while driving.").table(
            ["t [s]", "kind", "message"],
            [[e["t"], e["kind"], e["message"]] for e in events],
            row_status=["bad" if e["kind"] == "lost" else "" for e in events],
            caption="Estimator events",
        )
    pics = rep.section("Pictures", "The same pictures as in report/.")
    for name, caption in (
        ("trajectory.png", "Did the estimated path follow the true one (top view)?"),
        ("map.png", "Where in the map are the weld regions (top view)?"),
        ("visits.png", "Where did the second visit drive on the map?"),
        ("changes.png", "What changed between the visits?"),
    ):
        if ctx.path(f"report/{name}").is_file():
            pics.figure(ctx.path(f"report/{name}"), caption)
