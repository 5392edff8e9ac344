"""Measuring a fixed-size steel plate in the map (the paper's AE, §III-B): its four top corners from the
depth pixels of the key frames that saw it.

The measurement (:func:`plate_corners_ml`) fits the plate's box to the key frames' depth images by
analysis by synthesis (:mod:`~weldcell.plugins.mapping.plate_fit`: the box rendered into every key frame,
depth and silhouette compared pixel by pixel). It starts from a measurement on the points alone
(:func:`plate_corners_points`): a plate on a work stand is seen from a camera only a little above it, its
top face at grazing incidence (80-89°); a stereo depth error is along the viewing ray, there nearly
horizontal and up to ten times the head-on error (σ_z / cos θ), so every pixel keeps its ray and its
noise (the camera's model: σ_z = ``depth_noise``·z², grown by 1/cos θ, θ from the depth image's normals,
snapped to the vertical within 45° of it; across the ray 0.1 px), and along each axis of the plate the
extent [a, b] is the maximum-likelihood interval of points spread uniformly on [a, b], each seen with its
own Gaussian noise; the yaw the one of highest likelihood within ±12° of the minimum-area rectangle of
the precise half. That uniform spread does not hold at 1-7° above the top face (the side faces crowd
the near edge, the far part thins out): on its own it slides the plate towards the camera by 2-14 cm at
VGA, which the box fit removes. Measured effect: docs/methods/mapping.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.ndimage import maximum_filter1d
from scipy.optimize import minimize
from scipy.special import ndtr
from weldcell.plugins.mapping.plate_fit import (
    K_SIGMA,
    BoxFit,
    PlateView,
    crop_view,
    fit_box,
    params_from_corners,
)


@dataclass
class PlateObservations:
    """Depth pixels of a region in the world frame: points (N, 3), unit viewing rays (N, 3), the depth
    noise along each ray ``sigma_ray`` (N,) and the error across it ``sigma_lat`` (N,), metres; and per
    key frame the depth image around the region with its pose (``views``: what the box fit renders into)."""

    points: np.ndarray
    rays: np.ndarray
    sigma_ray: np.ndarray
    sigma_lat: np.ndarray
    views: list[PlateView] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.points)


LATERAL_PX = 0.1
"""Error of a pixel's point across its ray (px): the ray is the pixel centre's, exact up to calibration."""
MIN_COS = 0.1
"""Incidence cosine below which the noise stops growing (the camera model's ``min_cos``)."""
MIN_LAYER = 20
"""Points the plate's top layer needs for the measurement."""


def frame_observations(
    depth, K, T_world_cam, box_min, box_max, depth_noise: float, keyframe: int = -1, pose_cov=None
) -> PlateObservations:
    """The pixels of one key frame whose points fall in the box, with their rays and noise; ``keyframe``
    (its index) and ``pose_cov`` (its pose error as a world-frame correction, 6x6:
    :func:`~.plate_poses.camera_pose_cov`) go with its view to the box fit's pose correction."""
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
    view = crop_view(depth, K, T_world_cam, box_min, box_max, depth_noise, keyframe, pose_cov)
    return PlateObservations(P[inb], ray_c[inb] @ R.T, sig[inb], lat[inb], [view] if view is not None else [])


def merge(obs: list[PlateObservations]) -> PlateObservations:
    """The observations of several key frames as one set (an empty set for none)."""
    if not obs:
        return PlateObservations(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    arrays = (
        np.concatenate([getattr(o, f) for o in obs]) for f in ("points", "rays", "sigma_ray", "sigma_lat")
    )
    return PlateObservations(*arrays, [v for o in obs for v in o.views])


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
    """Height of the highest horizontal layer (the plate's top; side faces included), weighted by each
    point's vertical precision. A layer is a surface where the points within ``band`` of a height peak
    (the most within a band either side) and outnumber those a band above by K_SIGMA Poisson standard
    deviations, with at least MIN_LAYER points: the highest such peak, not the most populated (the region's
    crop may reach the ground or a stand below the plate, with many times the plate's pixels; a rule
    relative to the largest layer then measures the ground: issue 11, plate 1 of seed 0)."""
    step = 0.005
    e = np.arange(z.min() - 2 * band, z.max() + 2 * band + step, step)
    h = np.histogram(z, bins=e)[0].astype(float)
    nb = max(int(round(band / step)), 1)
    s = np.convolve(h, np.ones(2 * nb + 1), mode="same")  # points within a band of each bin
    peak = s >= maximum_filter1d(s, 2 * nb + 1, mode="constant")  # s >= 0: the edges see no more
    above = np.r_[s[2 * nb :], np.zeros(2 * nb)]
    surface = peak & (s >= MIN_LAYER) & (s - above > K_SIGMA * np.sqrt(np.maximum(s, 1.0)))
    k = np.flatnonzero(surface)[-1] if surface.any() else int(np.argmax(s))
    m = np.abs(z - (e[k] + e[k + 1]) / 2) < np.maximum(band, 2 * sv)
    w = 1 / np.maximum(sv[m], 1e-4) ** 2
    return float(np.sum(w * z[m]) / np.sum(w))


def plate_fit(
    obs: PlateObservations,
    top_band: float = 0.015,
    yaw_scan: float = np.radians(12),
    pose_correction: bool = True,
) -> BoxFit | None:
    """The plate's box fitted to the key frames' depth images (:func:`~.plate_fit.fit_box`), started from
    the points' measurement (:func:`plate_corners_points`) and its labels grown by the median horizontal
    smear of the points; None without enough points. ``ok`` False (with the reason) when the box is not
    determined by the views: the caller reports it, it does not guess. ``pose_correction``: a rigid
    correction per pass of the route fitted with the box, where the views carry their pose covariance."""
    c0 = plate_corners_points(obs, top_band, yaw_scan)
    if c0 is None:
        return None
    smear = float(np.median(obs.sigma_ray * np.linalg.norm(obs.rays[:, :2], axis=1)))
    region = (obs.points[:, :2].min(0), obs.points[:, :2].max(0))
    p0 = params_from_corners(c0, 0.0)
    return fit_box(obs.views, p0, smear, region=region, pose_correction=pose_correction)


def plate_corners_ml(
    obs: PlateObservations, top_band: float = 0.015, yaw_scan: float = np.radians(12)
) -> np.ndarray | None:
    """(4, 3) top corners of a plate lying flat (world z up, gravity-aligned) from the box fitted to the
    key frames' depth (:func:`plate_fit`); None when the plate is not measured (too few points, one key
    frame, an axis seen only along the line of sight)."""
    fit = plate_fit(obs, top_band, yaw_scan)
    return fit.corners if fit is not None and fit.ok else None


def plate_corners_points(
    obs: PlateObservations, top_band: float = 0.015, yaw_scan: float = np.radians(12)
) -> np.ndarray | None:
    """(4, 3) top corners from the points alone (each axis the maximum-likelihood interval of points
    spread uniformly over it; the box fit's start), or None with too few points."""
    if len(obs) < 30:
        return None
    P, r, sr, sl = obs.points, obs.rays, obs.sigma_ray, obs.sigma_lat
    sv = np.sqrt((sr * r[:, 2]) ** 2 + sl**2)
    ztop = _top_height(P[:, 2], sv, top_band)
    layer = np.abs(P[:, 2] - ztop) < np.maximum(top_band, 2 * sv)
    if layer.sum() < MIN_LAYER:
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
