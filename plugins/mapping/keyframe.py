"""What the mapping estimator (:mod:`weldcell.plugins.mapping.estimator`) hands on: its key frames (images,
features and the estimated IMU state) and the result of each camera frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from weldcell.hal.readings import Intrinsics
from weldcell.plugins.mapping.frontend import FrameFeatures, PnPResult


@dataclass
class KeyFrame:
    """A key frame: time (s, sensor clock), images, features and the estimated IMU state."""

    index: int
    t: float
    stamp: float
    rgb: np.ndarray
    depth: np.ndarray
    intrinsics: Intrinsics
    features: FrameFeatures
    T_world_imu: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias: np.ndarray = field(default_factory=lambda: np.zeros(6))
    visual: bool = True
    """False when the key frame was placed by the IMU alone (tracking lost)."""
    truth: np.ndarray | None = None
    covariance: np.ndarray | None = None
    """6x6 covariance of ``T_world_imu`` after the global batch (gtsam Pose3 tangent space: [rotation,
    translation], body frame); None before it or when it could not be computed."""


@dataclass
class FrameResult:
    """What :meth:`~weldcell.plugins.mapping.estimator.VioEstimator.process_frame` returns for one frame."""

    t: float
    T_world_cam: np.ndarray | None
    """None while initialising."""
    keyframe: KeyFrame | None
    tracked: bool
    events: list[str]


@dataclass
class TrackedFrame:
    """One camera frame after tracking, as the estimator turns it into a key frame: its images and
    features, the tracked IMU pose and the IMU prediction since the last key frame."""

    t: float
    rgb: np.ndarray
    depth: np.ndarray | None
    intrinsics: Intrinsics
    features: FrameFeatures
    T_world_imu: np.ndarray
    """PnP pose against the last key frame, or the IMU prediction when tracking failed."""
    velocity: np.ndarray
    """Predicted velocity in the world (m/s)."""
    preintegrated: Any
    """gtsam ``PreintegratedCombinedMeasurements`` from the last key frame to ``t``."""
    imu_covered: bool
    """Whether the IMU samples reach ``t`` (else the prediction is constant velocity)."""
    pnp: PnPResult | None
    truth: np.ndarray | None = None
