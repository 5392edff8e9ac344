"""Moved to :mod:`weldcell.sdk.pointfit` (other plugins fit point sets too); kept so existing imports
(benchmarks, user scripts, docs/methods/hand-eye.md) keep working."""

from weldcell.sdk.pointfit import (
    PointFit,
    RobustFit,
    batch_residuals,
    rigid_fit_batch,
    robust_point_fit,
    scaled_svd_fit,
)

__all__ = [
    "PointFit",
    "RobustFit",
    "batch_residuals",
    "rigid_fit_batch",
    "robust_point_fit",
    "scaled_svd_fit",
]
