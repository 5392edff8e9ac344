"""The segmented map while the robot drives (paper 004 §II-D, Table II): local maps cut by
:class:`~weldcell.plugins.mapping.segmentation.Segmenter`, each written to the map folder
(``weldcell/map-segments@1``, through the ``transfer`` stage) once its poses are final, served over
ZeroMQ from the start of the run and fetched on loopback as the operator's computer would.

Files in the map folder besides ``map.ply`` and the key-frame store: ``manifest.json`` and
``seg_000000.drc`` ... (one per local map). A segment's manifest entry carries, besides the transfer
format's keys, ``keyframe_poses`` ({key frame: T_segment_cam}) and ``handover`` (how it was attached to
the previous segment; docs/methods/map-segmentation.md).
"""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
from weldcell.plugins.mapping.segmentation import (
    SegmentationSettings,
    Segmenter,
    chain_poses,
    segment_cloud,
)


class LiveSegments:
    """Local maps of one visit: cut while driving, written when final, optionally served and fetched."""

    def __init__(self, ctx, tr, transfer, settings: SegmentationSettings, map_dir, serve: bool) -> None:
        ms = ctx.settings.map
        self.ctx, self.tr, self.transfer, self.s = ctx, tr, transfer, settings
        self.map_dir = map_dir
        self.voxel, self.step, self.depth = ms.voxel, ms.pixel_step, ms.max_depth
        self.segmenter = Segmenter(settings, ms.voxel, ms.pixel_step, ms.max_depth)
        from weldcell.plugins.mapping.frontend import OrbFrontEnd

        self.frontend = OrbFrontEnd(ctx.settings.frontend)
        cut = {"max_distance": settings.max_distance, "max_points": settings.max_points}
        self.writer = transfer.writer(map_dir, source="weldcell map job (live)", cut=cut)
        self.window = ctx.settings.estimator.window
        self.t0 = time.perf_counter()
        self.written_at: dict[int, float] = {}
        self.server = self.fetched = None
        self._fetch_thread: threading.Thread | None = None
        self.fetch_report = None
        self.fetch_error: str | None = None
        if serve:
            self.server = transfer.serve(map_dir)
            self.fetched = ctx.path("operator_map") / ""
            self._fetch_thread = threading.Thread(target=self._fetch, name="operator-fetch", daemon=True)
            self._fetch_thread.start()

    def _fetch(self) -> None:
        try:
            self.fetch_report = self.transfer.fetch(self.server.address, self.fetched)
        except Exception as e:  # reported in the figures, never stops the mapping
            self.fetch_error = f"{type(e).__name__}: {getattr(e, 'message', e)}"

    # -- while driving ---------------------------------------------------------------------------
    def _poses(self) -> dict[int, np.ndarray]:
        est = self.tr.estimator
        return {k.index: k.T_world_imu @ est.T_imu_cam for k in est.keyframes}

    def on_keyframe(self, kf) -> None:
        est = self.tr.estimator
        prev = est.keyframes[-2] if len(est.keyframes) >= 2 else None
        T = kf.T_world_imu @ est.T_imu_cam
        T_prev = None if prev is None else prev.T_world_imu @ est.T_imu_cam
        if prev is not None and prev.depth is None:  # resumed: the previous key frame from the store
            prev = self._from_store(prev.index)
        ho = self.segmenter.add(kf, T, self.frontend, prev, T_prev)
        if ho is not None:
            self.ctx.reporter.info(
                f"local map {ho.segment} starts at key frame {ho.first_keyframe} (hand-over: {ho.method}"
                f"{', ' + ho.note if ho.note else ''})"
            )
        self.flush(final=False)

    def _from_store(self, index: int):
        from weldcell.plugins.mapping.frontend import FrameFeatures

        rec = next(r for r in self.tr.store.records if r.index == index)
        d = self.tr.store.read(rec)
        f = FrameFeatures(d["pixels"].astype(float), d["descriptors"], d["points"].astype(float))
        return SimpleNamespace(
            index=index, depth=d["depth"], rgb=d["rgb"], features=f, intrinsics=self.tr.store.intrinsics
        )

    def replay(self) -> None:
        """After ``--resume``: the stored key frames cut again (same decisions, same hand-overs)."""
        est = self.tr.estimator
        poses = self._poses()
        prev = None
        for k in est.keyframes:
            cur = self._from_store(k.index)
            self.segmenter.add(
                cur, poses[k.index], self.frontend, prev, None if prev is None else poses[prev.index]
            )
            prev = cur

    def flush(self, final: bool) -> None:
        """Write every closed segment whose key frames have all left the smoother window (poses final);
        with ``final``, every segment."""
        est = self.tr.estimator
        if not est.keyframes:
            return
        t_now = est.keyframes[-1].t
        t_of = {k.index: k.t for k in est.keyframes}
        segs = self.segmenter.segments if final else self.segmenter.closed()
        todo = [
            g for g in segs if not g.written and (final or t_now - t_of[g.keyframes[-1]] > self.window + 1.0)
        ]
        if not todo:
            return
        poses = self._poses()
        T_ws, local = chain_poses(self.segmenter.segments[: todo[-1].id + 1], poses)
        for g in todo:
            P, C = segment_cloud(self.tr.store, g, local, self.voxel, self.step, self.depth)
            extra = {
                "keyframe_poses": {str(k): local[k][1].tolist() for k in g.keyframes},
                "handover": None if g.handover is None else g.handover.to_json(),
            }
            dist = g.end_distance - g.start_distance
            self.writer.add(g.id, P, C, T_ws[g.id], dist, g.keyframes, extra)
            g.written = True
            self.written_at[g.id] = time.perf_counter() - self.t0

    # -- at the end ------------------------------------------------------------------------------
    def finish(self) -> dict:
        """Write the last segments, mark the map complete, wait for the loopback fetch; the figures."""
        self.flush(final=True)
        self.writer.finish()
        done = time.perf_counter() - self.t0
        figs = {
            "segments": len(self.segmenter.segments),
            "segment_handovers": [g.handover.method for g in self.segmenter.segments if g.handover],
            "first_segment_written_s": self.written_at.get(0),
            "map_complete_s": done,
        }
        if self._fetch_thread is not None:
            self._fetch_thread.join(timeout=60.0)
            self.server.stop()
            figs.update(self._check_fetch())
        return figs

    def _check_fetch(self) -> dict:
        rep = self.fetch_report
        if rep is None:
            return {"fetch_ok": False, "fetch_error": self.fetch_error or "the loopback fetch did not end"}
        local = {e["id"]: e["sha256"] for e in self.transfer.manifest(self.map_dir)["segments"]}
        got = {e["id"]: e["sha256"] for e in self.transfer.manifest(self.fetched)["segments"]}
        return {
            "fetch_ok": bool(rep.complete and got == local),
            "fetch_segments": len(got),
            "fetch_received": len(rep.segments),
            "fetch_first_segment_s": rep.first_segment_s,
            "fetch_seconds": rep.seconds,
        }

    def close(self) -> None:
        """Stop serving (also when the run fails)."""
        if self.server is not None:
            self.server.stop()
