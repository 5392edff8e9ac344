"""Weld-region detection (paper 004 §II-C): the simulated detector, back-projection of 2-D boxes
through depth and the camera -> IMU -> world chain into 3-D regions fused across key frames, the
plate-corner measurement (AE), and the operator's confirm / reject / add decisions.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pydantic import Field
from weldcell.plugins.mapping.mapstore import back_project
from weldcell.plugins.mapping.plate import PlateObservations
from weldcell.sdk.errors import DataError
from weldcell.sdk.settings import Settings
from weldcell.sdk.stages import Detection2D

REGIONS_SCHEMA = "weldcell/weld-regions@1"


class SimDetectorSettings(Settings):
    """A detector that projects the simulated site's ground-truth weld regions, with errors."""

    miss_rate: float = Field(0.1, ge=0, le=1, description="probability of missing a visible region")
    false_alarms: float = Field(0.05, ge=0, description="mean false detections per image (Poisson)")
    jitter: float = Field(0.04, ge=0, description="box corner noise, fraction of the box size")
    min_visible: float = Field(0.4, gt=0, le=1, description="visible fraction of a region to detect it")
    max_range: float = Field(8.0, gt=0, description="regions farther than this are not detected [m]")
    seed: int = Field(0, description="random seed")


class SimDetector:
    """``detector.sim``: needs ``meta`` with ``T_world_camera`` (truth), ``intrinsics``, ``depth`` and
    ``regions`` (the site's weld truth: name, kind, corners/min/max)."""

    def __init__(self, settings: SimDetectorSettings) -> None:
        self.s = settings
        self.rng = np.random.default_rng(settings.seed)

    def __call__(self, rgb: np.ndarray, meta: dict | None = None) -> list[Detection2D]:
        if not meta or "regions" not in meta or "T_world_camera" not in meta:
            raise DataError(
                "detector.sim needs the frame's ground truth (meta: T_world_camera, regions)",
                "use detector.sim only with the simulated cell, or choose detector.onnx",
            )
        K, T, depth = meta["intrinsics"], np.asarray(meta["T_world_camera"]), meta.get("depth")
        H, W = rgb.shape[:2]
        out = []
        Tc = np.linalg.inv(T)
        for _i, reg in enumerate(meta["regions"]):
            lo, hi = np.asarray(reg["min"]), np.asarray(reg["max"])
            g = np.stack(np.meshgrid(*[np.linspace(lo[j], hi[j], 5) for j in range(3)]), -1).reshape(-1, 3)
            Pc = g @ Tc[:3, :3].T + Tc[:3, 3]
            front = (Pc[:, 2] > 0.3) & (Pc[:, 2] < self.s.max_range)
            if front.mean() < self.s.min_visible:
                continue
            u = K.fx * Pc[front, 0] / Pc[front, 2] + K.cx
            v = K.fy * Pc[front, 1] / Pc[front, 2] + K.cy
            inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
            if inside.mean() < self.s.min_visible:
                continue
            if depth is not None:  # occlusion: the rendered depth must reach the region
                ui, vi = u[inside].astype(int), v[inside].astype(int)
                d = depth[vi, ui]
                seen = (d <= 0) | (d >= Pc[front][inside, 2] - 0.15)
                if seen.mean() < self.s.min_visible:
                    continue
            if self.rng.random() < self.s.miss_rate:
                continue
            box = np.array([u[inside].min(), v[inside].min(), u[inside].max(), v[inside].max()])
            size = np.array([box[2] - box[0], box[3] - box[1]] * 2)
            box = box + self.rng.normal(0, self.s.jitter, 4) * size
            box = np.clip(box, 0, [W - 1, H - 1, W - 1, H - 1])
            if box[2] - box[0] < 3 or box[3] - box[1] < 3:
                continue
            out.append(
                Detection2D(tuple(map(float, box)), "weld-region", 0, float(self.rng.uniform(0.6, 0.95)))
            )
        for _ in range(self.rng.poisson(self.s.false_alarms)):
            w, h = self.rng.uniform(0.05, 0.2) * W, self.rng.uniform(0.05, 0.2) * H
            x, y = self.rng.uniform(0, W - w), self.rng.uniform(0, H - h)
            out.append(Detection2D((x, y, x + w, y + h), "weld-region", 0, float(self.rng.uniform(0.3, 0.7))))
        return out


@dataclass
class Region:
    """A 3-D weld region fused from detections in several key frames (world frame)."""

    id: str
    label: str
    points: np.ndarray
    observations: list[int] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)
    decision: str = "auto"
    dense: np.ndarray | None = None
    """Vertices of the region's TSDF surface, when built."""
    truth: str | None = None
    plate: PlateObservations | None = None
    """The depth pixels of the key frames that saw the region, with their rays and noise
    (set by the job after driving): what the plate measurement (AE) uses."""

    @property
    def center(self) -> np.ndarray:
        return np.median(self.points, axis=0)

    def oriented_box(self) -> dict:
        """Oriented bounding box (PCA axes): center, R (3x3 columns = axes), extent (m)."""
        P = self.points
        c = P.mean(0)
        _, _, Vt = np.linalg.svd(P - c, full_matrices=False)
        R = Vt.T
        if np.linalg.det(R) < 0:
            R[:, 2] *= -1
        L = (P - c) @ R
        lo, hi = L.min(0), L.max(0)
        return {"center": (c + R @ ((lo + hi) / 2)).tolist(), "R": R.tolist(), "extent": (hi - lo).tolist()}


def detection_points(
    det: Detection2D,
    depth: np.ndarray,
    K,
    T_world_cam: np.ndarray,
    max_depth: float = 8.0,
    shrink: float = 0.1,
) -> np.ndarray:
    """World points of one detection: pixels inside the (slightly shrunk) box with depth, kept where
    the depth belongs to the nearest dominant surface in the box (the detected object, not the
    background seen past its edges)."""
    x0, y0, x1, y1 = det.xyxy
    dx, dy = (x1 - x0) * shrink, (y1 - y0) * shrink
    x0, x1, y0, y1 = int(x0 + dx), int(np.ceil(x1 - dx)), int(y0 + dy), int(np.ceil(y1 - dy))
    if x1 <= x0 or y1 <= y0:
        return np.zeros((0, 3))
    sub = np.zeros_like(depth)
    sub[y0:y1, x0:x1] = depth[y0:y1, x0:x1]
    z = sub[(sub > 0) & (sub <= max_depth)]
    if len(z) < 10:
        return np.zeros((0, 3))
    hist, edges = np.histogram(z, bins=np.arange(z.min(), z.max() + 0.1, 0.1))
    near = edges[np.argmax(hist > 0.15 * hist.max())]  # the first well-populated depth bin
    sub[(sub < near - 0.3) | (sub > near + 0.6)] = 0
    P, _ = back_project(sub, K, T_world_cam, step=1, max_depth=max_depth)
    return P


class RegionFuser:
    """Fuses per-key-frame detections into physical regions: a new observation joins the region of
    the same label whose points it overlaps (centroid within ``merge_distance``)."""

    def __init__(self, merge_distance: float = 0.6, voxel: float = 0.01) -> None:
        self.merge_distance = merge_distance
        self.voxel = voxel
        self.regions: list[Region] = []

    def add(self, det: Detection2D, P: np.ndarray, keyframe: int) -> Region | None:
        if len(P) < 20:
            return None
        c = np.median(P, axis=0)
        best, dbest = None, np.inf
        for r in self.regions:
            if r.label != det.label:
                continue
            d = float(np.linalg.norm(r.center - c))
            if d < dbest:
                best, dbest = r, d
        if best is None or dbest > self.merge_distance:
            best = Region(f"R{len(self.regions) + 1:02d}", det.label, np.zeros((0, 3)))
            self.regions.append(best)
        P = np.vstack([best.points, P])
        q = np.floor(P / self.voxel).astype(np.int64)
        _, keep = np.unique(q, axis=0, return_index=True)
        best.points = P[np.sort(keep)]
        best.observations.append(keyframe)
        best.scores.append(det.score)
        return best


def plate_corners(points: np.ndarray, top_band: float = 0.015) -> np.ndarray | None:
    """The 4 top-face corners of a plate in a region's points: the highest horizontal layer (within
    ``top_band`` of its robust top), its minimum-area rectangle in x-y (OpenCV), at the layer's height."""
    import cv2

    if len(points) < 30:
        return None
    ztop = np.percentile(points[:, 2], 98)
    layer = points[np.abs(points[:, 2] - ztop) < top_band]
    if len(layer) < 20:
        return None
    (cx, cy), (w, h), ang = cv2.minAreaRect(layer[:, :2].astype(np.float32))
    # orientation from the minimum-area rectangle, extent robust to stray points (1st-99th percentile)
    a = np.radians(ang)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    loc = (layer[:, :2] - [cx, cy]) @ R
    lo, hi = np.percentile(loc, 1, axis=0), np.percentile(loc, 99, axis=0)
    box = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]]) @ R.T + [cx, cy]
    return np.column_stack([box, np.full(4, float(np.median(layer[:, 2])))])


def corner_distance_error(est: np.ndarray, true: np.ndarray) -> float:
    """The paper's AE on a fixed-size plate: mean |d_est - d_true| over the 6 corner-to-corner
    distances (4 edges, 2 diagonals), metres; invariant to the map's global pose."""

    def dists(c):
        return np.sort([np.linalg.norm(c[i] - c[j]) for i in range(4) for j in range(i + 1, 4)])

    return float(np.mean(np.abs(dists(est) - dists(true))))


def apply_decisions(regions: list[Region], path: str | Path | None) -> list[dict]:
    """Apply the operator's decisions file (JSON ``{"confirm": [ids], "reject": [ids], "add":
    [{"label", "min": [x,y,z], "max": [x,y,z]}]}``) and return the decision log."""
    log: list[dict] = []
    if path is None:
        return log
    p = Path(path)
    if not p.is_file():
        raise DataError(
            f"operator decisions file {p} does not exist",
            "write it (see docs/jobs/map.md) or drop the `decisions` setting",
        )
    try:
        data = json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise DataError(f"operator decisions file {p} is not JSON: {e}", "fix the file") from None
    by_id = {r.id: r for r in regions}
    for key, status in (("confirm", "confirmed"), ("reject", "rejected")):
        for rid in data.get(key, []):
            if rid not in by_id:
                log.append({"region": rid, "decision": status, "applied": False, "why": "no such region"})
                continue
            by_id[rid].decision = status
            log.append({"region": rid, "decision": status, "applied": True})
    for i, a in enumerate(data.get("add", [])):
        lo, hi = np.asarray(a["min"], float), np.asarray(a["max"], float)
        g = np.stack(np.meshgrid(*[np.linspace(lo[j], hi[j], 6) for j in range(3)]), -1).reshape(-1, 3)
        r = Region(f"A{i + 1:02d}", a.get("label", "weld-region"), g, decision="added")
        regions.append(r)
        log.append({"region": r.id, "decision": "added", "applied": True})
    return log
