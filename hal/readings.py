"""What devices return. Every reading carries a timestamp (s, the host's clock unless said) and a frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from weldcell.sdk.cloud import PointCloud


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera intrinsics (pixels) and distortion (OpenCV order)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = ()

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class RobotState:
    """Joint positions (rad), the flange and TCP poses in the robot base frame, and status flags."""

    stamp: float
    q: np.ndarray
    T_base_flange: np.ndarray
    T_base_tcp: np.ndarray
    qd: np.ndarray | None = None
    moving: bool = False
    protective_stop: bool = False
    frame: str = "base"


@dataclass(frozen=True)
class DepthFrame:
    """One depth image (metres, 0 = no data) in the camera's optical frame, with optional colour."""

    stamp: float
    depth: np.ndarray
    intrinsics: Intrinsics
    frame: str = "camera"
    color: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def to_cloud(self, min_depth: float = 1e-6) -> PointCloud:
        """Back-project the valid pixels into an (N, 3) cloud in the camera frame (optical: z forward)."""
        d = np.asarray(self.depth, dtype=np.float64)
        v, u = np.nonzero(np.isfinite(d) & (d > min_depth))
        z = d[v, u]
        k = self.intrinsics
        pts = np.column_stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z])
        colors = None
        if self.color is not None and self.color.shape[:2] == d.shape:
            c = np.asarray(self.color)[v, u]
            colors = (c[:, :3] / 255.0) if c.dtype == np.uint8 else c[:, :3]
        return PointCloud(pts, colors=colors, frame=self.frame, meta={"stamp": self.stamp})


@dataclass(frozen=True)
class Hand:
    """One tracked hand in the gesture sensor's frame (metres; y up for a Leap)."""

    side: str
    """'left' or 'right'."""
    palm_position: np.ndarray
    palm_normal: np.ndarray
    direction: np.ndarray
    grab_strength: float = 0.0
    pinch_strength: float = 0.0
    fingertips: dict[str, np.ndarray] = field(default_factory=dict)
    """Finger name ('thumb', 'index', 'middle', 'ring', 'pinky') -> tip position."""
    extended: dict[str, bool] = field(default_factory=dict)
    confidence: float = 1.0
    time_visible: float = 0.0


@dataclass(frozen=True)
class InteractionBox:
    """The sensor's interaction box: centre and size (metres) in the sensor frame."""

    center: np.ndarray
    size: np.ndarray


@dataclass(frozen=True)
class HandsFrame:
    """One frame of a gesture sensor."""

    stamp: float
    hands: tuple[Hand, ...]
    frame_id: int = 0
    interaction_box: InteractionBox | None = None
    frame: str = "gesture"

    def hand(self, side: str) -> Hand | None:
        return next((h for h in self.hands if h.side == side), None)


@dataclass(frozen=True)
class Displacement:
    """A 1-D laser displacement reading (metres along the beam), None when out of range."""

    stamp: float
    distance: float | None
    frame: str = "laser"
    device_stamp: float | None = None
    """The sensor's own time stamp (s, its clock) where the protocol sends one; None otherwise."""
    error: str | None = None
    """Why ``distance`` is None, as the sensor reports it ("too far from the sensor", ...)."""

    @property
    def valid(self) -> bool:
        return self.distance is not None


@dataclass(frozen=True)
class Image:
    """A camera image (H, W) or (H, W, 3) uint8 with its intrinsics."""

    stamp: float
    image: np.ndarray
    intrinsics: Intrinsics | None = None
    frame: str = "camera"


@dataclass(frozen=True)
class ImuReading:
    """Acceleration (m/s^2), angular rate (rad/s), optional magnetic field (uT) and orientation [x,y,z,w]."""

    stamp: float
    accel: np.ndarray
    gyro: np.ndarray
    mag: np.ndarray | None = None
    orientation: np.ndarray | None = None
    frame: str = "imu"
    device_stamp: float | None = None
    """The IMU's own time stamp (s, its clock) where the protocol sends one; None otherwise."""


@dataclass(frozen=True)
class GnssFix:
    """A GNSS fix: WGS-84 latitude/longitude (deg), altitude (m), and the local ENU position (m)."""

    stamp: float
    latitude: float
    longitude: float
    altitude: float
    enu: np.ndarray | None = None
    covariance: np.ndarray | None = None
    fix_type: str = "3d"
    """One of ``FIX_TYPES``: "none" (no position: latitude/longitude/altitude are NaN), "dead-reckoning",
    "2d", "3d", "gnss+dr", "time-only", "dgnss", "rtk-float", "rtk-fixed"."""
    frame: str = "enu"
    device_stamp: float | None = None
    """The receiver's UTC time of the solution (s since the Unix epoch) where it sends one."""
    h_acc: float | None = None
    """Horizontal accuracy estimate (1 sigma, m) as the receiver reports it."""
    v_acc: float | None = None
    """Vertical accuracy estimate (1 sigma, m)."""
    num_sv: int | None = None
    """Satellites used in the solution."""
    velocity_enu: np.ndarray | None = None
    """Velocity east/north/up (m/s) where the receiver sends it."""

    @property
    def valid(self) -> bool:
        """True when the fix carries a position (not "none" / "time-only", finite coordinates)."""
        return self.fix_type not in ("none", "time-only") and bool(
            np.isfinite([self.latitude, self.longitude]).all()
        )


FIX_TYPES = ("none", "dead-reckoning", "2d", "3d", "gnss+dr", "time-only", "dgnss", "rtk-float", "rtk-fixed")
"""The values of :attr:`GnssFix.fix_type`."""


@dataclass(frozen=True)
class Projection:
    """What a projector confirms it drew: the segments (N, 2, 3) in ``frame`` and when."""

    stamp: float
    segments: np.ndarray
    label: str = ""
    frame: str = "world"
