"""Synthetic sites for tests and benchmarks: a ground plane with boxes, pipes and walls, sampled as a
surface cloud (like a voxel map of the site), and "visits": a part of the site in its own world frame."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def _plane(rng, origin, u, v, spacing):
    n = max(int(np.linalg.norm(u) * np.linalg.norm(v) / spacing**2), 4)
    a, b = rng.random(n), rng.random(n)
    return origin + a[:, None] * u + b[:, None] * v


def _box(rng, c, size, spacing):
    c, s = np.asarray(c, float), np.asarray(size, float)
    lo = c - s / 2
    ex, ey, ez = np.diag(s)
    faces = [
        (lo, ex, ey),
        (lo + ez, ex, ey),
        (lo, ex, ez),
        (lo + ey, ex, ez),
        (lo, ey, ez),
        (lo + ex, ey, ez),
    ]
    return np.vstack([_plane(rng, o, u, v, spacing) for o, u, v in faces])


def _pipe(rng, p0, p1, radius, spacing):
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    length = np.linalg.norm(axis)
    n = max(int(2 * np.pi * radius * length / spacing**2), 4)
    d = axis / length
    u = np.cross(d, [0, 0, 1] if abs(d[2]) < 0.9 else [1, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    t, phi = rng.random(n) * length, rng.random(n) * 2 * np.pi
    return p0 + t[:, None] * d + radius * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)


def site_cloud(
    seed: int = 0,
    size: tuple[float, float] = (40.0, 30.0),
    spacing: float = 0.12,
    noise: float = 0.005,
    sample_seed: int | None = None,
) -> np.ndarray:
    """A site (the layout depends on ``seed``; the surface sampling and noise on ``sample_seed``)."""
    lay = np.random.default_rng(seed)
    rng = np.random.default_rng(seed if sample_seed is None else sample_seed + 1000)
    W, D = size
    parts = [_plane(rng, np.array([0, 0, 0.0]), np.array([W, 0, 0.0]), np.array([0, D, 0.0]), spacing * 1.5)]
    parts.append(
        _plane(rng, np.array([0, D, 0.0]), np.array([W * 0.6, 0, 0]), np.array([0, 0, 4.0]), spacing)
    )
    parts.append(
        _plane(rng, np.array([0, 0, 0.0]), np.array([0, D * 0.7, 0]), np.array([0, 0, 3.0]), spacing)
    )
    for _ in range(int(W * D / 40)):
        c = lay.random(3) * [W, D, 0]
        s = lay.uniform([0.5, 0.5, 0.5], [4.0, 3.0, 3.0])
        c[2] = s[2] / 2
        parts.append(_box(rng, c, s, spacing))
    for _ in range(int(W * D / 150)):
        p0 = lay.random(3) * [W, D, 0] + [0, 0, lay.uniform(0.5, 3.0)]
        ang = lay.uniform(0, np.pi)
        p1 = p0 + lay.uniform(3, 10) * np.array([np.cos(ang), np.sin(ang), 0])
        parts.append(_pipe(rng, p0, p1, lay.uniform(0.1, 0.4), spacing))
    pts = np.vstack(parts)
    return pts + rng.normal(scale=noise, size=pts.shape)


def pose(x: float, y: float, z: float, yaw: float, roll: float = 0.0, pitch: float = 0.0) -> np.ndarray:
    """T from a position (m) and z-y-x Euler angles (rad)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    T[:3, 3] = [x, y, z]
    return T


def visit(
    site: np.ndarray,
    center: tuple[float, float],
    radius: float,
    T_prior_current: np.ndarray,
    seed: int = 1,
    noise: float = 0.005,
) -> np.ndarray:
    """The part of the site within ``radius`` (xy) of ``center``, re-noised and expressed in the current
    map's frame (``T_prior_current`` maps current coordinates into the site's)."""
    rng = np.random.default_rng(seed)
    keep = np.linalg.norm(site[:, :2] - np.asarray(center), axis=1) < radius
    pts = site[keep]
    pts = pts[rng.random(len(pts)) < 0.7]
    pts = pts + rng.normal(scale=noise, size=pts.shape)
    Ti = np.linalg.inv(T_prior_current)
    return pts @ Ti[:3, :3].T + Ti[:3, 3]
