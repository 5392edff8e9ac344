"""Projector geometry and drawing: world segments -> projector frame -> frustum clip -> pixels -> image.

No display library here (OpenCV draws into a numpy image); the adapter shows the image.
"""

from __future__ import annotations

import cv2
import numpy as np
from weldcell.hal.readings import Intrinsics
from weldcell.sdk.geometry import invert, transform_points


def frustum_planes(k: Intrinsics, near: float) -> list[tuple[np.ndarray, float]]:
    """Half-spaces ``n . p >= d`` (projector frame, optical: z forward) bounding what the image can show."""
    Kinv = np.linalg.inv(k.K)
    uv = ((0, 0), (k.width, 0), (k.width, k.height), (0, k.height))
    corners = [Kinv @ np.array([u, v, 1.0]) for u, v in uv]
    planes = [(np.array([0.0, 0.0, 1.0]), near)]
    for a, b in zip(corners, corners[1:] + corners[:1], strict=True):
        n = np.cross(a, b)  # inward for the clockwise-in-image corner order (y down)
        planes.append((n / np.linalg.norm(n), 0.0))
    return planes


def clip_segments(seg: np.ndarray, planes: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """Clip segments (N, 2, 3) to the intersection of half-spaces; drops those entirely outside."""
    a, b = seg[:, 0].copy(), seg[:, 1].copy()
    t0, t1 = np.zeros(len(seg)), np.ones(len(seg))
    for n, d in planes:
        fa, fb = a @ n - d, b @ n - d
        den = fa - fb
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(den != 0, fa / den, 0.0)
        enter = (fa < 0) & (fb >= 0)
        leave = (fa >= 0) & (fb < 0)
        t0 = np.where(enter, np.maximum(t0, t), t0)
        t1 = np.where(leave, np.minimum(t1, t), t1)
        t1 = np.where((fa < 0) & (fb < 0), -1.0, t1)
    keep = t1 > t0
    d = b - a
    return np.stack([a + t0[:, None] * d, a + t1[:, None] * d], axis=1)[keep]


def project_segments(
    segments_world: np.ndarray, T_world_projector: np.ndarray, k: Intrinsics, near: float
) -> list[np.ndarray]:
    """Polylines (each (M, 2) pixels) of world segments (N, 2, 3) as the projector must draw them.

    With distortion, each clipped segment is sampled so the drawn curve lands on the straight world line.
    """
    P = transform_points(invert(T_world_projector), segments_world.reshape(-1, 3)).reshape(-1, 2, 3)
    P = clip_segments(P, frustum_planes(k, near))
    if len(P) == 0:
        return []
    n = 32 if any(k.dist) else 2
    s = np.linspace(0.0, 1.0, n)
    pts = (P[:, :1] + s[None, :, None] * (P[:, 1:2] - P[:, :1])).reshape(-1, 3)
    dist = np.asarray(k.dist, dtype=float) if any(k.dist) else None
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), k.K, dist)
    return list(uv.reshape(len(P), n, 2))


def draw(polylines: list[np.ndarray], k: Intrinsics, color: tuple[int, int, int], width: int) -> np.ndarray:
    """An RGB image (H, W, 3) uint8: anti-aliased lines on black (sub-pixel positions kept)."""
    img = np.zeros((k.height, k.width, 3), np.uint8)
    shift = 4
    pl = [np.round(p * (1 << shift)).astype(np.int32) for p in polylines]
    if pl:
        cv2.polylines(img, pl, False, tuple(int(c) for c in color), int(width), cv2.LINE_AA, shift)
    return img
