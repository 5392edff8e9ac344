"""Measuring a fixed-size steel plate in the map (the paper's AE, §III-B): its four top corners from the
depth pixels of the key frames that saw it, with each pixel's own noise.

Why not a rectangle around the region's points: a plate on a work stand is seen from a camera only a
little above it, so its top face is seen at grazing incidence (80-86° at 1.7-2.5 m from a camera 0.2 m
above the plate). A stereo depth error is along the viewing ray, there nearly horizontal and ten times
the head-on error (σ_z / cos θ): the top face's points smear 5-10 cm across the plate's far edge, and a
percentile box around them is as wrong. The side faces, seen head-on, are precise to σ_z. So every
pixel keeps its ray and its noise (the camera's model: σ_z = ``depth_noise``·z², grown by 1/cos θ, θ from
the depth image's normals, snapped to the vertical within 45° of it; across the ray 0.1 px), and along
each axis of the plate the
extent [a, b] is the maximum-likelihood interval of points spread uniformly on [a, b], each seen with its
own Gaussian noise along that axis: precise points fix an edge, noisy points only weakly. The plate's
yaw is the one of highest likelihood within ±12° of the minimum-area rectangle of the precise half.
Measured effect and weak points (uniform-spread assumption, few distant views): docs/methods/mapping.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr


@dataclass
class PlateObservations:
    """Depth pixels of a region in the world frame: points (N, 3), unit viewing rays (N, 3), the depth
    noise along each ray ``sigma_ray`` (N,) and the error across it ``sigma_lat`` (N,), metres."""

    points: np.ndarray
    rays: np.ndarray
    sigma_ray: np.ndarray
    sigma_lat: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


LATERAL_PX = 0.1
"""Error of a pixel's point across its ray (px): the ray is the pixel centre's, exact up to calibration."""
MIN_COS = 0.1
"""Incidence cosine below which the noise stops growing (the camera model's ``min_cos``)."""


def frame_observations(depth, K, T_world_cam, box_min, box_max, depth_noise: float) -> PlateObservations:
    """The pixels of one key frame whose points fall in the box, with their rays and noise."""
    z = np.asarray(depth, float)
    H, W = z.shape
    v, u = np.mgrid[0:H, 0:W]
    # surface normals from the back-projection of the 5x5-smoothed depth (central differences)
    zs = cv2.blur(np.where(z > 0, z, 0.0), (5, 5))
    Xs = np.dstack([(u - K.cx) * zs / K.fx, (v - K.cy) * zs / K.fy, zs])
    du, dv = np.zeros_like(Xs), np.zeros_like(Xs)
    du[:, 1:-1] = Xs[:, 2:] - Xs[:, :-2]
    dv[1:-1] = Xs[2:] - Xs[:-2]
    n = np.cross(du, dv)
    n /= np.linalg.norm(n, axis=2, keepdims=True) + 1e-12
    ok = np.isfinite(z) & (z > 0)
    zz = z[ok]
    Pc = np.column_stack([(u[ok] - K.cx) * zz / K.fx, (v[ok] - K.cy) * zz / K.fy, zz])
    ray_c = Pc / np.linalg.norm(Pc, axis=1, keepdims=True)
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    # the plate lies flat: a pixel whose estimated normal is closer to the world's vertical than 45° is on
    # a horizontal face and takes the exact vertical (the image normals are noisy at grazing incidence)
    n_w = n[ok] @ R.T
    flat = np.abs(n_w[:, 2]) > np.sqrt(0.5)
    n_w[flat] = [0.0, 0.0, 1.0]
    cos = np.abs(np.sum(n_w * (ray_c @ R.T), axis=1))
    P = Pc @ R.T + t
    inb = np.all((P >= box_min) & (P <= box_max), axis=1)
    sig = depth_noise * zz**2 / np.maximum(cos, MIN_COS)
    lat = LATERAL_PX * zz / K.fx
    return PlateObservations(P[inb], ray_c[inb] @ R.T, sig[inb], lat[inb])


def merge(obs: list[PlateObservations]) -> PlateObservations:
    """The observations of several key frames as one set (an empty set for none)."""
    if not obs:
        return PlateObservations(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    return PlateObservations(
        *(np.concatenate([getattr(o, f) for o in obs]) for f in ("points", "rays", "sigma_ray", "sigma_lat"))
    )


def _interval_ml(x: np.ndarray, s: np.ndarray) -> tuple[float, float, float]:
    """Maximum-likelihood [a, b] for points uniform on [a, b] seen with Gaussian noise ``s`` (per point);
    returns a, b and the negative log-likelihood."""

    def nll(p):
        a, b = p[0], p[0] + np.exp(p[1])
        return -np.sum(np.log(np.maximum((ndtr((b - x) / s) - ndtr((a - x) / s)) / (b - a), 1e-300)))

    lo, hi = np.percentile(x, [1, 99])
    r = minimize(
        nll,
        [lo, np.log(max(hi - lo, 1e-3))],
        method="Nelder-Mead",
        options={"xatol": 1e-5, "fatol": 1e-6, "maxiter": 2000},
    )
    return float(r.x[0]), float(r.x[0] + np.exp(r.x[1])), float(r.fun)


def _top_height(z: np.ndarray, sv: np.ndarray, band: float) -> float:
    """Height of the highest well-populated horizontal layer (the plate's top; side faces included),
    weighted by each point's vertical precision."""
    h, e = np.histogram(z, bins=np.arange(z.min(), z.max() + 0.01, 0.005))
    k = np.flatnonzero(h >= 0.2 * h.max())[-1]
    m = np.abs(z - (e[k] + e[k + 1]) / 2) < np.maximum(band, 2 * sv)
    w = 1 / np.maximum(sv[m], 1e-4) ** 2
    return float(np.sum(w * z[m]) / np.sum(w))


def plate_corners_ml(
    obs: PlateObservations, top_band: float = 0.015, yaw_scan: float = np.radians(12)
) -> np.ndarray | None:
    """(4, 3) top corners of a plate lying flat (world z up, gravity-aligned), or None with too few
    points. See the module docstring."""
    if len(obs) < 30:
        return None
    P, r, sr, sl = obs.points, obs.rays, obs.sigma_ray, obs.sigma_lat
    sv = np.sqrt((sr * r[:, 2]) ** 2 + sl**2)
    ztop = _top_height(P[:, 2], sv, top_band)
    layer = np.abs(P[:, 2] - ztop) < np.maximum(top_band, 2 * sv)
    if layer.sum() < 20:
        return None
    L, r, sr, sl = P[layer, :2], r[layer, :2], sr[layer], sl[layer]
    sh = sr * np.linalg.norm(r, axis=1)
    precise = sh <= np.median(sh)
    (cx, cy), _, ang = cv2.minAreaRect(L[precise].astype(np.float32))

    def fit(a):
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        loc = (L - [cx, cy]) @ R
        fits = [_interval_ml(loc[:, k], np.sqrt((sr * (r @ R[:, k])) ** 2 + sl**2)) for k in range(2)]
        return fits[0][2] + fits[1][2], R, fits

    a0 = np.radians(ang)
    coarse = min(
        (fit(a) + (a,) for a in a0 + np.arange(-yaw_scan, yaw_scan + 1e-9, np.radians(2))), key=lambda b: b[0]
    )
    best = min((fit(a) for a in coarse[3] + np.radians(np.arange(-1.5, 1.6, 0.5))), key=lambda b: b[0])
    _, R, ((a0, b0, _), (a1, b1, _)) = best
    box = np.array([[a0, a1], [b0, a1], [b0, b1], [a0, b1]]) @ R.T + [cx, cy]
    return np.column_stack([box, np.full(4, ztop)])
