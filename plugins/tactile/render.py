"""Rendered in-finger camera frames of the SRM's ArUco tag.

The simulated tactile tool produces real images that go through the same detector and PnP as a real
camera's frames: the tag bitmap from ``cv2.aruco.generateImageMarker`` (with its white quiet zone) is
mapped into a pinhole camera by the plane-induced homography ``H = K [r1 r2 t] A`` (A: bitmap pixels →
tag-plane metres), rendered at ``supersample``× resolution and box-filtered down (anti-aliased edges),
optionally through the camera's lens distortion, then blurred and given sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from weldcell.sdk.errors import UsageError

from .marker import CameraIntrinsics, cv2_module, marker_object_points

#: Tag rest pose convention: tag x = camera x, tag y = -camera y (up in the image), tag z toward the camera.
R_CAM_TAG_FACING = np.diag([1.0, -1.0, -1.0])


@lru_cache(maxsize=16)
def _marker_bitmap(dictionary: str, marker_id: int, side_px: int, margin_px: int) -> np.ndarray:
    cv2 = cv2_module()
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    if not 0 <= marker_id < d.bytesList.shape[0]:
        raise UsageError(
            f"marker id {marker_id} is not in {dictionary}", f"use an id below {d.bytesList.shape[0]}"
        )
    img = cv2.aruco.generateImageMarker(d, marker_id, side_px, borderBits=1)
    return np.pad(img, margin_px, constant_values=255)


@lru_cache(maxsize=8)
def _undistorted_rays(K_key: tuple, dist_key: tuple, width: int, height: int, ss: int) -> np.ndarray:
    """Normalised pinhole coordinates (H*ss, W*ss, 2) seen by each super-sampled pixel (distorted camera)."""
    cv2 = cv2_module()
    K = np.array(K_key).reshape(3, 3)
    u = (np.arange(width * ss) - (ss - 1) / 2.0) / ss
    v = (np.arange(height * ss) - (ss - 1) / 2.0) / ss
    uu, vv = np.meshgrid(u, v)
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-9)
    dist = np.array(dist_key)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x spells the iterative variant this way
        und = cv2.undistortPointsIter(pts, K, dist, None, None, crit)
    else:  # OpenCV 5: criteria is an argument of undistortPoints
        und = cv2.undistortPoints(pts, K, dist, None, None, None, crit)
    return und.reshape(height * ss, width * ss, 2).astype(np.float32)


def project_tag_corners(
    T_cam_tag: np.ndarray, intrinsics: CameraIntrinsics, marker_size: float
) -> np.ndarray:
    """Exact image positions (4, 2) of the tag's corners (ground truth for detection tests)."""
    cv2 = cv2_module()
    R, t = T_cam_tag[:3, :3], T_cam_tag[:3, 3]
    img, _ = cv2.projectPoints(
        marker_object_points(marker_size), cv2.Rodrigues(R)[0], t, intrinsics.K, intrinsics.dist
    )
    return img.reshape(4, 2)


# parameters: the pose, camera and tag of one rendered frame, each a keyword with a default
def render_tag_image(
    T_cam_tag: np.ndarray,
    intrinsics: CameraIntrinsics,
    marker_size: float = 0.010,
    dictionary: str = "DICT_4X4_50",
    marker_id: int = 0,
    *,
    blur_sigma: float = 0.7,
    noise_std: float = 2.0,
    supersample: int = 2,
    background: float = 85.0,
    black: float = 25.0,
    white: float = 215.0,
    margin: float = 0.3,
    rng: np.random.Generator | int = 0,
) -> np.ndarray:
    """Grey uint8 image (H, W) of the tag at pose ``T_cam_tag`` seen by the in-finger camera.

    ``margin`` is the white quiet zone around the black square as a fraction of its side. Pixels off the
    tag show a background with a soft vignette (the inside of the finger). ``rng``: the pixel noise's
    generator or seed (the same seed gives the same image).
    """
    cv2 = cv2_module()
    T = np.asarray(T_cam_tag, dtype=float)
    if T.shape != (4, 4) or T[2, 3] <= 0:
        raise UsageError(
            "render: T_cam_tag must be a 4x4 pose with the tag in front of the camera (z > 0)",
            "place the tag at positive depth in the camera frame",
        )
    ss = int(supersample)
    if ss < 1:
        raise UsageError("render: supersample must be >= 1", "use 1 (fast) to 4 (smooth)")
    w, h = intrinsics.width, intrinsics.height
    bitmap, Hn = _tag_bitmap(T, marker_size, dictionary, marker_id, margin)
    bitmap = black + (white - black) * bitmap / 255.0
    big = _warp_supersampled(bitmap, Hn, intrinsics, ss)
    bg = _background(h * ss, w * ss, background)
    big = np.where(big < 0, bg, big)
    img = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA) if ss > 1 else big
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    if noise_std > 0:
        rng = np.random.default_rng(rng)
        img = img + rng.normal(0.0, noise_std, img.shape).astype(np.float32)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _tag_bitmap(
    T: np.ndarray, marker_size: float, dictionary: str, marker_id: int, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """The tag bitmap with its quiet zone (float32, 0-255) and the homography ``[r1 r2 t] A`` from its
    pixels to normalised camera coordinates."""
    side_px = 240
    margin_px = int(round(margin * side_px))
    bitmap = _marker_bitmap(dictionary, int(marker_id), side_px, margin_px).astype(np.float32)
    S = bitmap.shape[0]
    W = marker_size * S / side_px  # metres spanned by the padded bitmap
    A = np.array([[W / S, 0.0, 0.5 * W / S - W / 2], [0.0, -W / S, W / 2 - 0.5 * W / S], [0.0, 0.0, 1.0]])
    return bitmap, np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]) @ A


def _warp_supersampled(
    bitmap: np.ndarray, Hn: np.ndarray, intrinsics: CameraIntrinsics, ss: int
) -> np.ndarray:
    """The bitmap seen at ``ss``× resolution (-1 off the tag): one perspective warp for a pinhole camera,
    else a per-pixel remap through the lens distortion."""
    cv2 = cv2_module()
    w, h = intrinsics.width, intrinsics.height
    if not np.any(intrinsics.dist):
        K = intrinsics.K
        Kss = np.array(
            [
                [ss * K[0, 0], ss * K[0, 1], ss * K[0, 2] + (ss - 1) / 2.0],
                [0.0, ss * K[1, 1], ss * K[1, 2] + (ss - 1) / 2.0],
                [0.0, 0.0, 1.0],
            ]
        )
        return cv2.warpPerspective(
            bitmap,
            Kss @ Hn,
            (w * ss, h * ss),
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=-1.0,
        )
    rays = _undistorted_rays(tuple(intrinsics.K.ravel()), tuple(intrinsics.dist.ravel()), w, h, ss)
    Hi = np.linalg.inv(Hn)
    x, y = rays[..., 0], rays[..., 1]
    den = Hi[2, 0] * x + Hi[2, 1] * y + Hi[2, 2]
    mx = ((Hi[0, 0] * x + Hi[0, 1] * y + Hi[0, 2]) / den).astype(np.float32)
    my = ((Hi[1, 0] * x + Hi[1, 1] * y + Hi[1, 2]) / den).astype(np.float32)
    mx[den <= 0] = -10.0
    return cv2.remap(bitmap, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)


@lru_cache(maxsize=8)
def _background_cached(h: int, w: int, level: float) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (h / 2)) ** 2
    return (level * (1.0 - 0.35 * r2 / 2.0)).astype(np.float32)


def _background(h: int, w: int, level: float) -> np.ndarray:
    return _background_cached(h, w, float(level))


@dataclass
class InFingerCamera:
    """The SRM's camera + tag as one simulated device: tag pose in, rendered frame out.

    ``T_cam_tag_rest`` defaults to the tag facing the camera ``tag_distance`` ahead on the optical axis.
    """

    intrinsics: CameraIntrinsics = field(default_factory=CameraIntrinsics.default_in_finger)
    marker_size: float = 0.010
    marker_id: int = 0
    dictionary: str = "DICT_4X4_50"
    tag_distance: float = 0.025
    blur_sigma: float = 0.7
    noise_std: float = 2.0
    supersample: int = 2
    seed: int = 0
    T_cam_tag_rest: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.T_cam_tag_rest is None:
            T = np.eye(4)
            T[:3, :3] = R_CAM_TAG_FACING
            T[2, 3] = self.tag_distance
            self.T_cam_tag_rest = T
        self._rng = np.random.default_rng(self.seed)

    def render(self, T_cam_tag: np.ndarray) -> np.ndarray:
        """One frame with the tag at ``T_cam_tag``."""
        return render_tag_image(
            T_cam_tag,
            self.intrinsics,
            self.marker_size,
            self.dictionary,
            self.marker_id,
            blur_sigma=self.blur_sigma,
            noise_std=self.noise_std,
            supersample=self.supersample,
            rng=self._rng,
        )
