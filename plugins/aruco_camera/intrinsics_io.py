"""Reading OpenCV camera calibration files (``cv2.FileStorage``: YAML or XML)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from weldcell.hal.readings import Intrinsics
from weldcell.sdk.errors import DataError


def read_opencv_intrinsics(path: str | Path) -> Intrinsics:
    """Intrinsics from an OpenCV calibration file: ``camera_matrix`` (3x3), ``distortion_coefficients``,
    ``image_width``/``image_height`` (as written by OpenCV's calibration samples)."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise DataError(
            f"intrinsics file {path} does not exist", "fix intrinsics_file in the camera settings"
        )
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        if not fs.isOpened():
            raise DataError(
                f"OpenCV cannot read {path}", "give a calibration YAML/XML written by cv2.FileStorage"
            )
        K = fs.getNode("camera_matrix").mat()
        D = fs.getNode("distortion_coefficients").mat()
        w, h = fs.getNode("image_width"), fs.getNode("image_height")
        width = int(w.real()) if not w.empty() else 0
        height = int(h.real()) if not h.empty() else 0
    finally:
        fs.release()
    if K is None or np.asarray(K).shape != (3, 3):
        raise DataError(f"{path} has no 3x3 'camera_matrix'", "calibrate the camera and save camera_matrix")
    if width <= 0 or height <= 0:
        raise DataError(
            f"{path} has no image_width/image_height", "add the calibration resolution to the file"
        )
    K = np.asarray(K, dtype=float)
    dist = tuple(float(v) for v in np.asarray(D, dtype=float).ravel()) if D is not None else ()
    return Intrinsics(width=width, height=height, fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], dist=dist)


def scaled(k: Intrinsics, width: int, height: int) -> Intrinsics:
    """Intrinsics of the same camera delivering ``width`` x ``height`` frames (a pure rescale of the sensor
    readout; the pixel-centre convention of OpenCV, ``u' = (u + 0.5) s - 0.5``)."""
    if (width, height) == (k.width, k.height):
        return k
    sx, sy = width / k.width, height / k.height
    return Intrinsics(
        width=width,
        height=height,
        fx=k.fx * sx,
        fy=k.fy * sy,
        cx=(k.cx + 0.5) * sx - 0.5,
        cy=(k.cy + 0.5) * sy - 0.5,
        dist=k.dist,
    )
