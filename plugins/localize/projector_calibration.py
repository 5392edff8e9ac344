"""Projector calibration: the projector as a pinhole "inverse camera" (paper 002, §II-III).

The projector lights a grid of dots (known pixels) on the table from several robot poses; where each dot
lands is measured in the robot base frame (with the laser sensor or a camera; in simulation by ray
casting plus measurement noise). Every view is then a planar calibration target seen by a camera:
object points = the measured dots in a table frame (z = 0 on the table), image points = the pixels that
lit them. OpenCV's ``calibrateCamera`` solves the intrinsics (and distortion) and each view's
``T_projector_table``; with the robot's flange pose of each view, ``T_flange_projector`` follows as the
average (rotation mean, translation mean) of ``T_base_flange^-1 T_base_table T_table_projector``.

The result is ``weldcell/projector-calibration@1`` JSON: K, dist, T_flange_projector, the RMS
re-projection error (px) and the per-view landing error (m) of the dots re-projected through the result.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.artifacts import read_json, write_json
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy, invert

SCHEMA = "weldcell/projector-calibration@1"


@dataclass
class DotView:
    """One calibration view: the flange pose, the lit pixels (N, 2) and where they landed (N, 3), base."""

    T_base_flange: np.ndarray
    pixels: np.ndarray
    landed: np.ndarray


@dataclass
class ProjectorCalibration:
    """Intrinsics ``K`` (3, 3), distortion ``dist`` (OpenCV order), the mount ``T_flange_projector`` and
    the residuals that say how much to trust them."""

    K: np.ndarray
    dist: np.ndarray
    T_flange_projector: np.ndarray
    size: tuple[int, int]
    rms_px: float
    landing_error_mean: float
    landing_error_max: float
    views: int
    notes: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "schema": SCHEMA,
            "K": np.round(self.K, 6).tolist(),
            "dist": np.round(self.dist, 8).tolist(),
            "T_flange_projector": np.round(self.T_flange_projector, 9).tolist(),
            "size": list(self.size),
            "rms_px": self.rms_px,
            "landing_error_mean_m": self.landing_error_mean,
            "landing_error_max_m": self.landing_error_max,
            "views": self.views,
            **self.notes,
        }

    def save(self, path: str | Path) -> Path:
        return write_json(path, self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> ProjectorCalibration:
        d = read_json(path)
        if d.get("schema") != SCHEMA:
            raise DataError(
                f"{path}: not a projector calibration ({d.get('schema')!r})", "run the calibration"
            )
        return cls(
            np.asarray(d["K"], float),
            np.asarray(d["dist"], float),
            np.asarray(d["T_flange_projector"], float),
            tuple(d["size"]),
            float(d["rms_px"]),
            float(d["landing_error_mean_m"]),
            float(d["landing_error_max_m"]),
            int(d["views"]),
        )


def dot_pattern(width: int, height: int, cols: int = 9, rows: int = 6, margin: float = 0.1) -> np.ndarray:
    """Pixels (rows*cols, 2) of a dot grid covering the image but ``margin`` of its size from the border."""
    u = np.linspace(margin * width, (1 - margin) * width, cols)
    v = np.linspace(margin * height, (1 - margin) * height, rows)
    U, V = np.meshgrid(u, v)
    return np.column_stack([U.ravel(), V.ravel()])


def calibration_poses(
    centre_xy: np.ndarray, table_z: float, height: float, n: int = 8, tilt: float = np.radians(15)
) -> np.ndarray:
    """``T_base_projector`` targets (n, 4, 4): looking down over ``centre_xy`` from ``height``, tilted by
    ``tilt`` in turn about x and y and rotated about the view axis, so the intrinsics are observable."""
    out = []
    for k in range(n):
        a = 2 * np.pi * k / n
        R = T_from_rpy([np.pi + tilt * np.cos(a), tilt * np.sin(a), a / 2])[:3, :3]
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = [centre_xy[0], centre_xy[1], table_z + height * (1.0 + 0.1 * (k % 3))]
        out.append(T)
    return np.stack(out)


def calibrate(
    views: list[DotView],
    size: tuple[int, int],
    table_z: float,
    K_guess: np.ndarray | None = None,
    fix_distortion: bool = False,
) -> ProjectorCalibration:
    """Solve intrinsics, distortion and ``T_flange_projector`` from dot views with cv2.calibrateCamera."""
    import cv2

    usable = []
    for v in views:
        ok = np.isfinite(v.landed).all(axis=1)
        if ok.sum() >= 8:
            usable.append((v, ok))
    if len(usable) < 3:
        raise DataError(
            f"only {len(usable)} projector views have 8 or more measured dots (need 3)",
            "project the dot pattern onto the empty table from more robot poses",
        )
    T_base_table = np.eye(4)
    T_base_table[2, 3] = table_z
    obj = [(v.landed[ok] - [0, 0, table_z]).astype(np.float32) for v, ok in usable]
    for o in obj:
        o[:, 2] = 0.0
    img = [v.pixels[ok].astype(np.float32) for v, ok in usable]
    w, h = size
    K0 = K_guess if K_guess is not None else np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1.0]])
    flags = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3
    if fix_distortion:
        flags |= cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_ZERO_TANGENT_DIST
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
        obj, img, (w, h), K0.astype(np.float64), None, flags=flags
    )
    Rs, ts = [], []
    for (v, _), rv, tv in zip(usable, rvecs, tvecs, strict=True):
        T_proj_table = np.eye(4)
        T_proj_table[:3, :3] = cv2.Rodrigues(rv)[0]
        T_proj_table[:3, 3] = tv.ravel()
        T_fp = invert(v.T_base_flange) @ T_base_table @ invert(T_proj_table)
        Rs.append(T_fp[:3, :3])
        ts.append(T_fp[:3, 3])
    T_fp = np.eye(4)
    T_fp[:3, :3] = Rotation.from_matrix(np.stack(Rs)).mean().as_matrix()
    T_fp[:3, 3] = np.mean(ts, axis=0)
    errs = []
    for v, ok in usable:
        pred = land_on_table(v.pixels[ok], K, dist, v.T_base_flange @ T_fp, table_z)
        errs.append(np.linalg.norm(pred - v.landed[ok], axis=1))
    e = np.concatenate(errs)
    return ProjectorCalibration(
        K, dist.ravel(), T_fp, (w, h), float(rms), float(e.mean()), float(e.max()), len(usable)
    )


def land_on_table(
    pixels: np.ndarray, K: np.ndarray, dist: np.ndarray, T_base_projector: np.ndarray, table_z: float
) -> np.ndarray:
    """Where pixels (N, 2) land on the table plane z = ``table_z`` (N, 3), base frame."""
    import cv2

    und = cv2.undistortPoints(pixels.reshape(-1, 1, 2).astype(np.float64), K, dist).reshape(-1, 2)
    d = np.column_stack([und, np.ones(len(und))]) @ T_base_projector[:3, :3].T
    o = T_base_projector[:3, 3]
    s = (table_z - o[2]) / d[:, 2]
    return o + s[:, None] * d


def collect_views_sim(
    robot,
    projector,
    poses_base_projector: np.ndarray,
    T_flange_projector_nominal: np.ndarray,
    pixels: np.ndarray,
    noise: float,
    rng: np.random.Generator,
) -> list[DotView]:
    """Simulated measurement: move (through the safety gate) so the *nominal* mount puts the projector at
    each target, light the dots, ray-cast where they land, add ``noise`` (m, 1 sigma) per coordinate.

    A real cell measures the dots with the laser sensor (scan across each dot) or a calibrated camera."""
    T_wb = robot.T_world_base
    views = []
    for T_bp in poses_base_projector:
        move_to(robot, T_bp @ invert(T_flange_projector_nominal) @ robot.T_flange_tcp)
        landed_w = projector.project_pixels(pixels)
        landed = (np.c_[landed_w, np.ones(len(landed_w))] @ invert(T_wb).T)[:, :3]
        landed = landed + rng.normal(0.0, noise, landed.shape)
        views.append(DotView(robot.state().T_base_flange, pixels, landed))
    return views


def move_to(robot, T_base_tcp: np.ndarray) -> None:
    """A transit to a TCP pose through the safety gate: a joint move to its IK solution (large turns of
    the wrist are joint moves), or a linear move when the robot has no kinematic model."""
    gate = robot.gate
    if gate.model is None:
        robot.move_linear(T_base_tcp)
        return
    q = gate.solve(T_base_tcp @ invert(robot.T_flange_tcp), robot.state().q, "transit target")
    robot.move_joint(q)
