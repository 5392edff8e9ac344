"""Global registration without an initial guess: FPFH features + RANSAC (Open3D), voxel size from the data.

The voxel is the smallest of 2 x the point spacing growing by 1.5 at which both clouds keep at most
``max_points`` points (FPFH and RANSAC cost grow with the count; the scene's structure survives at that
size); normals use 2 x, FPFH 5 x the voxel (Open3D's tutorial ratios, Rusu 2009: the feature radius must
exceed the normal radius); a correspondence is an inlier within 1.5 x the voxel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field
from weldcell.sdk.registration.ndt import point_spacing
from weldcell.sdk.settings import Settings


class GlobalSettings(Settings):
    """FPFH + RANSAC settings; the voxel is derived from the data unless given."""

    voxel: float = Field(0.0, ge=0.0, description="downsampling voxel in m (0: derived)")
    max_points: int = Field(3000, ge=500, description="points per cloud after downsampling")
    max_iterations: int = Field(200000, ge=1000, description="RANSAC iterations")
    confidence: float = Field(0.999, gt=0, lt=1, description="RANSAC stopping confidence")
    seed: int = Field(0, description="RANSAC random seed (Open3D's global seed)")


@dataclass
class GlobalResult:
    """T_target_source from features; ``fitness`` is Open3D's inlier share of the source."""

    T: np.ndarray
    fitness: float
    inlier_rmse: float
    voxel: float


def derive_voxel(a: np.ndarray, b: np.ndarray, max_points: int) -> float:
    from weldcell.sdk.registration.ndt import voxel_keys

    v = 2.0 * max(point_spacing(a), point_spacing(b))
    while max(len(voxel_keys(a, v)[1]), len(voxel_keys(b, v)[1])) > max_points:
        v *= 1.5
    return v


def features(pts: np.ndarray, voxel: float):
    """(downsampled Open3D cloud with normals, its FPFH features) at ``voxel``: computed once per cloud
    and voxel, then matched by as many RANSAC runs as needed (:func:`ransac`)."""
    import open3d as o3d

    return _features(o3d, pts, voxel)


def _features(o3d, pts: np.ndarray, voxel: float):
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).voxel_down_sample(voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    f = o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    )
    return pc, f


def global_register(
    target: np.ndarray, source: np.ndarray, settings: GlobalSettings | None = None
) -> GlobalResult:
    """T_target_source by FPFH matching + RANSAC (Open3D feature-matching RANSAC)."""
    import open3d as o3d

    s = settings or GlobalSettings()
    voxel = s.voxel or derive_voxel(target, source, s.max_points)
    return ransac(_features(o3d, target, voxel), _features(o3d, source, voxel), voxel, s)


def ransac(target_features, source_features, voxel: float, settings: GlobalSettings) -> GlobalResult:
    """T_target_source from precomputed :func:`features` by Open3D's feature-matching RANSAC (seeded)."""
    import open3d as o3d

    s = settings
    pt, ft = target_features
    ps, fs = source_features
    o3d.utility.random.seed(s.seed)
    reg = o3d.pipelines.registration
    dist = 1.5 * voxel
    res = reg.registration_ransac_based_on_feature_matching(
        ps,
        pt,
        fs,
        ft,
        True,
        dist,
        reg.TransformationEstimationPointToPoint(False),
        3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
        reg.RANSACConvergenceCriteria(s.max_iterations, s.confidence),
    )
    return GlobalResult(
        np.asarray(res.transformation).copy(), float(res.fitness), float(res.inlier_rmse), voxel
    )
