"""The ZED factory calibration file (``SN<serial>.conf``) and stereo rectification with OpenCV.

Format (INI, one section per camera and resolution)::

    [LEFT_CAM_HD]            fx, fy, cx, cy [px], k1, k2, p1, p2, k3 (OpenCV order)
    [RIGHT_CAM_HD]           same for the right camera
    [STEREO]                 Baseline [mm], TY, TZ [mm] (or TY_HD, TZ_HD), CV_HD, RX_HD, RZ_HD [rad]

Resolution keys: 2K (2208x1242 per eye), FHD (1920x1080), HD (1280x720), VGA (672x376).
Conventions (as in Stereolabs' zed-opencv-native sample): the right camera's centre in the left camera
frame is (Baseline, TY, TZ) mm, its rotation is Rodrigues([RX, CV, RZ]). OpenCV's stereo extrinsics
(``p_right = R p_left + T``) are then ``R`` and ``T = -R c_right`` (metres).
"""

from __future__ import annotations

import configparser
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from weldcell.hal.readings import Intrinsics
from weldcell.sdk.errors import DataError

RESOLUTIONS: dict[str, tuple[int, int]] = {
    "2K": (2208, 1242),
    "FHD": (1920, 1080),
    "HD": (1280, 720),
    "VGA": (672, 376),
}
"""Per-eye image size of each ZED resolution."""


@dataclass(frozen=True)
class StereoCalibration:
    """Both cameras' intrinsics and the stereo extrinsics (OpenCV convention, metres) at one resolution."""

    resolution: str
    size: tuple[int, int]
    K_left: np.ndarray
    dist_left: np.ndarray
    K_right: np.ndarray
    dist_right: np.ndarray
    R: np.ndarray
    T: np.ndarray

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T))


@dataclass(frozen=True)
class Rectification:
    """Rectification maps and the rectified left camera (``P1``), with ``fx * baseline`` for depth."""

    maps_left: tuple[np.ndarray, np.ndarray]
    maps_right: tuple[np.ndarray, np.ndarray]
    R1: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    intrinsics: Intrinsics
    fx_baseline: float
    """Focal length [px] times baseline [m]: depth = fx_baseline / disparity."""


def _cam(cp: configparser.ConfigParser, section: str, path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not cp.has_section(section):
        raise DataError(
            f"{path}: no [{section}] section", "use the factory file of this camera (SN<serial>.conf)"
        )
    try:
        s = cp[section]
        K = np.array([[float(s["fx"]), 0, float(s["cx"])], [0, float(s["fy"]), float(s["cy"])], [0, 0, 1]])
        dist = np.array([float(s.get(k, "0")) for k in ("k1", "k2", "p1", "p2", "k3")])
    except (KeyError, ValueError) as e:
        raise DataError(
            f"{path} [{section}]: missing or bad value ({e})", "re-download the factory file"
        ) from e
    return K, dist


def load_conf(path: str | Path, resolution: str) -> StereoCalibration:
    """Read ``SN<serial>.conf`` for one resolution ('2K', 'FHD', 'HD', 'VGA')."""
    path = Path(path)
    res = resolution.upper()
    if res not in RESOLUTIONS:
        raise DataError(f"unknown ZED resolution {resolution!r}", f"use one of {', '.join(RESOLUTIONS)}")
    if not path.is_file():
        raise DataError(
            f"ZED calibration file {path} not found",
            "download it once from https://calib.stereolabs.com/?SN=<serial> (the ZED SDK keeps it in "
            "/usr/local/zed/settings/) and set calibration_file",
        )
    cp = configparser.ConfigParser()
    cp.optionxform = str.lower
    try:
        cp.read_string(path.read_text())
    except configparser.Error as e:
        raise DataError(f"{path} is not a ZED calibration file: {e}", "re-download the factory file") from e
    K_l, d_l = _cam(cp, f"LEFT_CAM_{res}", path)
    K_r, d_r = _cam(cp, f"RIGHT_CAM_{res}", path)
    if not cp.has_section("STEREO"):
        raise DataError(f"{path}: no [STEREO] section", "re-download the factory file")
    st = cp["STEREO"]
    low = res.lower()

    def val(key: str, default: float = 0.0) -> float:
        for k in (f"{key}_{low}", key):
            if k in st:
                return float(st[k])
        return default

    baseline = val("baseline", float("nan"))
    if not np.isfinite(baseline) or baseline <= 0:
        raise DataError(f"{path}: [STEREO] Baseline missing or not positive", "re-download the factory file")
    c_right = np.array([baseline, val("ty"), val("tz")]) / 1000.0
    R, _ = cv2.Rodrigues(np.array([val("rx"), val("cv"), val("rz")], dtype=float))
    return StereoCalibration(res, RESOLUTIONS[res], K_l, d_l, K_r, d_r, R, -R @ c_right)


def write_conf(path: str | Path, cals: list[StereoCalibration]) -> None:
    """Write calibrations in the factory file format (for tests and for re-calibrated cameras)."""
    lines = []
    for c in cals:
        for side, K, d in (("LEFT", c.K_left, c.dist_left), ("RIGHT", c.K_right, c.dist_right)):
            lines.append(f"[{side}_CAM_{c.resolution}]")
            lines += [f"fx={K[0, 0]:.6f}", f"fy={K[1, 1]:.6f}", f"cx={K[0, 2]:.6f}", f"cy={K[1, 2]:.6f}"]
            lines += [f"{k}={v:.8f}" for k, v in zip(("k1", "k2", "p1", "p2", "k3"), d, strict=True)]
            lines.append("")
    c_right = -cals[0].R.T @ cals[0].T * 1000.0  # the centre is the same at every resolution
    lines += ["[STEREO]", f"Baseline={c_right[0]:.6f}", f"TY={c_right[1]:.6f}", f"TZ={c_right[2]:.6f}"]
    for cal in cals:
        r = cv2.Rodrigues(cal.R)[0].ravel()
        lines += [
            f"CV_{cal.resolution}={r[1]:.8f}",
            f"RX_{cal.resolution}={r[0]:.8f}",
            f"RZ_{cal.resolution}={r[2]:.8f}",
        ]
    Path(path).write_text("\n".join(lines) + "\n")


def rectify(cal: StereoCalibration) -> Rectification:
    """``cv2.stereoRectify`` (zero disparity at infinity, no black borders cropped) and remap tables."""
    size = cal.size
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
        cal.K_left,
        cal.dist_left,
        cal.K_right,
        cal.dist_right,
        size,
        cal.R,
        cal.T,
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0,
    )
    ml = cv2.initUndistortRectifyMap(cal.K_left, cal.dist_left, R1, P1, size, cv2.CV_16SC2)
    mr = cv2.initUndistortRectifyMap(cal.K_right, cal.dist_right, R2, P2, size, cv2.CV_16SC2)
    intr = Intrinsics(size[0], size[1], float(P1[0, 0]), float(P1[1, 1]), float(P1[0, 2]), float(P1[1, 2]))
    return Rectification(ml, mr, R1, P1, P2, Q, intr, float(-P2[0, 3]))
