"""The mobile robot's sensor mounts used by the cell-4 mapping tests (same as profiles/cell4-map-sim.toml)."""

from __future__ import annotations

import numpy as np
from weldcell.sdk.geometry import T_from_rpy

T_BASE_CAM = T_from_rpy(np.radians([-95.0, 0.0, -90.0]), [0.3, 0.0, 1.0])
T_BASE_IMU = T_from_rpy([0.0, 0.0, 0.0], [0.0, 0.0, 0.5])
