"""Depth from a rectified stereo pair with OpenCV's semi-global matching (StereoSGBM)."""

from __future__ import annotations

import math

import cv2
import numpy as np


class StereoDepth:
    """SGBM tuned from the depth range: the disparity search covers ``fx*B/max_depth .. fx*B/min_depth``."""

    def __init__(
        self,
        fx_baseline: float,
        min_depth: float,
        max_depth: float,
        block_size: int = 5,
        uniqueness: int = 10,
    ) -> None:
        self.fx_baseline = float(fx_baseline)
        d_max = fx_baseline / min_depth
        d_min = fx_baseline / max_depth
        self.min_disp = max(0, int(math.floor(d_min)) - 1)
        self.num_disp = max(16, int(math.ceil((d_max - self.min_disp + 1) / 16.0)) * 16)
        self.min_depth, self.max_depth = min_depth, max_depth
        bs = block_size | 1
        self.sgbm = cv2.StereoSGBM_create(
            minDisparity=self.min_disp,
            numDisparities=self.num_disp,
            blockSize=bs,
            P1=8 * bs * bs,
            P2=32 * bs * bs,
            disp12MaxDiff=1,
            uniquenessRatio=uniqueness,
            speckleWindowSize=100,
            speckleRange=2,
            mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
        )

    def depth(self, left_gray: np.ndarray, right_gray: np.ndarray) -> np.ndarray:
        """Depth [m] (float32) in the rectified left camera; 0 where there is no reliable match."""
        disp = self.sgbm.compute(left_gray, right_gray).astype(np.float32) / 16.0
        valid = disp > max(self.min_disp, 0.5)
        depth = np.zeros(disp.shape, np.float32)
        depth[valid] = self.fx_baseline / disp[valid]
        depth[(depth < self.min_depth) | (depth > self.max_depth)] = 0.0
        return depth
