"""PhoXi point maps -> :class:`DepthFrame` (vendor-free, shared by the GenTL and the PLY replay modes).

A PhoXi delivers an *organised XYZ point map* (one 3-D point per sensor pixel, mm, (0, 0, 0) where there is
no measurement), not a depth image. The frame keeps it exactly: ``depth`` = Z in metres (0 = no data),
``meta["xyz"]`` = the (H, W, 3) points in metres, ``meta["normals"]`` / ``meta["texture"]`` when transferred.
:func:`exact_cloud` builds the cloud from ``meta["xyz"]`` (no back-projection error); ``DepthFrame.to_cloud``
back-projects ``depth`` through the intrinsics and agrees with it to the intrinsics' fit residual.
"""

from __future__ import annotations

import time

import numpy as np
from weldcell.hal.readings import DepthFrame, Intrinsics
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import DataError


def fit_intrinsics(xyz: np.ndarray) -> tuple[Intrinsics, float]:
    """Pinhole intrinsics of an organised (H, W, 3) point map by linear least squares.

    Each valid pixel (u, v) holds a point with ``u = fx X/Z + cx`` and ``v = fy Y/Z + cy``; the two 1-D fits
    are solved independently. Returns the intrinsics and the RMS pixel residual (0 for an ideal pinhole grid).
    """
    h, w = xyz.shape[:2]
    z = xyz[..., 2]
    valid = np.isfinite(z) & (z > 0)
    if valid.sum() < 3:
        raise DataError(
            "the point map has fewer than 3 valid points; cannot fit intrinsics",
            "check the scan (exposure, range) or give intrinsics in the settings",
        )
    v, u = np.nonzero(valid)
    a = xyz[v, u, 0] / z[v, u]
    b = xyz[v, u, 1] / z[v, u]
    if np.ptp(a) < 1e-9 or np.ptp(b) < 1e-9:
        raise DataError(
            "the point map spans a single row or column; cannot fit intrinsics",
            "give (fx, fy, cx, cy) in the settings",
        )
    (fx, cx), *_ = np.linalg.lstsq(np.column_stack([a, np.ones_like(a)]), u.astype(float), rcond=None)
    (fy, cy), *_ = np.linalg.lstsq(np.column_stack([b, np.ones_like(b)]), v.astype(float), rcond=None)
    res = np.sqrt(np.mean((fx * a + cx - u) ** 2 + (fy * b + cy - v) ** 2))
    return Intrinsics(width=w, height=h, fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy)), float(res)


def _front(points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1) & (p[:, 2] > 0)]
    if len(p) == 0:
        raise DataError(
            "the cloud has no point in front of the camera (z > 0)", "check the file's frame/units"
        )
    return p


def virtual_camera(clouds: list[np.ndarray]) -> Intrinsics:
    """A virtual pinhole for unorganised clouds: pixel pitch at the median depth = the first cloud's median
    nearest-neighbour spacing; principal point and size so that the image covers every cloud."""
    from scipy.spatial import cKDTree

    p0 = _front(clouds[0])
    d, _ = cKDTree(p0).query(p0, k=2)
    spacing = float(np.median(d[:, 1])) if len(p0) > 1 else 1e-3
    f = float(np.median(p0[:, 2])) / max(spacing, 1e-9)
    allp = np.concatenate([_front(c) for c in clouds])
    a, b = allp[:, 0] / allp[:, 2], allp[:, 1] / allp[:, 2]
    cx, cy = -f * a.min() + 0.5, -f * b.min() + 0.5
    return Intrinsics(
        width=int(np.ceil(f * a.max() + cx)) + 1,
        height=int(np.ceil(f * b.max() + cy)) + 1,
        fx=f,
        fy=f,
        cx=cx,
        cy=cy,
    )


def virtual_grid(
    points: np.ndarray,
    intrinsics: tuple[float, float, float, float] | Intrinsics | None = None,
) -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """Project an unorganised (N, 3) cloud (camera frame, z forward) into a z-buffered point map.

    Without given intrinsics a virtual pinhole is chosen whose pixel pitch at the median depth equals the
    median nearest-neighbour spacing of the points, and whose image just covers them; a full
    :class:`Intrinsics` is used as is (points outside its image are dropped). Returns the (H, W, 3)
    map (nearest point per pixel, zeros elsewhere), the (H, W) index of the point kept per pixel (-1 = none)
    and the intrinsics.
    """
    p = _front(points)
    if isinstance(intrinsics, Intrinsics):
        k = intrinsics
    elif intrinsics is None:
        k = virtual_camera([p])
    else:
        fx, fy, cx, cy = intrinsics
        u_all = fx * p[:, 0] / p[:, 2] + cx
        v_all = fy * p[:, 1] / p[:, 2] + cy
        k = Intrinsics(
            width=int(np.ceil(u_all.max())) + 1,
            height=int(np.ceil(v_all.max())) + 1,
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
        )
    u = np.rint(k.fx * p[:, 0] / p[:, 2] + k.cx).astype(np.int64)
    v = np.rint(k.fy * p[:, 1] / p[:, 2] + k.cy).astype(np.int64)
    inside = (u >= 0) & (v >= 0) & (u < k.width) & (v < k.height)
    idx = np.nonzero(inside)[0]
    pix = v[idx] * k.width + u[idx]
    order = np.lexsort((p[idx, 2], pix))  # by pixel, nearest first
    pix, idx = pix[order], idx[order]
    first = np.r_[True, pix[1:] != pix[:-1]][: len(pix)]
    owner = np.full(k.width * k.height, -1, dtype=np.int64)
    owner[pix[first]] = idx[first]
    grid = np.zeros((k.height * k.width, 3))
    grid[owner >= 0] = p[owner[owner >= 0]]
    return grid.reshape(k.height, k.width, 3), owner.reshape(k.height, k.width), k


def texture_to_rgb(texture: np.ndarray) -> np.ndarray:
    """A PhoXi texture (Mono10/12/16 or RGB8) as (H, W, 3) uint8, contrast-stretched like PhoXi Control."""
    t = np.asarray(texture)
    if t.ndim == 3 and t.shape[2] == 3 and t.dtype == np.uint8:
        return t
    g = t.astype(np.float64)
    if g.ndim == 3:
        g = g[..., 0]
    hi = np.percentile(g[g > 0], 99.5) if np.any(g > 0) else 1.0
    g8 = np.clip(g / max(hi, 1e-9) * 255.0, 0, 255).astype(np.uint8)
    return np.repeat(g8[..., None], 3, axis=2)


def point_map_frame(
    xyz_m: np.ndarray,
    intrinsics: Intrinsics,
    frame: str,
    *,
    stamp: float | None = None,
    normals: np.ndarray | None = None,
    texture: np.ndarray | None = None,
    meta: dict | None = None,
) -> DepthFrame:
    """A :class:`DepthFrame` from an organised (H, W, 3) point map in metres (invalid points all-zero/NaN)."""
    xyz = np.asarray(xyz_m, dtype=np.float64)
    if xyz.ndim != 3 or xyz.shape[2] != 3:
        raise DataError(
            f"a point map must be (H, W, 3), got {xyz.shape}", "reshape the Range data to rows x cols"
        )
    z = xyz[..., 2]
    valid = np.isfinite(xyz).all(axis=2) & (z > 0)
    depth = np.where(valid, z, 0.0).astype(np.float32)
    xyz = np.where(valid[..., None], xyz, 0.0)
    m = {"xyz": xyz, "valid": valid, "units": "m", "source": "phoxi"}
    if normals is not None:
        m["normals"] = np.asarray(normals, dtype=np.float64).reshape(xyz.shape)
    color = None
    if texture is not None:
        m["texture"] = np.asarray(texture)
        rgb = texture_to_rgb(texture)
        color = rgb if rgb.shape[:2] == depth.shape else None
    if meta:
        m.update(meta)
    return DepthFrame(
        stamp=time.time() if stamp is None else stamp,
        depth=depth,
        intrinsics=intrinsics,
        frame=frame,
        color=color,
        meta=m,
    )


def exact_cloud(frame: DepthFrame) -> PointCloud:
    """The frame's exact PhoXi points (from ``meta["xyz"]``), with normals when transferred."""
    xyz = frame.meta.get("xyz")
    if xyz is None:
        return frame.to_cloud()
    valid = frame.meta.get("valid", xyz[..., 2] > 0)
    normals = frame.meta.get("normals")
    n = None
    if normals is not None:
        n = normals[valid]
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.where(norm > 1e-12, n / np.maximum(norm, 1e-12), 0.0)
    colors = None
    if frame.color is not None:
        colors = frame.color[valid][:, :3] / 255.0
    return PointCloud(xyz[valid], normals=n, colors=colors, frame=frame.frame, meta={"stamp": frame.stamp})
