"""A captured view: a cloud in the camera frame with the robot's flange pose at that instant."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from weldcell.sdk.cloud import PointCloud


@dataclass
class PosedScan:
    """One captured view: ``cloud`` in the camera frame and the flange pose ``T_base_flange`` at capture."""

    cloud: PointCloud
    T_base_flange: np.ndarray
    timestamp: float = 0.0
