"""Map segmentation into local maps (paper 004 §II-D) and the segmented map folder
``weldcell/map-segments@1``.

A new local map starts after the robot has travelled ``max_distance`` (15 m, the low end of the
paper's 15–20 m) or when it would exceed ``max_points`` (5 × 10^5, Table II's threshold), whichever
comes first. Each point belongs to the trajectory pose nearest to it (the key frame that saw it);
the poses are walked in order and cut into segments. A segment's frame is the pose of its first key
frame: its points are stored in that local frame and ``T_world_segment`` maps them into the world.

Folder::

    MAP_DIR/
      manifest.json     weldcell/map-segments@1 (below); rewritten atomically after each segment
      seg_000000.qpc    one file per segment: quantised (.qpc, default), Draco (.drc) or binary PLY (.ply)

Manifest: ``{"schema", "frame": "world", "units": "m", "complete": bool, "settings": {...},
"segments": [{"id", "file", "encoding", "points", "bytes", "sha256", "T_world_segment" (4x4),
"bounds_world" [[min xyz], [max xyz]], "distance_m", "keyframes" [indices],
"quantisation": {bits, step_m, bound_m, max_error_m, rms_error_m} | null}]}``.
A segment file is written (atomically) before the manifest names it, so a reader of a growing
folder only ever sees finished segments; ``complete`` turns true when the map is finished.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field
from weldcell.plugins.map_transfer import codec
from weldcell.sdk import artifacts
from weldcell.sdk.errors import DataError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length

SCHEMA = "weldcell/map-segments@1"
MANIFEST = "manifest.json"


class SegmentSettings(Settings):
    """How a map is cut into local maps and how each is encoded."""

    max_distance: Length = Field(
        15.0, gt=0, description="new local map after this travel [m] (paper: 15-20 m)"
    )
    max_points: int = Field(500_000, ge=1, description="new local map beyond this many points (Table II)")
    encoding: Literal["quantised", "draco", "ply"] = Field(
        "quantised",
        description="segment file encoding: quantised (<= max_error grid, deflated; fast to decode), draco "
        "(<= max_error, DracoPy) or ply (lossless float32)",
    )
    max_error: Length = Field(
        0.001, gt=0, description="largest geometric error the quantisation (quantised, draco) may add [m]"
    )


@dataclass
class Trajectory:
    """Poses of the robot (or camera) in the world, in travel order."""

    T_world: np.ndarray  # (K, 4, 4)
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # key-frame ids (or 0..K-1)

    def __post_init__(self) -> None:
        self.T_world = np.asarray(self.T_world, dtype=float).reshape(-1, 4, 4)
        if len(self.index) != len(self.T_world):
            self.index = np.arange(len(self.T_world))
        if len(self.T_world) == 0:
            raise DataError("the trajectory has no poses", "give a TUM file or keyframes.json with poses")
        if not np.all(np.isfinite(self.T_world)):
            raise DataError("the trajectory has non-finite poses", "export the trajectory again")

    @property
    def travelled(self) -> np.ndarray:
        """Distance travelled up to each pose [m]."""
        p = self.T_world[:, :3, 3]
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


@dataclass
class Segment:
    """One local map: points in its own frame and the frame's pose in the world."""

    id: int
    points: np.ndarray
    colors: np.ndarray | None
    T_world_segment: np.ndarray
    distance: float = 0.0
    keyframes: list[int] = field(default_factory=list)

    def world_points(self) -> np.ndarray:
        T = self.T_world_segment
        return rigid(self.points, T[:3, :3], T[:3, 3])


def rigid(points: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``R @ p + t`` for each row p of ``points`` (N, 3). Column arithmetic: a (N,3)x(3,3) BLAS product
    was 4-5x slower on a loaded 2-core machine (thread oversubscription)."""
    out = np.empty((len(points), 3))
    for i in range(3):
        out[:, i] = points[:, 0] * R[i, 0] + points[:, 1] * R[i, 1] + points[:, 2] * R[i, 2] + t[i]
    return out


def read_trajectory(path: str | Path) -> Trajectory:
    """A TUM trajectory (``t x y z qx qy qz qw`` per line) or a ``weldcell/keyframes@1`` index."""
    from scipy.spatial.transform import Rotation

    path = Path(path)
    if not path.is_file():
        raise DataError(f"trajectory {path} does not exist", "give a TUM file or a map's keyframes.json")
    if path.suffix == ".json":
        data = artifacts.read_json(path)
        if data.get("schema") != "weldcell/keyframes@1":
            raise DataError(f"{path} is not weldcell/keyframes@1", "give a TUM file or keyframes.json")
        recs = sorted(data["keyframes"], key=lambda r: r["t"])
        return Trajectory(np.array([r["T_world_cam"] for r in recs]), np.array([r["index"] for r in recs]))
    try:
        rows = np.loadtxt(path, comments="#", ndmin=2)
    except ValueError as e:
        raise DataError(f"{path}: not a TUM trajectory ({e})", "one pose a line: t x y z qx qy qz qw") from e
    if rows.shape[1] != 8:
        raise DataError(f"{path}: {rows.shape[1]} columns, TUM has 8", "one pose a line: t x y z qx qy qz qw")
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(rows[:, 4:8]).as_matrix()
    T[:, :3, 3] = rows[:, 1:4]
    return Trajectory(T)


def _split_large(idx: np.ndarray, points: np.ndarray, max_points: int) -> list[np.ndarray]:
    """Indices of one key frame's points, cut into pieces of ≤ max_points along their main axis."""
    if len(idx) <= max_points:
        return [idx]
    p = points[idx] - points[idx].mean(axis=0)
    axis = np.linalg.svd(p[: min(len(p), 100_000)], full_matrices=False)[2][0]
    order = idx[np.argsort(p @ axis, kind="stable")]
    return [order[i : i + max_points] for i in range(0, len(order), max_points)]


def plan_segments(
    points: np.ndarray, traj: Trajectory, s: SegmentSettings
) -> list[tuple[int, list, np.ndarray]]:
    """(first pose, key frames, point indices) of each local map, in travel order."""
    from scipy.spatial import cKDTree

    owner = cKDTree(traj.T_world[:, :3, 3]).query(points, workers=-1)[1]
    order = np.argsort(owner, kind="stable")
    starts = np.searchsorted(owner[order], np.arange(len(traj.T_world) + 1))
    dist = traj.travelled
    plans: list[tuple[int, list, np.ndarray]] = []
    first, kfs, parts, count = 0, [], [], 0

    def close() -> None:
        if parts:
            plans.append((first, list(kfs), np.concatenate(parts)))

    for k in range(len(traj.T_world)):
        mine = order[starts[k] : starts[k + 1]]
        if kfs and (dist[k] - dist[first] >= s.max_distance or count + len(mine) > s.max_points):
            close()
            first, kfs, parts, count = k, [], [], 0
        for piece in _split_large(mine, points, s.max_points):
            if count and count + len(piece) > s.max_points:
                close()
                first, kfs, parts, count = k, [], [], 0
            parts.append(piece)
            count += len(piece)
        kfs.append(int(traj.index[k]))
    close()
    return plans


def segment_map(
    points: np.ndarray, colors: np.ndarray | None, traj: Trajectory, s: SegmentSettings
) -> list[Segment]:
    """Cut a posed map (world points + trajectory) into local maps in their own frames."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) == 0:
        raise DataError("the map has no points", "give a non-empty cloud")
    if not np.all(np.isfinite(points)):
        raise DataError("the map has non-finite points", "drop NaN points before segmenting")
    out = []
    for i, (first, kfs, idx) in enumerate(plan_segments(points, traj, s)):
        T = traj.T_world[first]
        R, t = T[:3, :3], T[:3, 3]
        local = rigid(points[idx], R.T, -R.T @ t)  # T_segment_world = T_world_segment^-1
        dist = float(traj.travelled[min(first + len(kfs), len(traj.T_world)) - 1] - traj.travelled[first])
        col = None if colors is None else colors[idx]
        out.append(Segment(i, local, col, T.copy(), dist, kfs))
    return out


class SegmentWriter:
    """Writes a segmented map folder one segment at a time (a server may serve it while it grows)."""

    def __init__(self, root: str | Path, settings: SegmentSettings | None = None, source: str = "") -> None:
        self.root = Path(root)
        self.settings = settings or SegmentSettings()
        self.root.mkdir(parents=True, exist_ok=True)
        self.manifest = {
            "schema": SCHEMA,
            "frame": "world",
            "units": "m",
            "complete": False,
            "source": source,
            "settings": self.settings.model_dump(mode="json"),
            "segments": [],
        }
        self._save()

    def _save(self) -> None:
        artifacts.write_json(self.root / MANIFEST, self.manifest)

    def add(self, seg: Segment, extra: dict | None = None) -> dict:
        """Encode and write one segment, then list it in the manifest; returns its manifest entry.
        ``extra`` adds keys to the entry (e.g. the key frames' poses and the hand-over of a live map)."""
        s = self.settings
        data, quant = codec.encode(seg.points, seg.colors, s.encoding, s.max_error)
        name = f"seg_{seg.id:06d}.{codec.SUFFIX[s.encoding]}"
        artifacts.write_bytes(self.root / name, data)
        w = seg.world_points()
        entry = {
            "id": seg.id,
            "file": name,
            "encoding": s.encoding,
            "points": len(seg.points),
            "bytes": len(data),
            "sha256": _sha256(data),
            "T_world_segment": seg.T_world_segment.tolist(),
            "bounds_world": [w.min(axis=0).tolist(), w.max(axis=0).tolist()],
            "distance_m": seg.distance,
            "keyframes": seg.keyframes,
            "quantisation": None if quant is None else quant.to_json(),
            **(extra or {}),
        }
        self.manifest["segments"].append(entry)
        self._save()
        return entry

    def add_existing(self, src_root: str | Path, entry: dict, new_id: int | None = None) -> dict:
        """List a segment of another folder unchanged: its file copied byte for byte (checked against its
        sha256), its manifest entry kept (a new map version shares its unchanged segments bit-identically)."""
        src = Path(src_root) / entry["file"]
        data = src.read_bytes() if src.is_file() else b""
        if _sha256(data) != entry["sha256"]:
            raise DataError(
                f"segment {entry['id']} ({src}) is missing or fails its sha256", "write the map again"
            )
        e = dict(entry)
        if new_id is not None and new_id != e["id"]:
            e["id"] = new_id
            e["file"] = f"seg_{new_id:06d}{Path(entry['file']).suffix}"
        artifacts.write_bytes(self.root / e["file"], data)
        self.manifest["segments"].append(e)
        self._save()
        return e

    def finish(self) -> dict:
        """Mark the map complete."""
        self.manifest["complete"] = True
        self._save()
        return self.manifest


def _sha256(data: bytes) -> str:
    import hashlib

    return hashlib.sha256(data).hexdigest()


def write_segmented_map(
    root: str | Path,
    points: np.ndarray,
    colors: np.ndarray | None,
    traj: Trajectory,
    settings: SegmentSettings | None = None,
    source: str = "",
) -> dict:
    """Segment a posed map and write the whole folder; returns the manifest."""
    s = settings or SegmentSettings()
    w = SegmentWriter(root, s, source)
    for seg in segment_map(points, colors, traj, s):
        w.add(seg)
    return w.finish()


def read_manifest(root: str | Path) -> dict:
    """The manifest of a segmented map folder (DataError with the fix when missing or invalid)."""
    p = Path(root) / MANIFEST
    if not p.is_file():
        raise DataError(
            f"{root} has no {MANIFEST}: not a segmented map folder",
            "make one with `weldcell map segment CLOUD --trajectory TRAJ -o MAP_DIR`",
        )
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"{p} is not valid JSON ({e})", "write the map folder again") from e
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        got = data.get("schema") if isinstance(data, dict) else None
        raise DataError(f"{p} is not {SCHEMA} (schema {got!r})", "give a folder written by `weldcell map`")
    ids = [s.get("id") for s in data.get("segments", [])]
    if len(set(ids)) != len(ids):
        raise DataError(f"{p} lists a segment id twice", "write the map folder again")
    return data


def load_segment(root: str | Path, entry: dict, verify: bool = True) -> Segment:
    """One segment of a folder (checked against its sha256 first)."""
    path = Path(root) / entry["file"]
    if not path.is_file():
        raise DataError(f"segment file {path} is missing", "fetch or write the map again")
    if verify and artifacts.sha256_file(path) != entry["sha256"]:
        raise DataError(f"segment {entry['id']} ({path}) fails its sha256", "fetch or write the map again")
    pts, col = codec.decode_file(path, entry["encoding"])
    return Segment(
        entry["id"],
        pts,
        col,
        np.array(entry["T_world_segment"]),
        entry.get("distance_m", 0.0),
        entry.get("keyframes", []),
    )


def load_world_cloud(root: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """All segments of a folder joined in the world frame."""
    m = read_manifest(root)
    segs = [load_segment(root, e) for e in m["segments"]]
    if not segs:
        raise DataError(f"{root} has no segments yet", "wait for the map or fetch it again")
    pts = np.concatenate([s.world_points() for s in segs])
    cols = None if any(s.colors is None for s in segs) else np.concatenate([s.colors for s in segs])
    return pts, cols
