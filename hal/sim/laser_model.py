"""A laser-triangulation displacement sensor (Micro-Epsilon optoNCDT 1402 class) ray-cast on the scene.

What the model reproduces, per reading (vectorised over N readings at once):

* **measuring range**: a distance outside ``[min_range, max_range]`` (start of measuring range to end
  of measuring range) is *no reading* (NaN), never a zero;
* **accuracy**: Gaussian distance noise of ``accuracy`` (1 sigma) on a flat, matte surface -- the
  paper's 0.288 mm for the ILD 1402 (§II);
* **spot size**: the beam is a disc of ``spot_diameter``; the reading is the mean distance over the
  lit footprint (7 rays: centre + a hexagon on the spot's rim). Where the spot straddles an edge the
  reading is a *mixed* value between the top and the bottom ("shearing": the true edge is unreadable);
* **edge dropouts**: a spot whose footprint spans a step larger than ``edge_step`` is returned as no
  reading with probability ``edge_dropout`` (the receiver sees two spots and rejects the peak);
* **triangulation shadow**: the receiving lens sits ``baseline`` from the emitter along the sensor's x
  axis; a lit point the receiver cannot see (hidden behind a member's edge) is no reading;
* **robot-sensor coupling** (§II: any point observed through the robot-sensor chain lies within 0.4 mm):
  :class:`CouplingError` -- a smooth (robot path-accuracy-like) offset of the sensor's true pose from the
  pose the robot reports, bounded by ``coupling`` in norm. The device applies it only when the sensor is
  carried by a robot.

Presets follow the ILD 1402 data sheet (measuring ranges, spot sizes, 1.5 kHz) and the paper's accuracy.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from weldcell.sdk.errors import DataError


@dataclass(frozen=True)
class LaserSpec:
    """Characteristics of one sensor model (SI units)."""

    name: str
    min_range: float
    max_range: float
    accuracy: float
    spot_diameter: float
    rate: float
    baseline: float
    coupling: float = 0.4e-3
    edge_step: float = 1.0e-3
    edge_dropout: float = 0.5

    def with_overrides(self, **kw) -> LaserSpec:
        """A copy with the given fields replaced (``None`` values are ignored)."""
        return replace(self, **{k: v for k, v in kw.items() if v is not None})


#: ILD 1402-xx: start of measuring range (SMR) and SMR + measuring range (MR); spot at mid range;
#: the triangulation baseline puts the receiver at ~20 deg from the beam at mid range.
PRESETS: dict[str, LaserSpec] = {
    "ild1402-100": LaserSpec("ild1402-100", 0.050, 0.150, 0.288e-3, 1.0e-3, 1500.0, 0.036),
    "ild1402-200": LaserSpec("ild1402-200", 0.060, 0.260, 0.288e-3, 1.3e-3, 1500.0, 0.058),
    "ild1402-600": LaserSpec("ild1402-600", 0.200, 0.800, 0.288e-3, 1.6e-3, 1500.0, 0.180),
}


def preset(name: str) -> LaserSpec:
    """The spec of a sensor model by name; a clear error listing the known ones."""
    if name not in PRESETS:
        raise DataError(f"unknown laser sensor model '{name}'", f"use one of {', '.join(PRESETS)}")
    return PRESETS[name]


class CouplingError:
    """The robot-sensor chain's position error: a smooth 3-D offset bounded by ``amplitude`` (m).

    A sum of four sinusoids per axis at 0.2-4 Hz with random phases (robot path errors are low-frequency),
    scaled so the RMS norm is half the bound, then clipped to the bound.
    """

    def __init__(self, amplitude: float, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        self.amplitude = float(amplitude)
        self.freq = rng.uniform(0.2, 4.0, size=(4, 3))
        self.phase = rng.uniform(0.0, 2 * np.pi, size=(4, 3))
        # each sinusoid has RMS 1/sqrt(2): 4 per axis, 3 axes -> RMS norm sqrt(6); scale to amplitude / 2
        self.scale = 0.5 * self.amplitude / np.sqrt(6.0)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Offsets (N, 3) at times ``t`` (N,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if self.amplitude <= 0:
            return np.zeros((len(t), 3))
        e = self.scale * np.sin(2 * np.pi * self.freq[None] * t[:, None, None] + self.phase[None]).sum(axis=1)
        n = np.linalg.norm(e, axis=1, keepdims=True)
        return e * np.minimum(1.0, self.amplitude / np.maximum(n, 1e-15))


class LaserModel:
    """Ray-casts readings of a :class:`LaserSpec` sensor against a list of Open3D triangle meshes."""

    def __init__(self, spec: LaserSpec, meshes: list, seed: int = 0) -> None:
        import open3d as o3d

        self.spec = spec
        self.seed = int(seed)
        self._count = 0
        self.scene = o3d.t.geometry.RaycastingScene()
        for m in meshes:
            self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
        r = 0.5 * spec.spot_diameter
        ang = np.arange(6) * np.pi / 3
        self.spot = np.vstack([[0.0, 0.0], np.column_stack([r * np.cos(ang), r * np.sin(ang)])])  # (7, 2)

    def _cast(self, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        import open3d as o3d

        rays = np.concatenate([origins, dirs], axis=1).astype(np.float32)
        return self.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(float)

    def _draws(self, index: np.ndarray, stream: int, normal: bool) -> np.ndarray:
        """Random numbers tied to the sample index (the same sample gets the same draw however the
        samples are split into bursts): blocks of 1024 from generators seeded (seed, stream, block)."""
        out = np.empty(len(index))
        for b in np.unique(index // 1024):
            g = np.random.default_rng([self.seed, stream, int(b)])
            block = g.standard_normal(1024) if normal else g.random(1024)
            sel = index // 1024 == b
            out[sel] = block[index[sel] % 1024]
        return out

    def measure(self, T_world_sensor: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
        """Distances (N,) along the sensor's z axis for sensor poses (N, 4, 4); NaN = no reading.

        ``index`` (N,) numbers the samples (stream sample counter) so noise is reproducible; default:
        consecutive numbers continuing the previous call.
        """
        T = np.asarray(T_world_sensor, dtype=float).reshape(-1, 4, 4)
        n, s = len(T), self.spec
        if n == 0:
            return np.zeros(0)
        if index is None:
            index = self._count + np.arange(n)
            self._count += n
        index = np.asarray(index, dtype=np.int64)
        o, x, y, z = T[:, :3, 3], T[:, :3, 0], T[:, :3, 1], T[:, :3, 2]
        k = len(self.spot)
        origins = o[:, None] + self.spot[None, :, :1] * x[:, None] + self.spot[None, :, 1:] * y[:, None]
        t_hit = self._cast(origins.reshape(-1, 3), np.repeat(z, k, axis=0)).reshape(n, k)
        valid = np.isfinite(t_hit)
        lit = valid.sum(axis=1)
        d = np.where(lit > 0, np.where(valid, t_hit, 0.0).sum(axis=1) / np.maximum(lit, 1), np.nan)
        spread = np.where(
            lit > 1,
            np.nanmax(np.where(valid, t_hit, np.nan), axis=1)
            - np.nanmin(np.where(valid, t_hit, np.nan), axis=1),
            0.0,
        )
        partial = (lit < k) & (lit > 0)
        edge = (spread > s.edge_step) | partial
        drop = edge & (self._draws(index, 1, False) < s.edge_dropout)
        d = np.where(drop, np.nan, d)
        d = np.where(self._shadowed(o, x, z, t_hit[:, 0]), np.nan, d)
        d = d + s.accuracy * self._draws(index, 2, True)
        return np.where((d >= s.min_range) & (d <= s.max_range), d, np.nan)

    def _shadowed(self, o: np.ndarray, x: np.ndarray, z: np.ndarray, t_centre: np.ndarray) -> np.ndarray:
        """True where the receiver (``baseline`` along +x from the emitter) cannot see the lit point."""
        ok = np.isfinite(t_centre)
        out = np.zeros(len(o), dtype=bool)
        if not ok.any():
            return out
        p = o[ok] + t_centre[ok, None] * z[ok]
        receiver = o[ok] + self.spec.baseline * x[ok]
        v = receiver - p
        dist = np.linalg.norm(v, axis=1)
        v = v / dist[:, None]
        t = self._cast(p + 2e-4 * v, v)
        out[ok] = np.isfinite(t) & (t < dist - 1e-3)
        return out
