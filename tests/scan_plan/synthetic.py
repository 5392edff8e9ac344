"""Synthetic workpieces with known surfaces for the scan_plan tests and benchmarks."""

from __future__ import annotations

import numpy as np


def corner_workpiece(
    spacing: float = 0.002, noise: float = 0.0, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """A base plate (0.2 x 0.2 m, z = 0) with two welded upright plates at x = 0.1 m and y = 0.15 m:
    three orthogonal planes, so every rigid motion is observable. Returns (points, unit normals)."""
    rng = np.random.default_rng(seed)

    def patch(u0, u1, v0, v1, make):
        n = int((u1 - u0) * (v1 - v0) / spacing**2)
        u, v = rng.uniform(u0, u1, n), rng.uniform(v0, v1, n)
        return make(u, v)

    parts = [
        patch(0, 0.2, 0, 0.2, lambda u, v: (np.c_[u, v, 0 * u], [0, 0, 1.0])),
        patch(0, 0.2, 0, 0.06, lambda u, v: (np.c_[0.1 + 0 * u, u, v], [1.0, 0, 0])),
        patch(0, 0.1, 0, 0.04, lambda u, v: (np.c_[u, 0.15 + 0 * u, v], [0, -1.0, 0])),
    ]
    P = np.concatenate([p for p, _ in parts])
    N = np.concatenate([np.tile(n, (len(p), 1)) for p, n in parts])
    if noise:
        P = P + N * rng.normal(0.0, noise, (len(P), 1))
    return P, N
