"""The ``map`` job (paper 004 §II-A to §II-C): drive the mobile welding robot through the site, estimate
its trajectory (visual-inertial-GNSS key-frame smoother), build the map (eq. 3), find the weld
regions (§II-C) and report everything, against ground truth in the simulated site.

Run folder: ``map/`` (map folder: ``map.ply``, ``keyframes.json`` + ``keyframes/``, ``regions/``),
``trajectory_keyframes.tum`` and ``trajectory_frames.tum`` (TUM format: t x y z qx qy qz qw, camera in
the world), ``regions.json`` (``weldcell/weld-regions@1``), ``events.json``, ``report.md`` + pictures.
``--resume`` continues from the last key frame written to the store.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from weldcell.plugins.mapping.estimator import VioEstimator
from weldcell.plugins.mapping.frontend import OrbFrontEnd
from weldcell.plugins.mapping.mapstore import KeyFrameStore
from weldcell.sdk.errors import DataError, DeviceError
from weldcell.sdk.geometry import T_from_rpy

SITE_BASE = "base"


@dataclass
class Rig:
    """The devices and their extrinsics (from the profile's mounts)."""

    camera: object
    imu: object
    gnss: object | None
    T_imu_cam: np.ndarray
    T_imu_antenna: np.ndarray | None
    site: object | None


@dataclass
class Tracking:
    estimator: VioEstimator
    store: KeyFrameStore
    frames: int = 0
    truth_frames: list = field(default_factory=list)
    detections: list = field(default_factory=list)
    frame_seconds: list = field(default_factory=list)
    segments: object | None = None
    """The live local maps (:class:`~weldcell.plugins.mapping.live_map.LiveSegments`), when segmenting."""
    record: bool = True
    """Record key frames in the run's state (the first visit; ``--resume`` continues it)."""
    mag: list = field(default_factory=list)
    """(t, magnetic field (3,) in the IMU frame) during the start-up standstill (heading of the world)."""
    end: float | None = None
    """Simulated time at which the drive ends (default: the route's end)."""


def _mount_T(ctx, role: str) -> tuple[str, np.ndarray]:
    m = ctx.profile.devices[role].mount
    return m.parent, T_from_rpy(m.rpy, m.xyz)


def make_rig(ctx) -> Rig:
    """Devices ``camera``, ``imu`` (and optional ``gnss``); camera-IMU extrinsics from their mounts."""
    cam, imu = ctx.device("camera"), ctx.device("imu")
    gnss = ctx.devices.get("gnss")
    pc, T_p_cam = _mount_T(ctx, "camera")
    pi, T_p_imu = _mount_T(ctx, "imu")
    if pc != pi:
        raise DataError(
            f"camera is mounted on '{pc}' but the IMU on '{pi}': the camera-IMU extrinsics need one parent",
            "mount [devices.camera] and [devices.imu] on the same frame (the robot's base)",
        )
    T_imu_cam = np.linalg.inv(T_p_imu) @ T_p_cam
    T_imu_ant = None
    if gnss is not None:
        pg, T_p_ant = _mount_T(ctx, "gnss")
        T_imu_ant = np.linalg.inv(T_p_imu) @ T_p_ant if pg == pi else None
    site = getattr(getattr(cam, "world", None), "site", None) if pc == SITE_BASE else None
    return Rig(cam, imu, gnss, T_imu_cam, T_imu_ant, site)


def _feed_imu(ctx, rig: Rig, est: VioEstimator, t_frame: float, mag: list | None = None) -> bool:
    """Collect IMU samples until they cover ``t_frame``; False when the IMU stays silent."""
    s = ctx.settings
    deadline = time.monotonic() + s.imu_wait
    while True:
        try:
            got = rig.imu.read_available(timeout=0.02)
        except DeviceError as e:
            if not any(ev["kind"] == "imu-failed" for ev in est.events):  # reported once
                est._event(
                    t_frame, "imu-failed", f"IMU stream failed: {e.message}; tracking goes on visually"
                )
            return False
        if got:
            # simulation: the sensors' shared simulated clock; hardware: the host's arrival stamps (one
            # clock for camera, IMU and GNSS; the devices' own clocks are not synchronised)
            sim = rig.site is not None
            t = np.array([r.device_stamp if sim and r.device_stamp is not None else r.stamp for r in got])
            est.add_imu(t, np.array([r.accel for r in got]), np.array([r.gyro for r in got]))
            if mag is not None and not est.keyframes:  # the start-up standstill: the world's heading
                mag += [(ti, r.mag) for ti, r in zip(t, got, strict=True) if r.mag is not None]
        if est.imu and est.imu[-1][0] >= t_frame:
            return True
        if time.monotonic() > deadline:
            return False


def _feed_gnss(rig: Rig, est: VioEstimator) -> None:
    if rig.gnss is None:
        return
    try:
        fixes = rig.gnss.read_available()
    except DeviceError:
        return
    for g in fixes:
        if g.valid and g.enu is not None:
            sig = np.array([g.h_acc or 2.0, g.h_acc or 2.0, g.v_acc or 3.0])
            sim = rig.site is not None and g.device_stamp is not None
            est.add_gnss(g.device_stamp if sim else g.stamp, g.enu, sig)


def _frame_time(frame) -> float:
    return float(frame.meta.get("capture_sim_time", frame.stamp))


def drive_and_track(ctx, rig: Rig, tr: Tracking, detector, regions_truth) -> None:
    """The capture loop: one camera frame at a time, IMU and GNSS up to it, tracking, key frames
    written to the store as they are made (nothing captured is lost on interruption)."""
    s = ctx.settings
    end = rig.site.route.duration if rig.site is not None else np.inf
    end = min(end, tr.end) if tr.end is not None else end
    fps = 1.0 / float(getattr(rig.camera, "frame_time", 1 / 15))
    total = int(end * fps) if np.isfinite(end) else None
    with ctx.step("drive and track", total=total) as advance:
        while True:
            if tr.record and s.max_frames is not None and tr.frames >= s.max_frames:
                break
            if rig.site is not None and rig.site.world.clock.t > end:
                break
            t0 = time.perf_counter()
            frame = rig.camera.capture()
            if frame.color is None:
                raise DataError(
                    "the camera delivers no colour image", "enable colour (camera.sim: color = true)"
                )
            t = _frame_time(frame)
            imu_ok = _feed_imu(ctx, rig, tr.estimator, t, tr.mag)
            _feed_gnss(rig, tr.estimator)
            if not imu_ok and not tr.estimator.keyframes:
                raise DeviceError(
                    "no IMU data reached the job before the first frame",
                    "check the IMU connection and that the stream runs",
                )
            if frame.color is None:
                raise DataError(
                    "the camera delivers no colour image", "enable colour (camera.sim: color = true)"
                )
            truth = frame.meta.get("T_world_camera")
            res = tr.estimator.process_frame(t, frame.color, frame.depth, frame.intrinsics, truth)
            for e in res.events:
                ctx.reporter.info(f"t={t:.2f} s {e}")
            if res.T_world_cam is not None and truth is not None:
                tr.truth_frames.append((t, np.asarray(truth)))
            if res.keyframe is not None:
                _on_keyframe(ctx, tr, res.keyframe, frame, detector, regions_truth)
            tr.frames += 1
            tr.frame_seconds.append(time.perf_counter() - t0)
            advance(tr.frames, total, f"{len(tr.estimator.keyframes)} key frames")


def _on_keyframe(ctx, tr: Tracking, kf, frame, detector, regions_truth) -> None:
    T_cam = kf.T_world_imu @ tr.estimator.T_imu_cam
    tr.store.add(kf, T_cam)
    if tr.segments is not None:  # §II-D: a new local map (and its hand-over) while driving
        tr.segments.on_keyframe(kf)
    keep = ctx.settings.estimator.links + 1
    for old in tr.estimator.keyframes[:-keep]:  # images live in the store; memory stays bounded
        old.rgb = old.depth = None
    if not tr.record:
        return
    record = {"keyframe": kf.index, "t": kf.t, "file": f"map/keyframes/{kf.index:06d}.npz"}
    if detector is not None and kf.index % ctx.settings.detect_every == 0:
        dets = _detect(tr, frame, detector, regions_truth)
        tr.detections.append((kf.index, dets))
        record["detections"] = [[*d.xyxy, d.label, d.class_id, d.score] for d in dets]
    ctx.state.add_capture(record)  # with its detections: a resumed run loses none


def _detect(tr: Tracking, frame, detector, regions_truth) -> list:
    meta = {
        "T_world_camera": frame.meta.get("T_world_camera"),
        "intrinsics": frame.intrinsics,
        "depth": frame.depth,
        "regions": regions_truth,
    }
    t0 = time.perf_counter()
    dets = detector(frame.color, meta)
    tr.estimator.timing.setdefault("detector", []).append(time.perf_counter() - t0)
    return dets


def run(ctx) -> dict:
    """Entry point of the job (see the module docstring)."""
    from weldcell.plugins.mapping import finish

    s = ctx.settings
    if s.revisit.prior_map is not None:
        from weldcell.plugins.mapping.prior_map import check_at_start

        check_at_start(ctx)
    rig = make_rig(ctx)
    if rig.site is not None:
        from weldcell.hal.sim.site import RouteSettings

        r = s.route
        rig.site.set_route(
            RouteSettings(
                cruise_speed=r.cruise_speed,
                work_speed=r.work_speed,
                length=r.length,
                standstill=r.standstill,
                seed=ctx.profile.cell.seed,
            )
        )
        for dev in (rig.imu, rig.gnss):  # the new route: sensors restart their models on it
            if dev is not None:
                dev.on_configure()
    est = VioEstimator(s.estimator, OrbFrontEnd(s.frontend), rig.T_imu_cam, s.imu_noise, rig.T_imu_antenna)
    store = KeyFrameStore(
        ctx.path("map") / "",
        T_imu_cam=rig.T_imu_cam,
        meta={"profile": ctx.profile.name, "site": "sim" if rig.site else "hardware"},
    )
    tr = Tracking(est, store)
    live = None
    if s.segmentation.enabled:  # §II-D: local maps while driving, served from the start (Table II)
        from weldcell.plugins.mapping.live_map import LiveSegments

        live = LiveSegments(ctx, tr, ctx.stage("transfer"), s.segmentation, ctx.path("map") / "", s.serve_map)
    finish.resume_if_any(ctx, rig, tr)
    try:
        if live is not None:
            if tr.estimator.keyframes:
                live.replay()
            tr.segments = live
        figures = _visit(ctx, rig, tr)
        if live is not None:
            figures.update(live.finish())
    finally:
        if live is not None:
            live.close()
    if live is not None and rig.site is not None:
        from weldcell.plugins.mapping.seg_eval import evaluate_segmentation

        figures.update(evaluate_segmentation(ctx, rig, tr, live.segmenter.segments))
    figures["world_heading_rad"] = _world_heading(tr)
    store.meta["magnetic_heading_rad"] = figures["world_heading_rad"]
    store.meta["T_world_enu"] = None if est.T_world_enu is None else est.T_world_enu.tolist()
    store.save_index()
    if s.revisit.enabled:
        from weldcell.plugins.mapping.visits import second_visit

        figures.update(second_visit(ctx, rig, tr, figures))
    if ctx.profile.output.report:
        from weldcell.plugins.mapping.report import append_report

        append_report(ctx, figures)
    return figures


def _visit(ctx, rig: Rig, tr: Tracking) -> dict:
    from weldcell.plugins.mapping import finish

    detector = ctx.stage("detector") if "detector" in ctx.resolved.stages else None
    regions_truth = rig.site.weld_truth() if rig.site is not None else []
    drive(ctx, rig, tr, detector, regions_truth)
    return finish.finish(ctx, rig, tr)


def drive(ctx, rig: Rig, tr: Tracking, detector=None, regions_truth=()) -> None:
    """Stream the IMU (and GNSS) while the capture loop runs."""
    rig.imu.start_stream()
    if rig.gnss is not None:
        rig.gnss.start_stream()
    try:
        drive_and_track(ctx, rig, tr, detector, list(regions_truth))
    finally:
        rig.imu.stop_stream()
        if rig.gnss is not None:
            rig.gnss.stop_stream()


def _world_heading(tr: Tracking) -> float | None:
    """Heading of the map's world x axis from magnetic north's direction (rad, atan2 of the horizontal
    field in the world), from the magnetometer during the start-up standstill; None without samples."""
    est = tr.estimator
    if not tr.mag or not est.keyframes:
        return None
    m = np.mean([v for _, v in tr.mag], axis=0)
    R = est.keyframes[0].T_world_imu[:3, :3]
    w = R @ m
    return float(np.arctan2(w[1], w[0]))
