"""The refined path (REFINE's output, Algorithm 2 lines 16-20): the recorded tip positions with their
times, and the seam (wall-contact) points derived from them.
"""

from __future__ import annotations

import numpy as np

from .paths import Polyline, left_normal


class RefinedPath:
    """Growing list of recorded tip positions ``P_s`` (base frame, 3-D) with their times."""

    def __init__(self, min_step: float) -> None:
        self.min_step = min_step
        self._pts: list[np.ndarray] = []
        self._t: list[float] = []
        self._line: Polyline | None = None

    def append(self, p: np.ndarray, t: float) -> bool:
        p = np.asarray(p, dtype=float)
        if self._pts and np.linalg.norm(p[:2] - self._pts[-1][:2]) < self.min_step:
            return False
        self._pts.append(p.copy())
        self._t.append(float(t))
        self._line = None
        return True

    @property
    def points(self) -> np.ndarray:
        return np.array(self._pts).reshape(-1, 3)

    @property
    def times(self) -> np.ndarray:
        return np.array(self._t)

    def __len__(self) -> int:
        return len(self._pts)

    def polyline(self) -> Polyline | None:
        if self._line is None and len(self._pts) >= 2:
            self._line = Polyline(self.points, "refined path")
        return self._line

    @property
    def length(self) -> float:
        line = self.polyline()
        return 0.0 if line is None else line.length


def seam_from_tip_path(
    tip_points: np.ndarray, tip_radius: float, wall_side: str, half_window: float = 0.003
) -> np.ndarray:
    """Seam (wall-contact) points: tip centres moved by the tip radius into the wall along the path normal."""
    P = np.asarray(tip_points, dtype=float)
    if len(P) < 2 or tip_radius == 0:
        return P.copy()
    line = Polyline(P, "refined path")
    sign = 1.0 if wall_side == "left" else -1.0
    out = P.copy()
    s_vertices = line.s
    for i, s in enumerate(s_vertices):
        n = sign * left_normal(line.smooth_tangent(float(s), half_window))
        out[i, :2] += tip_radius * n
    return out
