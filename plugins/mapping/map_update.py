"""Map update after relocalization (paper 004 §II-E, end): the new visit's key frames update the prior map
where the scene changed, and the map is kept in versions.

Change detection is symmetric free-space evidence, not just "far from the other map":

* **removed**: a prior-map point that the new visit's depth images *saw through* (measured depth beyond
  the point by more than the margin) in at least ``min_views`` key frames and *saw at* in none;
* **added**: a new-visit point that the prior visit's key frames saw through the same way (so it was free
  space then); a new-visit point that no prior key frame observed at all is an *extension* (newly seen
  area), added to the map and reported apart;
* changed and extension points are grouped (connected within 2 x ``change_distance``) and groups smaller
  than ``min_points`` are dropped (depth noise at grazing angles, scattered far points).

The margin at depth z is ``change_distance + 0.01 z^2`` (stereo depth noise grows with z^2).

Versions (``MAP_VERSIONS/index.json``, ``weldcell/map-versions@1``)::

    map_versions/
      index.json   {"schema", "current": "v2", "versions": [{"version": "v1", "parent": null, ...},
                    {"version": "v2", "parent": "v1", "changed_segments": [..], "unchanged_segments": [..],
                     "changes": [{"kind", "points", "center", "min", "max", "segment"}],
                     "relocalization": {..}}]}
      v1/          weldcell/map-segments@1 folder (the prior map)
      v2/          the same with the changed segments re-written; every unchanged segment is the v1 file
                   byte for byte (same sha256)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from weldcell.sdk import artifacts
from weldcell.sdk.errors import DataError

VERSIONS_SCHEMA = "weldcell/map-versions@1"


@dataclass
class View:
    """A depth image and where it was taken: ``T_map_cam`` in the frame of the points tested against it."""

    T_map_cam: np.ndarray
    depth: np.ndarray
    K: object


@dataclass
class MapChanges:
    """Changed points in the prior map's frame: removed (prior-map indices), added and extension points."""

    removed: np.ndarray
    added: np.ndarray
    extension: np.ndarray
    groups: list[dict] = field(default_factory=list)


def visibility(points: np.ndarray, views: list[View], margin: float, max_depth: float) -> tuple:
    """(through, at): per point, in how many views the measured depth passed beyond it / matched it."""
    through = np.zeros(len(points), int)
    at = np.zeros(len(points), int)
    for v in views:
        Ti = np.linalg.inv(v.T_map_cam)
        P = points @ Ti[:3, :3].T + Ti[:3, 3]
        z = P[:, 2]
        ok = (z > 0.3) & (z < max_depth)
        u = np.round(P[ok, 0] / z[ok] * v.K.fx + v.K.cx).astype(int)
        w = np.round(P[ok, 1] / z[ok] * v.K.fy + v.K.cy).astype(int)
        H, W = v.depth.shape
        inside = (u >= 0) & (u < W) & (w >= 0) & (w < H)
        idx = np.nonzero(ok)[0][inside]
        d = v.depth[w[inside], u[inside]].astype(float)
        zz = z[idx]
        tol = margin + 0.01 * zz**2
        valid = np.isfinite(d) & (d > 0)
        through[idx[valid & (d > zz + tol)]] += 1
        at[idx[valid & (np.abs(d - zz) <= tol)]] += 1
    return through, at


def _groups(points: np.ndarray, radius: float, min_points: int) -> np.ndarray:
    """Labels of connected groups (points within ``radius``); -1 for groups below ``min_points``."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    if len(points) == 0:
        return np.zeros(0, int)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    from scipy.sparse import coo_matrix

    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2)
    _, lab = connected_components(g, directed=False)
    counts = np.bincount(lab)
    lab[counts[lab] < min_points] = -1
    return lab


def detect_changes(
    prior: np.ndarray,
    current: np.ndarray,
    prior_views: list[View],
    current_views: list[View],
    change_distance: float,
    min_points: int,
    max_depth: float,
    min_views: int = 2,
) -> MapChanges:
    """Removed prior points, added and extension current points (``current`` already in the prior frame,
    ``current_views`` posed in the prior frame)."""
    from scipy.spatial import cKDTree

    near_c = cKDTree(current).query(prior, distance_upper_bound=change_distance)[0] < np.inf
    t, a = visibility(prior, current_views, change_distance, max_depth)
    removed = np.nonzero((t >= min_views) & (a == 0) & ~near_c)[0]
    far = cKDTree(prior).query(current, distance_upper_bound=change_distance)[0] == np.inf
    t, a = visibility(current, prior_views, change_distance, max_depth)
    added = np.nonzero(far & (t >= min_views) & (a == 0))[0]
    extension = np.nonzero(far & (t == 0) & (a == 0))[0]
    extension = extension[_groups(current[extension], 2.0 * change_distance, min_points) >= 0]
    out = MapChanges(np.zeros(0, int), np.zeros(0, int), extension)
    for kind, idx, pts in (("removed", removed, prior), ("added", added, current)):
        lab = _groups(pts[idx], 2.0 * change_distance, min_points)
        keep = idx[lab >= 0]
        setattr(out, kind, keep)
        for g in np.unique(lab[lab >= 0]):
            P = pts[idx[lab == g]]
            out.groups.append(
                {
                    "kind": kind,
                    "points": len(P),
                    "center": np.round(P.mean(0), 3).tolist(),
                    "min": P.min(0).tolist(),
                    "max": P.max(0).tolist(),
                }
            )
    return out


def _load(transfer, root) -> tuple[dict, list, np.ndarray, np.ndarray, np.ndarray | None]:
    m = transfer.manifest(root)
    if not m["segments"]:
        raise DataError(f"{root} has no local maps", "map the site first (job map)")
    segs = [transfer.segment(root, e) for e in m["segments"]]
    pts = np.concatenate([s.world_points() for s in segs])
    sid = np.concatenate([np.full(len(s.points), i) for i, s in enumerate(segs)])
    cols = None if any(s.colors is None for s in segs) else np.concatenate([s.colors for s in segs])
    return m, segs, pts, sid, cols


def start_versions(transfer, prior_dir, versions_root) -> Path:
    """``versions_root/v1``: the prior map's local maps carried over byte for byte, and the index."""
    root = Path(versions_root)
    m = transfer.manifest(prior_dir)
    w = transfer.writer(root / "v1", source=str(prior_dir), cut=_cut(m))
    for e in m["segments"]:
        w.add_existing(prior_dir, e)
    w.finish()
    index = {
        "schema": VERSIONS_SCHEMA,
        "current": "v1",
        "versions": [{"version": "v1", "parent": None, "source": str(prior_dir)}],
    }
    artifacts.write_json(root / "index.json", index)
    return root / "v1"


def _cut(m: dict) -> dict:
    s = m.get("settings", {})
    return {k: s[k] for k in ("max_distance", "max_points") if k in s}


def write_version(
    transfer,
    versions_root,
    changes: MapChanges,
    current: np.ndarray,
    current_colors: np.ndarray | None,
    relocalization: dict | None = None,
) -> dict:
    """The next version: the current one with ``changes`` applied segment by segment (unchanged local maps
    byte-identical); returns its index entry."""
    from scipy.spatial import cKDTree

    root = Path(versions_root)
    index = artifacts.read_json(root / "index.json")
    parent = index["current"]
    src = root / parent
    m, segs, pts, sid, cols = _load(transfer, src)
    new = list(changes.added) + list(changes.extension)
    new_pts = current[new] if new else np.zeros((0, 3))
    new_sid = sid[cKDTree(pts).query(new_pts)[1]] if len(new_pts) else np.zeros(0, int)
    gone = np.zeros(len(pts), bool)
    gone[changes.removed] = True
    name = f"v{int(parent[1:]) + 1}"
    w = transfer.writer(root / name, source=f"{parent} + new visit", cut=_cut(m))
    changed = []
    offset = 0
    for i, (e, seg) in enumerate(zip(m["segments"], segs, strict=True)):
        n = len(seg.points)
        mine_gone = gone[offset : offset + n]
        offset += n
        add = new_pts[new_sid == i]
        if not mine_gone.any() and not len(add):
            w.add_existing(src, e)
            continue
        changed.append(e["id"])
        T = np.asarray(e["T_world_segment"], float)
        Ti = np.linalg.inv(T)
        local = np.vstack([seg.points[~mine_gone], add @ Ti[:3, :3].T + Ti[:3, 3]])
        col = None
        if seg.colors is not None:
            ac = (
                current_colors[np.asarray(new)[new_sid == i]]
                if current_colors is not None and len(add)
                else None
            )
            col = np.vstack([seg.colors[~mine_gone], ac if ac is not None else np.full((len(add), 3), 0.5)])
        keep = {k: e[k] for k in ("keyframe_poses", "handover") if k in e}
        w.add(
            e["id"],
            local,
            col,
            T,
            e.get("distance_m", 0.0),
            e.get("keyframes", []),
            {**keep, "updated_in": name},
        )
    for g in changes.groups:
        g["segment"] = int(sid[cKDTree(pts).query(np.array(g["center"]))[1]])
    w.finish({"version": name, "parent": parent})
    entry = {
        "version": name,
        "parent": parent,
        "changed_segments": changed,
        "unchanged_segments": [e["id"] for e in m["segments"] if e["id"] not in changed],
        "removed_points": int(len(changes.removed)),
        "added_points": int(len(changes.added)),
        "extension_points": int(len(changes.extension)),
        "changes": changes.groups,
        "relocalization": relocalization,
    }
    index["versions"].append(entry)
    index["current"] = name
    artifacts.write_json(root / "index.json", index)
    return entry


def prior_points(transfer, root) -> tuple[np.ndarray, np.ndarray | None]:
    """The map of a version (or any segmented folder) in its world frame."""
    _, _, pts, _, cols = _load(transfer, root)
    return pts, cols
