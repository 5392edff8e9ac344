"""Synthetic posed maps for the map-transfer tests."""

from __future__ import annotations

import numpy as np
from weldcell.plugins.map_transfer.segments import SegmentSettings, Trajectory, segment_map


def corridor(n_points: int = 60_000, length: float = 50.0, seed: int = 0):
    """A 3 m wide corridor scanned along a bent path: world points, colours and the trajectory."""
    rng = np.random.default_rng(seed)
    k = max(2, int(length / 0.2))  # a key frame every 0.2 m (paper)
    s = np.linspace(0.0, length, k)
    heading = 0.4 + 0.02 * s  # a gently curving path, not aligned with any axis
    xy = np.column_stack(
        [np.cumsum(np.cos(heading)) * (s[1] - s[0]), np.cumsum(np.sin(heading)) * (s[1] - s[0])]
    )
    T = np.tile(np.eye(4), (k, 1, 1))
    c, sn = np.cos(heading), np.sin(heading)
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -sn, sn, c
    T[:, :2, 3] = xy
    T[:, 2, 3] = 1.2
    i = rng.integers(0, k, n_points)
    lateral = rng.uniform(-1.5, 1.5, n_points)
    pts = np.column_stack(
        [xy[i, 0] - sn[i] * lateral, xy[i, 1] + c[i] * lateral, rng.uniform(0, 3, n_points)]
    )
    pts[:, :2] += rng.normal(0, 0.05, (n_points, 2))
    return pts, rng.random((n_points, 3)), Trajectory(T)


def segments_of(points, colors, traj, **kw):
    return segment_map(points, colors, traj, SegmentSettings(**kw))
