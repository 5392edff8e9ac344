"""Colour + depth rendering for the simulated RGB-D camera (ZED 2i and others).

:class:`RgbdCamera` is a :class:`~weldcell.hal.sim.camera_model.RaycastCamera` (same depth, noise and
dropout model) that also shades a colour image from the same ray cast: every surface gets a base
colour (per mesh, seeded) modulated by a procedural 3-D texture evaluated at the world hit point
(value noise at 0.1 m, random-valued cells of 0.4 m and sparse dark marks — rust, chalk, bolts),
so ORB sees stable features that stick to the surfaces as the camera moves; Lambert shading from a
fixed sun direction and 2-level sensor noise. Rays that hit nothing see a featureless sky.
The colour image is registered to the depth image (the ZED SDK's left-image-aligned depth).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
from weldcell.hal.sim.camera_model import DepthImage, RaycastCamera

SKY = np.array([185.0, 205.0, 230.0])
SUN = np.array([0.35, 0.25, 0.9]) / np.linalg.norm([0.35, 0.25, 0.9])


def _hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, salt: int) -> np.ndarray:
    """Deterministic pseudo-random values in [0, 1) for integer lattice points."""
    h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791) ^ (salt * 2654435761)
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF).astype(np.float32) / 65536.0


def value_noise(p: np.ndarray, scale: float, salt: int = 0) -> np.ndarray:
    """Smooth 3-D value noise in [0, 1) at points ``p`` (N, 3), lattice spacing ``scale`` metres."""
    q = p / scale
    i = np.floor(q).astype(np.int64)
    f = (q - i).astype(np.float32)
    f = f * f * (3 - 2 * f)
    out = np.zeros(len(p), np.float32)
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1 - f[:, 0]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1 - f[:, 1]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1 - f[:, 2]
                out += wx * wy * wz * _hash(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, salt)
    return out


def cell_noise(p: np.ndarray, scale: float, salt: int = 0) -> np.ndarray:
    """Piecewise-constant 3-D noise in [0, 1): one random value per cube of side ``scale`` metres
    (sharp edges between cells: corners for ORB, at a fraction of value noise's cost)."""
    i = np.floor(p / scale).astype(np.int64)
    return _hash(i[:, 0], i[:, 1], i[:, 2], salt)


def surface_texture(p: np.ndarray) -> np.ndarray:
    """Brightness factor (N,) in about [0.3, 1.3] of the procedural texture at world points ``p``:
    smooth value noise at 0.1 m (blobs whose shape ORB re-finds from any view), cells of 0.4 m (large
    patches) and dark marks (cells of 0.15 m)."""
    t = 0.45 + 0.85 * (0.65 * value_noise(p, 0.1, 1) + 0.35 * cell_noise(p, 0.4, 2))
    return np.where(cell_noise(p, 0.15, 4) > 0.85, t * 0.35, t)


class RgbdCamera(RaycastCamera):
    """A ray-cast RGB-D camera: :meth:`render_rgbd` returns the depth image and a colour image."""

    def __init__(self, *args, color_seed: int = 0, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.color_seed = color_seed
        self._last: tuple | None = None

    def _cast(self, T: np.ndarray):
        d = self._dirs_cam @ np.ascontiguousarray(T[:3, :3].T, dtype=np.float32)
        if not self._items:
            self._last = None
            return super()._cast(T)
        rays = np.empty((len(d), 6), dtype=np.float32)
        rays[:, :3] = T[:3, 3].astype(np.float32)
        rays[:, 3:] = d
        ans = self.scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
        z = ans["t_hit"].numpy()
        n = ans["primitive_normals"].numpy()
        dn = np.einsum("ij,ij->i", n, d) / self._dir_norm
        n *= np.where(dn > 0, -1.0, 1.0).astype(np.float32)[:, None]
        cos = np.abs(dn)
        cos[~np.isfinite(z)] = 0.0
        self._last = (ans["geometry_ids"].numpy(), z, n, d, T[:3, 3].astype(np.float32))
        return z, cos, n, d

    def palette(self) -> np.ndarray:
        """Base colour (RGB 0-255) per mesh handle, in the order the meshes were added."""
        rng = np.random.default_rng(self.color_seed)
        n = max(self._next, 1)
        hues = rng.uniform(0, 1, n)
        sat = rng.uniform(0.15, 0.6, n)
        val = rng.uniform(120, 235, n)
        import colorsys

        return np.array(
            [np.array(colorsys.hsv_to_rgb(h, s, 1.0)) * v for h, s, v in zip(hues, sat, val, strict=False)]
        )

    def render_rgbd(
        self, T_world_camera: np.ndarray, rng=None, *, noise: bool | None = None, timestamp: float = 0.0
    ) -> tuple[DepthImage, np.ndarray]:
        """Depth image (with the preset's noise) and a registered RGB uint8 colour image (H, W, 3)."""
        depth = self.render(T_world_camera, rng, noise=noise, timestamp=timestamp)
        p = self.preset
        rgb = np.tile(SKY.astype(np.float32), (p.height * p.width, 1))
        if self._last is not None:
            gid, z, n, d, o = self._last
            hit = np.isfinite(z)
            handles = np.array(list(self._items), dtype=np.int64)
            pal = self.palette()
            base = pal[handles[np.clip(gid[hit], 0, len(handles) - 1)]]
            P = o + d[hit] * z[hit, None]
            shade = 0.55 + 0.45 * np.abs(n[hit] @ SUN.astype(np.float32))
            rgb[hit] = base * (surface_texture(P) * shade)[:, None]
        g = np.random.default_rng(rng)
        rgb += 2.0 * g.standard_normal(rgb.shape, dtype=np.float32)
        img = np.clip(rgb, 0, 255).astype(np.uint8).reshape(p.height, p.width, 3)
        return depth, img
