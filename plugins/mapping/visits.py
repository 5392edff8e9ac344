"""The second visit of the ``map`` job (paper 004 §II-E, §III-D) in the simulated site.

The robot comes back another time (simulated clock from 0, sensors powered up again): some structure has
been added (a box) and some removed (a standing plate), it starts elsewhere on the loop (its world frame,
the first IMU frame, is therefore offset from the first visit's), drives ``revisit.length`` metres,
builds its own map (``visit2/map``), relocalizes it against the first visit's segmented map with the
magnetometer heading and, when both visits aligned GNSS, the GNSS position as priors (else the prior key
frames within twice the travelled distance, §II-E), and updates the map into ``map_versions/v2``.
"""

from __future__ import annotations

import math

import numpy as np
from weldcell.plugins.mapping.map_update import View, detect_changes, start_versions, write_version
from weldcell.plugins.mapping.mapstore import KeyFrameStore, VoxelMap, back_project
from weldcell.sdk.errors import DataError

ADDED_BOX = ("revisit-box", (11.0, 2.6, 0.6), (1.0, 0.8, 1.2))
"""A box on the yard ahead of both visits' routes (x east, y north, centre, size in m)."""
REMOVED = "column-1-0"
"""A portal column both visits face."""


def change_scene(rig) -> list[str]:
    """Remove a column and add a box on the site; the camera re-builds its scene."""
    from weldcell.hal.sim.site import _box

    world = rig.site.world
    before = len(world.workpieces)
    world.workpieces = [w for w in world.workpieces if w.name != REMOVED]
    name, c, size = ADDED_BOX
    world.workpieces.append(_box(c, size, name, "steel"))
    rig.camera.on_configure()
    return [f"removed {REMOVED}" if len(world.workpieces) == before else "nothing removed", f"added {name}"]


def _new_route(rig, r) -> None:
    from weldcell.hal.sim.site import DEFAULT_WAYPOINTS, Route, RouteSettings

    wp = np.roll(DEFAULT_WAYPOINTS, -int(r.start_waypoint) % len(DEFAULT_WAYPOINTS), axis=0)
    site = rig.site
    site.base.route = Route.build(
        RouteSettings(length=r.length, cruise_speed=1.0, work_speed=0.3, seed=97),
        waypoints=wp,
        work_points=site.work_points(),
    )
    site.world.clock.t = 0.0  # another day: the clock and the sensors start again
    for dev in (rig.imu, rig.gnss):
        if dev is not None:
            dev.sim = None
            dev.on_configure()


def _visit_map(ctx, tr) -> tuple[np.ndarray, np.ndarray]:
    ms = ctx.settings.map
    est = tr.estimator
    tr.store.update_poses({k.index: (k.T_world_imu, k.T_world_imu @ est.T_imu_cam) for k in est.keyframes})
    tr.store.save_index()
    vm = VoxelMap(ms.voxel)
    for r in tr.store.records:
        d = tr.store.read(r)
        vm.integrate(
            *back_project(
                d["depth"], tr.store.intrinsics, r.T_world_cam, d["rgb"], ms.pixel_step, ms.max_depth
            )
        )
    vm.save(tr.store.root / "map.ply")
    return vm.points()


def _views(store: KeyFrameStore, T: np.ndarray, every: int = 2) -> list[View]:
    recs = sorted(store.records, key=lambda r: r.index)[::every]
    return [View(T @ r.T_world_cam, store.read(r)["depth"], store.intrinsics) for r in recs]


def _truth_align(tr) -> np.ndarray | None:
    """T_site_world of a visit from its key frames' full poses (the mean rotation of truth x estimate^-1,
    then the translation fitting the positions): well-posed also for a short, straight visit, where an
    alignment of positions alone leaves the roll about the travel direction free."""
    from scipy.spatial.transform import Rotation

    truth = {round(t, 6): T for t, T in tr.truth_frames}
    kfs = [k for k in tr.estimator.keyframes if round(k.t, 6) in truth]
    if len(kfs) < 3:
        return None
    est = [k.T_world_imu @ tr.estimator.T_imu_cam for k in kfs]
    ref = [truth[round(k.t, 6)] for k in kfs]
    R = (
        Rotation.from_matrix([g[:3, :3] @ e[:3, :3].T for g, e in zip(ref, est, strict=True)])
        .mean()
        .as_matrix()
    )
    A = np.eye(4)
    A[:3, :3] = R
    A[:3, 3] = np.mean([g[:3, 3] - R @ e[:3, 3] for g, e in zip(ref, est, strict=True)], axis=0)
    return A


def priors(ctx, tr1, tr2, heading1, heading2) -> tuple[dict, list[str]]:
    """The relocalizer's priors (prior-map frame) and notes on what was not usable."""
    r = ctx.settings.revisit
    out: dict = {}
    notes = []
    if r.use_magnetometer and heading1 is not None and heading2 is not None:
        out["yaw"], out["yaw_sigma"] = heading1 - heading2, r.yaw_sigma
    elif r.use_magnetometer:
        notes.append("no magnetometer heading in one of the visits")
    e1, e2 = tr1.estimator.T_world_enu, tr2.estimator.T_world_enu
    if r.use_gnss and e1 is not None and e2 is not None:
        out["position"] = (e1 @ np.linalg.inv(e2))[:3, 3]
        out["position_sigma"] = r.position_sigma
    elif r.use_gnss:
        notes.append(
            "GNSS not aligned in both visits (no fix, too little travel, or rejected jumps): "
            "key-frame sampling instead (§II-E)"
        )
    if "position" not in out:
        kf1 = np.array([(k.T_world_imu @ tr1.estimator.T_imu_cam)[:3, 3] for k in tr1.estimator.keyframes])
        kf2 = np.array([(k.T_world_imu @ tr2.estimator.T_imu_cam)[:3, 3] for k in tr2.estimator.keyframes])
        out["keyframe_positions"] = kf1
        out["current_keyframes"] = kf2
    return out, notes


def _record_relocalization(ctx, res, prior, notes: list[str], out: dict) -> dict:
    """Write ``visit2/relocalization.json`` (the result with the priors' notes) and add the
    relocalization's figures to ``out``; returns the written document."""
    doc = res.to_json()
    doc["notes"] = list(doc.get("notes", [])) + notes
    ctx.write_json("visit2/relocalization.json", doc)
    out.update(
        relocalization_status=res.status,
        relocalization_overlap=float(res.overlap),
        relocalization_confidence=float(res.confidence),
        relocalization_s=float(res.seconds),
        relocalization_priors=", ".join(res.priors_used),
        prepare_s=float(prior.prepare_seconds),
    )
    return doc


def second_visit(ctx, rig, tr1, figures1: dict) -> dict:
    """Drive the second visit, relocalize, update the map; the figures under ``visit2``."""
    from weldcell.plugins.mapping.estimator import VioEstimator
    from weldcell.plugins.mapping.frontend import OrbFrontEnd
    from weldcell.plugins.mapping.job import Tracking, _world_heading, drive

    s = ctx.settings
    if s.revisit.prior_map is not None:  # hardware (or a later simulated run): this run is the new visit
        return {"visit2": on_prior_map(ctx, tr1, figures1)}
    if rig.site is None:
        raise DataError(
            "the second visit drives the simulated site only",
            "on hardware set revisit.prior_map to the first run's map folder (or its map server) in the "
            "profile of the second run",
        )
    out: dict = {}
    with ctx.step("second visit: drive"):
        out["scene_changes"] = change_scene(rig) if s.revisit.change_scene else []
        _new_route(rig, s.revisit)
        est = VioEstimator(
            s.estimator, OrbFrontEnd(s.frontend), rig.T_imu_cam, s.imu_noise, rig.T_imu_antenna
        )
        store = KeyFrameStore(ctx.path("visit2/map") / "", T_imu_cam=rig.T_imu_cam, meta={"visit": 2})
        tr2 = Tracking(est, store, record=False, end=rig.site.route.duration)
        drive(ctx, rig, tr2)
        if not est.keyframes:
            raise DataError("the second visit made no key frame", "check the route and the sensors")
        cur, cur_col = _visit_map(ctx, tr2)
        out["keyframes"] = len(est.keyframes)
    with ctx.step("second visit: relocalize"):
        stage = ctx.stage("relocalizer")
        prior = stage.prepare(_prior_points(ctx))
        pri, notes = priors(ctx, tr1, tr2, figures1.get("world_heading_rad"), _world_heading(tr2))
        res = stage(prior, cur, **pri)
        doc = _record_relocalization(ctx, res, prior, notes, out)
        if res.status != "ok":
            out["relocalization_reason"] = res.reason
        A1, A2 = _truth_align(tr1), _truth_align(tr2)
        if A1 is not None and A2 is not None:  # truth: both VIO worlds placed on the site by their ATE fits
            E = np.linalg.inv(np.linalg.inv(A1) @ A2) @ res.T_prior_current
            out["relocalization_error_m"] = float(np.linalg.norm(E[:3, 3]))
            out["relocalization_error_deg"] = math.degrees(
                math.acos(float(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
            )
    if res.status == "ok":
        with ctx.step("second visit: map update"):
            out.update(_update(ctx, tr1, tr2, res, cur, cur_col, doc))
    else:
        out["map_update"] = "not done: the relocalization failed (the prior map is left unchanged)"
    _plots(ctx, tr1, tr2, res, out)
    return {"visit2": out}


def _prior_visit(folder) -> tuple[object, float | None]:
    """The prior visit as far as :func:`priors` needs it (GNSS frame, key-frame camera poses) and its
    magnetic heading, from the folder's key-frame index, or from its manifest's key-frame poses when it
    holds local maps only (a fetched map)."""
    from types import SimpleNamespace

    from weldcell.sdk import artifacts

    meta, cams = {}, []
    if (folder / "keyframes.json").is_file():
        meta = artifacts.read_json(folder / "keyframes.json")
        cams = [np.asarray(k["T_world_cam"], float) for k in meta.get("keyframes", [])]
    else:
        for e in artifacts.read_json(folder / "manifest.json")["segments"]:
            T = np.asarray(e["T_world_segment"], float)
            cams += [T @ np.asarray(v, float) for v in (e.get("keyframe_poses") or {}).values()]
    enu = meta.get("T_world_enu")
    est = SimpleNamespace(
        T_world_enu=None if enu is None else np.asarray(enu, float),
        T_imu_cam=np.eye(4),
        keyframes=[SimpleNamespace(T_world_imu=T) for T in cams],
    )
    return SimpleNamespace(estimator=est), meta.get("magnetic_heading_rad")


def on_prior_map(ctx, tr, figures: dict) -> dict:
    """This run as the second visit of ``revisit.prior_map`` (§II-E on hardware): its map relocalized on the
    prior map with the magnetometer / GNSS / key-frame priors both runs recorded, then the prior map
    updated into ``RUN/map_versions`` (see :mod:`~weldcell.plugins.mapping.prior_map`)."""
    from weldcell.plugins.mapping.job import _world_heading
    from weldcell.plugins.mapping.map_update import prior_points
    from weldcell.plugins.mapping.prior_map import resolve_prior_map

    out: dict = {"prior_map": str(ctx.settings.revisit.prior_map)}
    with ctx.step("relocalize on the prior map"):
        folder = resolve_prior_map(ctx)
        stage = ctx.stage("relocalizer")
        prior = stage.prepare(prior_points(ctx.stage("transfer"), folder)[0])
        cur, cur_col = _visit_map(ctx, tr)
        tr_prior, heading1 = _prior_visit(folder)
        heading2 = figures.get("world_heading_rad", _world_heading(tr))
        pri, notes = priors(ctx, tr_prior, tr, heading1, heading2)
        if not tr_prior.estimator.keyframes:
            pri.pop("keyframe_positions", None)
            pri.pop("current_keyframes", None)
            notes.append("the prior map has no key-frame poses: no key-frame sampling")
        res = stage(prior, cur, **pri)
        out["keyframes"] = len(tr.estimator.keyframes)
        doc = _record_relocalization(ctx, res, prior, notes, out)
    if res.status != "ok":
        out["relocalization_reason"] = res.reason
        out["map_update"] = "not done: the relocalization failed (the prior map is left unchanged)"
        return out
    with ctx.step("map update of the prior map"):
        out.update(_update_prior(ctx, tr, folder, res, cur, cur_col, doc))
    return out


def _update_prior(ctx, tr, folder, res, cur, cur_col, doc) -> dict:
    from weldcell.plugins.mapping.map_update import prior_points

    s, transfer = ctx.settings, ctx.stage("transfer")
    vroot = ctx.path("map_versions") / ""
    start_versions(transfer, folder, vroot)
    p1, _ = prior_points(transfer, vroot / "v1")
    T = res.T_prior_current
    cur_p = cur @ T[:3, :3].T + T[:3, 3]
    out: dict = {}
    views1 = []
    if (folder / "keyframes.json").is_file():
        views1 = _views(KeyFrameStore.load(folder), np.eye(4))
    else:
        out["map_update_note"] = "the prior map has no key frames: removals only, new structure is extension"
    r = s.revisit
    ch = detect_changes(
        p1,
        cur_p,
        views1,
        _views(tr.store, T),
        r.change_distance,
        r.min_change_points,
        min(s.map.max_depth, r.change_max_depth),
        r.min_views,
    )
    entry = write_version(transfer, vroot, ch, cur_p, cur_col, doc)
    changes = {"schema": "weldcell/map-changes@1", "frame": "prior map", "units": "m"}
    ctx.write_json("visit2/changes.json", {**changes, "changes": entry["changes"]})
    keys = ("changed_segments", "unchanged_segments", "changes", "removed_points", "added_points")
    out.update({k: entry[k] for k in (*keys, "extension_points")}, map_version=entry["version"])
    return out


def _prior_points(ctx) -> np.ndarray:
    from weldcell.plugins.mapping.map_update import prior_points

    pts, _ = prior_points(ctx.stage("transfer"), ctx.path("map") / "")
    return pts


def _update(ctx, tr1, tr2, res, cur, cur_col, doc) -> dict:
    s = ctx.settings
    transfer = ctx.stage("transfer")
    vroot = ctx.path("map_versions") / ""
    start_versions(transfer, ctx.path("map") / "", vroot)
    from weldcell.plugins.mapping.map_update import prior_points

    prior, _ = prior_points(transfer, vroot / "v1")
    T = res.T_prior_current
    cur_p = cur @ T[:3, :3].T + T[:3, 3]
    ch = detect_changes(
        prior,
        cur_p,
        _views(tr1.store, np.eye(4)),
        _views(tr2.store, T),
        s.revisit.change_distance,
        s.revisit.min_change_points,
        min(s.map.max_depth, s.revisit.change_max_depth),
        s.revisit.min_views,
    )
    entry = write_version(transfer, vroot, ch, cur_p, cur_col, doc)
    ctx.write_json(
        "visit2/changes.json",
        {"schema": "weldcell/map-changes@1", "frame": "prior map", "units": "m", "changes": entry["changes"]},
    )
    return {
        "map_version": entry["version"],
        "changed_segments": entry["changed_segments"],
        "unchanged_segments": entry["unchanged_segments"],
        "removed_points": entry["removed_points"],
        "added_points": entry["added_points"],
        "extension_points": entry["extension_points"],
        "changes": entry["changes"],
        "_changes": (prior, ch, cur_p),
    }


def _plots(ctx, tr1, tr2, res, out: dict) -> None:
    if not ctx.profile.output.report:
        out.pop("_changes", None)
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4.5))
    for tr, col, name in ((tr1, "r", "visit 1"), (tr2, "b", "visit 2")):
        G = np.array([T[:3, 3] for _, T in tr.truth_frames]) if tr.truth_frames else None
        if G is not None:
            ax.plot(G[:, 0], G[:, 1], col + ":", lw=1, label=f"{name} ground truth")
        A = _truth_align(tr1)
        P = np.array([(k.T_world_imu @ tr.estimator.T_imu_cam)[:3, 3] for k in tr.estimator.keyframes])
        if tr is tr2:  # visit 2 placed in the prior map by the relocalization, then like visit 1 on the site
            P = P @ res.T_prior_current[:3, :3].T + res.T_prior_current[:3, 3]
        if A is not None:
            P = P @ A[:3, :3].T + A[:3, 3]
        ax.plot(
            P[:, 0],
            P[:, 1],
            col + ".-",
            ms=2,
            lw=0.8,
            label=f"{name} estimated" + (" (relocalized)" if tr is tr2 else ""),
        )
    ax.set_aspect("equal")
    ax.legend(fontsize=7)
    ax.set_title(f"both visits: relocalization {res.status}, overlap {res.overlap:.2f}")
    fig.tight_layout()
    fig.savefig(ctx.path("report/visits.png"), dpi=110)
    plt.close(fig)
    ch = out.pop("_changes", None)
    if ch is None:
        return
    prior, c, cur_p = ch
    fig, ax = plt.subplots(figsize=(10, 4.5))
    sel = np.random.default_rng(0).choice(len(prior), min(len(prior), 40000), replace=False)
    ax.scatter(prior[sel, 0], prior[sel, 1], s=0.2, c="0.6", label="prior map")
    if len(c.removed):
        ax.scatter(prior[c.removed, 0], prior[c.removed, 1], s=1, c="b", label="removed")
    if len(c.added):
        ax.scatter(cur_p[c.added, 0], cur_p[c.added, 1], s=1, c="r", label="added")
    ax.set_aspect("equal")
    ax.legend(fontsize=7, markerscale=8)
    ax.set_title("changed regions (prior map frame)")
    fig.tight_layout()
    fig.savefig(ctx.path("report/changes.png"), dpi=110)
    plt.close(fig)
