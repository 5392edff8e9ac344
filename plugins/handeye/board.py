"""Calibration-board pose from a photo (ChArUco or ArUco grid): cv2.aruco detection + solvePnP.
OpenCV is imported inside these functions only."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from weldcell.sdk.errors import DataError, MissingExtraError


def _cv2():
    try:
        import cv2
    except ImportError:
        raise MissingExtraError("board detection", "cv2", "vision") from None
    return cv2


@dataclass
class BoardSpec:
    """A board: ``kind`` "charuco" (squares_x x squares_y chessboard, square and marker side in m)
    or "aruco-grid" (squares_x x squares_y markers of ``marker`` m separated by ``separation`` m)."""

    kind: str = "charuco"
    squares_x: int = 5
    squares_y: int = 7
    square: float = 0.04
    marker: float = 0.02
    separation: float = 0.01
    dictionary: str = "DICT_6X6_250"

    def build(self):
        cv2 = _cv2()
        if not hasattr(cv2.aruco, self.dictionary):
            raise DataError(
                f"unknown ArUco dictionary '{self.dictionary}'", "use e.g. DICT_6X6_250, DICT_5X5_100"
            )
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        if self.kind == "charuco":
            return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square, self.marker, d), d
        if self.kind == "aruco-grid":
            return cv2.aruco.GridBoard((self.squares_x, self.squares_y), self.marker, self.separation, d), d
        raise DataError(f"unknown board kind '{self.kind}'", "use 'charuco' or 'aruco-grid'")


@dataclass
class BoardPose:
    """``T_cam_board`` (board frame into the camera), points used and RMS reprojection error (px)."""

    T_cam_board: np.ndarray
    n_points: int
    reprojection_rms: float
    marker_ids: list[int]


def read_intrinsics(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Camera matrix and distortion from an OpenCV YAML/XML file (camera_matrix,
    distortion_coefficients)."""
    cv2 = _cv2()
    path = Path(path)
    if not path.is_file():
        raise DataError(f"intrinsics file not found: {path}", "check the path")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat()
    fs.release()
    if K is None or K.shape != (3, 3):
        raise DataError(f"{path}: no 3x3 camera_matrix", "write the OpenCV calibration file again")
    return K.astype(float), (np.zeros(5) if dist is None else dist.ravel().astype(float))


def board_pose(
    image, spec: BoardSpec, K: np.ndarray, dist: np.ndarray | None = None, min_points: int = 6
) -> BoardPose:
    """Detect the board in ``image`` (array or path) and estimate ``T_cam_board`` by solvePnP
    (iterative, from the matched board points). Raises DataError when too few points are seen."""
    cv2 = _cv2()
    if isinstance(image, str | Path):
        img = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise DataError(f"cannot read image {image}", "check the path and format")
    else:
        img = np.asarray(image)
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    board, d = spec.build()
    dist = np.zeros(5) if dist is None else np.asarray(dist, float)
    if spec.kind == "charuco":
        ch_corners, ch_ids, m_corners, m_ids = cv2.aruco.CharucoDetector(board).detectBoard(img)
        if ch_ids is None or len(ch_ids) < min_points:
            raise DataError(
                f"ChArUco board: {0 if ch_ids is None else len(ch_ids)} corners found, need {min_points}",
                "check the board parameters (squares, dictionary), focus and lighting",
            )
        obj, imgp = board.matchImagePoints(ch_corners, ch_ids)
    else:
        m_corners, m_ids, _ = cv2.aruco.ArucoDetector(d).detectMarkers(img)
        if m_ids is None or 4 * len(m_ids) < min_points:
            raise DataError("ArUco grid: too few markers found", "check the board parameters and image")
        obj, imgp = board.matchImagePoints(m_corners, m_ids)
    obj = obj.reshape(-1, 3).astype(float)
    imgp = imgp.reshape(-1, 2).astype(float)
    ok, rvec, tvec = cv2.solvePnP(obj, imgp, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise DataError("solvePnP failed on the detected board points", "check the intrinsics")
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - imgp) ** 2, axis=1))))
    R, _ = cv2.Rodrigues(rvec)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, tvec.ravel()
    ids = [] if m_ids is None else [int(i) for i in np.ravel(m_ids)]
    return BoardPose(T, len(obj), rms, ids)
