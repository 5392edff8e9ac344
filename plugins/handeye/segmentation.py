"""Flange segmentation from a raw scan (paper §2.1.4, first step).

Pass-through box (removes table, floor, background), statistical outlier removal, Euclidean
clustering (DBSCAN) with the flange-size constraint ("the segmented cluster can not have a range
more extensive than the diameter of the tool flange"), then the flange face plane by RANSAC.
Clustering runs on a voxel-down-sampled copy for speed; the full-resolution points of the chosen
cluster are recovered by a radius search, so the circle fit sees every measured point.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from weldcell.sdk.errors import DataError
from weldcell.sdk.repeatable import open3d_serial


@dataclass
class SegmentSettings:
    """Segmentation settings (metres). ``box_min``/``box_max``: pass-through box in the camera frame
    (None: keep all). ``flange_diameter``: the ISO 9409-1 outer diameter d3."""

    box_min: tuple[float, float, float] | None = None
    box_max: tuple[float, float, float] | None = None
    sor_neighbors: int = 20
    sor_std_ratio: float = 2.0
    voxel: float = 0.001
    cluster_eps: float = 0.004
    cluster_min_points: int = 30
    flange_diameter: float = 0.063
    size_tolerance: float = 0.15
    min_size_fraction: float = 0.5
    plane_distance: float = 0.001
    plane_iterations: int = 1000


@dataclass
class FlangeSegment:
    """The flange face points (M, 3), its plane normal (toward the camera) and a report."""

    face: np.ndarray
    normal: np.ndarray
    cluster: np.ndarray
    report: dict = field(default_factory=dict)


def _extent(points: np.ndarray) -> float:
    c = points - points.mean(0)
    _, _, Vt = np.linalg.svd(c, full_matrices=False)
    proj = c @ Vt[:2].T
    return float(np.max(np.ptp(proj, axis=0)))


def segment_flange(points: np.ndarray, settings: SegmentSettings | None = None) -> FlangeSegment:
    """Isolate the flange face in a raw scan (N, 3, metres, camera frame). Raises DataError with the
    cluster sizes found when no cluster fits the flange-size constraint."""
    import open3d as o3d

    s = settings or SegmentSettings()
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1) & np.any(P != 0, axis=1)]
    report: dict = {"n_raw": int(len(P))}
    if s.box_min is not None or s.box_max is not None:
        lo = np.asarray(s.box_min if s.box_min is not None else [-np.inf] * 3, float)
        hi = np.asarray(s.box_max if s.box_max is not None else [np.inf] * 3, float)
        P = P[np.all((P >= lo) & (P <= hi), axis=1)]
    report["n_box"] = int(len(P))
    if len(P) < s.cluster_min_points:
        raise DataError(
            f"only {len(P)} points left after the pass-through box",
            "widen the box (box_min/box_max, metres, camera frame) or check the cloud's units",
        )
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    _, keep = pc.remove_statistical_outlier(s.sor_neighbors, s.sor_std_ratio)
    P = P[np.asarray(keep, dtype=int)]
    report["n_sor"] = int(len(P))
    down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    if s.voxel and s.voxel > 0:
        down = down.voxel_down_sample(s.voxel)
    D = np.asarray(down.points)
    labels = np.asarray(down.cluster_dbscan(s.cluster_eps, max(3, s.cluster_min_points // 10)))
    clusters = []
    for lab in np.unique(labels[labels >= 0]):
        pts = D[labels == lab]
        if len(pts) < 3:
            continue
        clusters.append((lab, len(pts), _extent(pts)))
    report["clusters"] = [{"points": n, "extent_mm": round(e * 1e3, 2)} for _, n, e in clusters]
    dmax = s.flange_diameter * (1 + s.size_tolerance)
    dmin = s.flange_diameter * s.min_size_fraction
    fits = [c for c in clusters if dmin <= c[2] <= dmax]
    if not fits:
        raise DataError(
            f"no cluster is flange-sized ({dmin * 1e3:.0f}-{dmax * 1e3:.0f} mm); found extents "
            f"{[c['extent_mm'] for c in report['clusters']][:10]} mm",
            "set flange_diameter to the flange's outer diameter, tighten the pass-through box, "
            "or raise cluster_eps if the flange is split",
        )
    lab = max(fits, key=lambda c: c[1])[0]
    tree = cKDTree(D[labels == lab])
    dist, _ = tree.query(P, distance_upper_bound=max(s.voxel, 1e-9) * 1.5 + 1e-9)
    cluster = P[np.isfinite(dist)]
    report["n_cluster"] = int(len(cluster))
    cpc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cluster))
    o3d.utility.random.seed(0)
    with open3d_serial():  # threaded RANSAC draws in a load-dependent order
        plane, idx = cpc.segment_plane(s.plane_distance, 3, s.plane_iterations)
    face = cluster[np.asarray(idx, dtype=int)]
    n = np.asarray(plane[:3], float)
    n /= np.linalg.norm(n)
    if np.dot(n, -face.mean(0)) < 0:
        n = -n
    report["n_face"] = int(len(face))
    report["extent_mm"] = round(_extent(face) * 1e3, 2)
    if len(face) < 50:
        raise DataError(
            f"flange face plane has only {len(face)} points",
            "the flange must face the camera (angle below θmax); check plane_distance",
        )
    return FlangeSegment(face, n, cluster, report)
