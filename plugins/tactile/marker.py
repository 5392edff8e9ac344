"""ArUco marker displacement in the SRM finger (paper 003 §2.2.1, eq. 15's δ).

The SRM finger carries an ArUco tag that an in-finger camera watches. Detection uses OpenCV's
``cv2.aruco.ArucoDetector`` (OpenCV ≥ 4.7 / 5), the pose of the tag comes from ``cv2.solvePnP`` with
``SOLVEPNP_IPPE_SQUARE`` on its four corners, and the displacement of the tag is its translation relative
to the rest pose captured without contact, expressed in the tool frame. A tag that is not found, has the
wrong id, or whose pose does not re-project onto its corners is reported as :class:`MarkerLost` — never as
a zero displacement, which the servo would read as "no contact" and drive into the wall.

``cv2`` is imported lazily, so the rest of weldcell works without the ``vision`` extra.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError, MissingExtraError, UsageError
from weldcell.sdk.geometry import make_T, orthonormalize

from .filters import OneEuroFilter, PassThrough


def cv2_module() -> Any:
    """Import OpenCV with ArUco support, or raise :class:`MissingExtraError`."""
    try:
        import cv2
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise MissingExtraError("tactile marker detection", "cv2", "vision") from exc
    if not hasattr(cv2, "aruco") or not hasattr(cv2.aruco, "ArucoDetector"):  # pragma: no cover
        raise MissingExtraError(
            "tactile marker detection (cv2.aruco.ArucoDetector, OpenCV >= 4.7)",
            "opencv-contrib-python-headless",
            "vision",
        )
    return cv2


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of the in-finger camera (pixels) and OpenCV distortion coefficients."""

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 640
    height: int = 480

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        dist = np.asarray(self.dist, dtype=float).ravel()
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise DataError(
                "camera intrinsics: K must be a finite 3x3 matrix with fx, fy > 0",
                "give K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels",
            )
        if dist.size not in (0, 4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
            raise DataError(
                f"camera intrinsics: {dist.size} distortion coefficients",
                "give 4, 5, 8, 12 or 14 OpenCV distortion coefficients (or none)",
            )
        if self.width <= 0 or self.height <= 0:
            raise DataError(
                "camera intrinsics: image size must be positive", "set width and height in pixels"
            )
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist if dist.size else np.zeros(5))

    @classmethod
    def default_in_finger(cls) -> CameraIntrinsics:
        """A small wide-ish in-finger camera: 640x480, f = 420 px, no distortion."""
        return cls(
            np.array([[420.0, 0.0, 320.0], [0.0, 420.0, 240.0], [0.0, 0.0, 1.0]]), np.zeros(5), 640, 480
        )

    @classmethod
    def from_opencv_yaml(cls, path: str | Path) -> CameraIntrinsics:
        """Read ``camera_matrix``, ``distortion_coefficients``, ``image_width/height`` from an OpenCV YAML."""
        cv2 = cv2_module()
        path = Path(path)
        if not path.is_file():
            raise DataError(f"camera file not found: {path}", "give the path of an OpenCV calibration YAML")
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        try:
            K = fs.getNode("camera_matrix").mat()
            dist = fs.getNode("distortion_coefficients").mat()
            w = fs.getNode("image_width").real()
            h = fs.getNode("image_height").real()
        finally:
            fs.release()
        if K is None:
            raise DataError(f"{path}: no 'camera_matrix' entry", "write the intrinsics with cv2.FileStorage")
        return cls(K, np.zeros(5) if dist is None else dist, int(w) or 640, int(h) or 480)


@dataclass(frozen=True)
class DetectedMarker:
    """One detected ArUco marker: id and its 4 corners (OpenCV order: TL, TR, BR, BL), pixels."""

    id: int
    corners: np.ndarray


_REFINE = {
    "none": "CORNER_REFINE_NONE",
    "subpix": "CORNER_REFINE_SUBPIX",
    "contour": "CORNER_REFINE_CONTOUR",
    "apriltag": "CORNER_REFINE_APRILTAG",
}


def _as_gray(image: np.ndarray) -> np.ndarray:
    cv2 = cv2_module()
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2 or img.size == 0:
        raise DataError(
            f"marker detection: expected a grey or BGR image, got shape {img.shape}",
            "pass the camera frame as an (H, W) or (H, W, 3) uint8 array",
        )
    if img.dtype != np.uint8:
        if not np.issubdtype(img.dtype, np.number):
            raise DataError(f"marker detection: image dtype {img.dtype} is not numeric", "pass a uint8 image")
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


class MarkerDetector:
    """ArUco detection with ``cv2.aruco.ArucoDetector``.

    ``corner_refinement='subpix'`` (default) gives the sub-pixel corners the displacement needs;
    ``'none'`` reproduces OpenCV's default detector (used to check against its tutorial test data).
    ``params`` overrides ``cv2.aruco.DetectorParameters`` attributes by name.
    """

    def __init__(
        self,
        dictionary: str = "DICT_4X4_50",
        corner_refinement: Literal["none", "subpix", "contour", "apriltag"] = "subpix",
        params: dict[str, float | int] | None = None,
    ) -> None:
        cv2 = cv2_module()
        if not hasattr(cv2.aruco, dictionary) or not dictionary.startswith("DICT_"):
            raise UsageError(
                f"unknown ArUco dictionary {dictionary!r}",
                "use a cv2.aruco name such as DICT_4X4_50 or DICT_6X6_250",
            )
        if corner_refinement not in _REFINE:
            raise UsageError(
                f"unknown corner refinement {corner_refinement!r}", f"use one of {list(_REFINE)}"
            )
        self.dictionary_name = dictionary
        self.dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
        p = cv2.aruco.DetectorParameters()
        p.cornerRefinementMethod = getattr(cv2.aruco, _REFINE[corner_refinement])
        if corner_refinement == "subpix":
            p.cornerRefinementWinSize = 5
            p.cornerRefinementMinAccuracy = 0.01
            p.cornerRefinementMaxIterations = 50
        for k, v in (params or {}).items():
            if not hasattr(p, k):
                raise UsageError(
                    f"unknown ArUco detector parameter {k!r}",
                    "see cv2.aruco.DetectorParameters for the valid names",
                )
            setattr(p, k, type(getattr(p, k))(v))
        self._detector = cv2.aruco.ArucoDetector(self.dictionary, p)

    def detect(self, image: np.ndarray) -> list[DetectedMarker]:
        """All markers of the dictionary in ``image``."""
        corners, ids, _ = self._detector.detectMarkers(_as_gray(image))
        if ids is None:
            return []
        return [
            DetectedMarker(int(i), np.asarray(c, dtype=float).reshape(4, 2))
            for c, i in zip(corners, ids.ravel(), strict=True)
        ]


def marker_object_points(marker_size: float) -> np.ndarray:
    """Corners of a square tag of side ``marker_size`` in its own frame, in the order IPPE_SQUARE needs."""
    h = 0.5 * marker_size
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass(frozen=True)
class MarkerPose:
    """Tag pose in the camera frame and its RMS re-projection error (px)."""

    T_cam_tag: np.ndarray
    reprojection_error: float


def estimate_marker_pose(
    corners: np.ndarray, intrinsics: CameraIntrinsics, marker_size: float, R_prior: np.ndarray | None = None
) -> MarkerPose:
    """Pose of a square tag from its 4 corners: ``cv2.solvePnPGeneric`` with ``SOLVEPNP_IPPE_SQUARE``.

    IPPE returns the two poses a planar square admits; we keep the one with the lower re-projection
    error, or — when both fit about equally well (a nearly fronto-parallel tag) — the one whose rotation
    is closest to ``R_prior`` (the rest pose), then polish it with Levenberg-Marquardt.
    """
    cv2 = cv2_module()
    if marker_size <= 0:
        raise UsageError(
            "marker_size must be > 0 (metres)", "give the printed tag's black-square side in metres"
        )
    img = np.asarray(corners, dtype=np.float64).reshape(4, 1, 2)
    obj = marker_object_points(marker_size).reshape(4, 1, 3)
    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(
        obj, img, intrinsics.K, intrinsics.dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
    )
    if n < 1:
        raise DataError("marker pose: solvePnP found no solution", "check the intrinsics and the marker size")
    errs = np.asarray(errs, dtype=float).ravel()
    best = int(np.argmin(errs))
    if R_prior is not None and n > 1 and errs.max() < 2.0 * errs.min() + 0.3:
        angles = [
            np.linalg.norm(Rotation.from_matrix(R_prior.T @ cv2.Rodrigues(r)[0]).as_rotvec()) for r in rvecs
        ]
        best = int(np.argmin(angles))
    rvec, tvec = cv2.solvePnPRefineLM(
        obj, img, intrinsics.K, intrinsics.dist, rvecs[best].copy(), tvecs[best].copy()
    )
    proj, _ = cv2.projectPoints(obj, rvec, tvec, intrinsics.K, intrinsics.dist)
    err = float(np.sqrt(np.mean(np.sum((proj.reshape(4, 2) - img.reshape(4, 2)) ** 2, axis=1))))
    return MarkerPose(make_T(cv2.Rodrigues(rvec)[0], tvec.ravel()), err)


@dataclass(frozen=True)
class MarkerReading:
    """Tag displacement at time ``t`` relative to the rest pose, in the tool frame (metres).

    ``displacement`` is filtered, ``raw`` is not; ``lateral`` = tool x, y components (the 2-D δ plane of
    the paper), ``axial`` = along the finger (tool z). ``tilt`` is the tag's rotation vector from rest (tool
    frame, rad).
    """

    t: float
    displacement: np.ndarray
    raw: np.ndarray
    tilt: np.ndarray
    reprojection_error: float
    corners: np.ndarray | None = None

    @property
    def lateral(self) -> np.ndarray:
        return self.displacement[:2]

    @property
    def axial(self) -> float:
        return float(self.displacement[2])

    def split(self, normal_tool_xy: np.ndarray) -> tuple[float, float]:
        """Normal and tangential components of the lateral displacement w.r.t. a unit tool-frame xy normal."""
        n = np.asarray(normal_tool_xy, dtype=float)[:2]
        n = n / np.linalg.norm(n)
        t = np.array([n[1], -n[0]])
        return float(self.lateral @ n), float(self.lateral @ t)


@dataclass(frozen=True)
class MarkerLost:
    """No trustworthy tag pose in this frame. ``frames_lost`` counts consecutive lost frames."""

    t: float
    reason: str
    frames_lost: int


def require_reading(result: MarkerReading | MarkerLost) -> MarkerReading:
    """Return the reading, or raise :class:`DataError` for a lost marker (for callers that cannot go on)."""
    if isinstance(result, MarkerLost):
        raise DataError(
            f"SRM marker lost at t={result.t:.3f} s ({result.reason}, {result.frames_lost} frames)",
            "check the in-finger camera, its lighting and that the tag is not occluded or torn",
        )
    return result


class MarkerDisplacementEstimator:
    """Camera frames → tag displacement δ in the tool frame, filtered at camera rate.

    Call :meth:`capture_rest` with frames taken without contact, then :meth:`update` once per frame.
    ``T_tool_cam`` places the in-finger camera in the tool frame (default: optical axis along tool z,
    camera x along tool x).
    """

    # parameters: the tag, the camera and the One-Euro filter, each a keyword with a default
    def __init__(
        self,
        intrinsics: CameraIntrinsics,
        marker_size: float = 0.010,
        marker_id: int = 0,
        dictionary: str = "DICT_4X4_50",
        T_tool_cam: np.ndarray | None = None,
        filter: Literal["one-euro", "none"] = "one-euro",
        min_cutoff: float = 3.0,
        beta: float = 200.0,
        max_reprojection_error: float = 1.5,
        reset_after: float = 0.5,
        detector: MarkerDetector | None = None,
    ) -> None:
        if marker_size <= 0:
            raise UsageError("marker_size must be > 0 (metres)", "give the tag's side in metres, e.g. 0.010")
        self.intrinsics = intrinsics
        self.marker_size = float(marker_size)
        self.marker_id = int(marker_id)
        self.T_tool_cam = np.eye(4) if T_tool_cam is None else np.asarray(T_tool_cam, dtype=float)
        self.detector = detector or MarkerDetector(dictionary, "subpix")
        if filter not in ("one-euro", "none"):
            raise UsageError(f"unknown filter {filter!r}", "use 'one-euro' or 'none'")
        self.filter = OneEuroFilter(min_cutoff, beta) if filter == "one-euro" else PassThrough()
        self.max_reprojection_error = float(max_reprojection_error)
        self.reset_after = float(reset_after)
        self.T_cam_tag_rest: np.ndarray | None = None
        self._lost = 0
        self._last_ok_t: float | None = None

    def _find(self, image: np.ndarray) -> tuple[DetectedMarker | None, str]:
        found = self.detector.detect(image)
        if not found:
            return None, "no marker detected"
        mine = [m for m in found if m.id == self.marker_id]
        if not mine:
            return None, f"marker id {self.marker_id} not found (saw {sorted(m.id for m in found)})"
        return mine[0], ""

    def capture_rest(self, images: list[np.ndarray] | np.ndarray) -> np.ndarray:
        """Average the tag pose over frames taken without contact; returns ``T_cam_tag_rest``."""
        frames = (
            [images]
            if isinstance(images, np.ndarray)
            and images.ndim in (2, 3)
            and (images.ndim == 2 or images.shape[2] in (3, 4))
            else list(images)
        )
        poses = []
        for img in frames:
            m, _ = self._find(img)
            if m is None:
                continue
            pose = estimate_marker_pose(m.corners, self.intrinsics, self.marker_size)
            if pose.reprojection_error <= self.max_reprojection_error:
                poses.append(pose.T_cam_tag)
        if not poses:
            raise DataError(
                f"SRM rest pose: marker id {self.marker_id} not found in any of {len(frames)} frames",
                "capture the rest pose with the finger free of contact and the tag in view",
            )
        R = orthonormalize(np.mean([T[:3, :3] for T in poses], axis=0))
        self.T_cam_tag_rest = make_T(R, np.mean([T[:3, 3] for T in poses], axis=0))
        self.filter.reset()
        return self.T_cam_tag_rest

    def set_rest(self, T_cam_tag_rest: np.ndarray) -> None:
        """Set the rest pose directly (e.g. from a stored SRM calibration)."""
        self.T_cam_tag_rest = np.asarray(T_cam_tag_rest, dtype=float)
        self.filter.reset()

    def _lost_result(self, t: float, reason: str) -> MarkerLost:
        self._lost += 1
        return MarkerLost(t, reason, self._lost)

    def update_pose(
        self,
        T_cam_tag: np.ndarray,
        t: float,
        reprojection_error: float = 0.0,
        corners: np.ndarray | None = None,
    ) -> MarkerReading:
        """Displacement from an already estimated tag pose (also used when rendering is skipped)."""
        if self.T_cam_tag_rest is None:
            raise UsageError("SRM marker: no rest pose", "call capture_rest() with contact-free frames first")
        if self._last_ok_t is not None and t - self._last_ok_t > self.reset_after:
            self.filter.reset()
        R_tc = self.T_tool_cam[:3, :3]
        raw = R_tc @ (T_cam_tag[:3, 3] - self.T_cam_tag_rest[:3, 3])
        rot = Rotation.from_matrix(T_cam_tag[:3, :3] @ self.T_cam_tag_rest[:3, :3].T).as_rotvec()
        self._lost = 0
        self._last_ok_t = t
        return MarkerReading(t, self.filter(raw, t), raw, R_tc @ rot, reprojection_error, corners)

    def update(self, image: np.ndarray, t: float) -> MarkerReading | MarkerLost:
        """Process one camera frame taken at time ``t`` (s)."""
        if self.T_cam_tag_rest is None:
            raise UsageError("SRM marker: no rest pose", "call capture_rest() with contact-free frames first")
        m, why = self._find(image)
        if m is None:
            return self._lost_result(t, why)
        pose = estimate_marker_pose(m.corners, self.intrinsics, self.marker_size, self.T_cam_tag_rest[:3, :3])
        if not np.isfinite(pose.reprojection_error) or pose.reprojection_error > self.max_reprojection_error:
            return self._lost_result(
                t, f"pose rejected: re-projection error {pose.reprojection_error:.2f} px"
            )
        return self.update_pose(pose.T_cam_tag, t, pose.reprojection_error, m.corners)
