"""Local refinement from an initial guess: our NDT, or a maintained library for comparison / choice
(Open3D point-to-plane ICP, small-gicp GICP/VGICP). Each goes coarse to fine over the same resolution
ladder as NDT (correspondence distance = the level's cell size), so they see the same initial basin."""

from __future__ import annotations

from typing import Literal

import numpy as np
from weldcell.sdk.registration.ndt import NDT, voxel_downsample

Method = Literal["ndt", "icp", "gicp", "vgicp"]
METHODS: tuple[str, ...] = ("ndt", "icp", "gicp", "vgicp")


def refine(ndt: NDT, source: np.ndarray, T_init: np.ndarray, levels: tuple[float, ...], method: str = "ndt"):
    """T_target_source refined by ``method`` over ``levels`` (m, coarse to fine); target = ``ndt.target``."""
    if method == "ndt":
        return ndt.align(source, T_init, resolutions=levels).T
    T = np.asarray(T_init, dtype=float).copy()
    if method in ("gicp", "vgicp"):
        for r in levels:
            res = _gicp(ndt, source, T, r, method)
            T = np.asarray(res.T_target_source)
        return T
    if method == "icp":
        import open3d as o3d

        reg = o3d.pipelines.registration
        for r in levels:
            tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(voxel_downsample(ndt.target, r / 4.0)))
            tgt.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=r, max_nn=30))
            src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(voxel_downsample(source, r / 4.0)))
            res = reg.registration_icp(
                src,
                tgt,
                r,
                T,
                reg.TransformationEstimationPointToPlane(),
                reg.ICPConvergenceCriteria(max_iteration=30),
            )
            T = np.asarray(res.transformation).copy()
        return T
    raise ValueError(f"unknown registration method {method!r}; use one of {', '.join(METHODS)}")


def gicp_target(ndt: NDT, r: float, method: str = "gicp"):
    """small-gicp's target at cell size ``r`` (downsampled at r/4, covariances from 10 neighbours, KD-tree;
    VGICP: a voxel map at r), made once per NDT object and resolution and kept on it (a prepared map)."""
    import small_gicp

    cache = ndt.__dict__.setdefault("_small_gicp", {})
    key = (method, round(r, 9))
    if key not in cache:
        tgt, tree = small_gicp.preprocess_points(
            ndt.target, downsampling_resolution=r / 4.0, num_neighbors=10
        )
        if method == "vgicp":
            vmap = small_gicp.GaussianVoxelMap(r)
            vmap.insert(tgt)
            cache[key] = (vmap, None)
        else:
            cache[key] = (tgt, tree)
    return cache[key]


def _gicp(ndt: NDT, source: np.ndarray, T: np.ndarray, r: float, method: str):
    """small-gicp at cell size ``r`` against the (cached) prepared target."""
    import small_gicp

    tgt, tree = gicp_target(ndt, r, method)
    src, _ = small_gicp.preprocess_points(source, downsampling_resolution=r / 4.0, num_neighbors=10)
    if method == "vgicp":
        return small_gicp.align(tgt, src, T, max_correspondence_distance=r, max_iterations=30)
    return small_gicp.align(
        tgt, src, tree, T, registration_type="GICP", max_correspondence_distance=r, max_iterations=30
    )
