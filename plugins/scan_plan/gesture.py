"""Gesture-guided scanning: the "joystick" interaction of Algorithm 1 (paper 000, §II-B).

The left palm's position in a cube-shaped interaction box above the sensor picks one of seven
regions. Outside *home* the camera moves along the region's unit direction ``u_d`` (expressed in the
robot base frame through ``R_base_sensor``) by a step ``l`` per frame (Alg. 1 lines 5-8, written
there as ``P_{t+1} = u_d · l``; the step is added to the current position). In *home* the camera
keeps its position and takes the hand's orientation: ``R_base_hand = R_base_lm · R_lm_hand``
(lines 11-14), with the camera's approach axis aligned with the palm normal as in the paper's §IV-A;
the result is written as a UR rotation vector (inverse Rodrigues). The right hand's "ok" sign
captures a cloud with the flange pose of that instant; a closed right fist ends the scan.

Beyond the paper (docs/methods/gesture-scanning.md): the palm position is low-pass filtered; the
home region has a dead-band with hysteresis so a shaky hand does not jerk the robot; translation
and rotation are rate-limited; a hand must be tracked for a few frames before it acts; "ok" and
fist need to be held (debounced) and a capture fires once per sign; ``rotation = "relative"``
makes rotation mode a clutch (hand rotation relative to the moment it entered home) instead of the
paper's absolute mapping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation
from weldcell.hal.readings import Hand, HandsFrame
from weldcell.sdk.geometry import T_from_rpy, orthonormalize
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, AngularSpeed, Duration, Length, Speed

REGION_AXES = {  # unit direction of each region in the sensor (Leap) frame: x right, y up, z toward the user
    "left": np.array([-1.0, 0.0, 0.0]),
    "right": np.array([1.0, 0.0, 0.0]),
    "up": np.array([0.0, 1.0, 0.0]),
    "down": np.array([0.0, -1.0, 0.0]),
    "inward": np.array([0.0, 0.0, -1.0]),
    "outward": np.array([0.0, 0.0, 1.0]),
}


class GestureScanSettings(Settings):
    """Settings of the gesture "joystick" (Algorithm 1)."""

    box_size: Length = Field(0.10, gt=0, description="edge of the cubic interaction box (paper: 10 cm) [m]")
    box_center: tuple[Length, Length, Length] | None = Field(
        None,
        description="centre of the box in the sensor frame [m]; default: the sensor's own interaction box",
    )
    home_size: Length = Field(0.04, gt=0, description="edge of the central home cube [m]")
    hysteresis: Length = Field(0.005, ge=0, description="extra distance to leave home (dead-band) [m]")
    speed: Speed = Field(0.08, gt=0, description="camera speed outside home: the step l per second [m/s]")
    max_angular_speed: AngularSpeed = Field(0.8, gt=0, description="rotation rate limit in home [rad/s]")
    rotation: Literal["absolute", "relative"] = Field(
        "absolute", description="'absolute' = the paper's mapping; 'relative' = clutch from entering home"
    )
    rotation_deadband: Angle = Field(0.05, ge=0, description="hand rotation ignored below this [rad]")
    smoothing: float = Field(
        0.35, gt=0, le=1, description="low-pass weight of a new palm position (1 = none)"
    )
    min_visible_frames: int = Field(5, ge=1, description="frames a hand must be tracked before it acts")
    ok_distance: Length = Field(0.03, gt=0, description="thumb-index tip distance of the 'ok' sign [m]")
    ok_hold: Duration = Field(0.12, ge=0, description="how long 'ok' must be held to capture [s]")
    stop_hold: Duration = Field(
        0.4, ge=0, description="how long a right fist must be held to end the scan [s]"
    )
    sensor_rpy: tuple[Angle, Angle, Angle] = Field(
        (math.pi / 2, 0.0, 0.0),
        description="orientation of the sensor in the robot base frame (roll, pitch, yaw) [rad]; the default "
        "maps the Leap's y (up) to base z and its z (toward the user) to base -y",
    )


@dataclass(frozen=True)
class GestureCommand:
    """What one frame asks for: a camera target (or None), a capture, the end of the scan."""

    target: np.ndarray | None
    capture: bool
    stop: bool
    region: str | None
    mode: str


def hand_rotation(hand: Hand) -> np.ndarray:
    """``R_sensor_hand``: z = palm normal, x = finger direction (orthogonalised), y = z × x."""
    z = np.asarray(hand.palm_normal, dtype=float)
    z = z / np.linalg.norm(z)
    x = np.asarray(hand.direction, dtype=float)
    x = x - np.dot(x, z) * z
    x = x / np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def is_ok_sign(hand: Hand, distance: float) -> bool:
    """Thumb and index tips touching while middle, ring and pinky stay extended."""
    tips = hand.fingertips
    if "thumb" not in tips or "index" not in tips:
        return hand.pinch_strength > 0.9 and hand.grab_strength < 0.5
    close = np.linalg.norm(np.asarray(tips["thumb"]) - np.asarray(tips["index"])) < distance
    others = all(hand.extended.get(f, True) for f in ("middle", "ring", "pinky"))
    return bool(close and others)


def is_fist(hand: Hand) -> bool:
    return hand.grab_strength > 0.95 or (bool(hand.extended) and not any(hand.extended.values()))


class GestureScanController:
    """Turns hands frames into camera targets, captures and a stop (Algorithm 1 + safeguards)."""

    def __init__(self, settings: GestureScanSettings | None = None, rate_hint: float = 60.0) -> None:
        self.s = settings or GestureScanSettings()
        self.R_base_sensor = T_from_rpy(self.s.sensor_rpy)[:3, :3]
        self.rate_hint = rate_hint
        self._palm: np.ndarray | None = None
        self._visible = 0
        self._region: str | None = None
        self._ok_since: float | None = None
        self._ok_fired = False
        self._fist_since: float | None = None
        self._clutch: tuple[np.ndarray, np.ndarray] | None = None
        self._last_stamp: float | None = None

    def _dt(self, stamp: float) -> float:
        dt = 1.0 / self.rate_hint if self._last_stamp is None else stamp - self._last_stamp
        self._last_stamp = stamp
        return float(np.clip(dt, 1e-3, 0.1)) if dt > 0 else 1.0 / self.rate_hint

    def region_of(self, palm: np.ndarray, center: np.ndarray) -> str | None:
        """The region of a palm position (None outside the box); home keeps a dead-band."""
        rel = palm - center
        half_box = self.s.box_size / 2
        if np.any(np.abs(rel) > half_box * 1.5):
            return None
        half_home = self.s.home_size / 2 + (self.s.hysteresis if self._region in (None, "home") else 0.0)
        if np.all(np.abs(rel) <= half_home):
            return "home"
        axis = int(np.argmax(np.abs(rel)))
        names = (("left", "right"), ("down", "up"), ("inward", "outward"))[axis]
        return names[int(rel[axis] > 0)]

    def update(
        self, frame: HandsFrame, T_base_camera: np.ndarray, stamp: float | None = None
    ) -> GestureCommand:
        """One step of Algorithm 1 for the current camera pose ``T_base_camera``."""
        t = frame.stamp if stamp is None else stamp
        dt = self._dt(t)
        capture = stop = False
        right = frame.hand("right")
        if right is not None:
            if is_ok_sign(right, self.s.ok_distance):
                self._ok_since = t if self._ok_since is None else self._ok_since
                if not self._ok_fired and t - self._ok_since >= self.s.ok_hold:
                    capture, self._ok_fired = True, True
            else:
                self._ok_since, self._ok_fired = None, False
            if is_fist(right):
                self._fist_since = t if self._fist_since is None else self._fist_since
                stop = t - self._fist_since >= self.s.stop_hold
            else:
                self._fist_since = None
        else:
            self._ok_since, self._ok_fired, self._fist_since = None, False, None

        left = frame.hand("left")
        if left is None:
            self._visible, self._palm, self._region, self._clutch = 0, None, None, None
            return GestureCommand(None, capture, stop, None, "idle")
        self._visible += 1
        palm = np.asarray(left.palm_position, dtype=float)
        self._palm = palm if self._palm is None else self._palm + self.s.smoothing * (palm - self._palm)
        if self._visible < self.s.min_visible_frames or capture or stop:
            return GestureCommand(None, capture, stop, self._region, "idle")
        if self.s.box_center is not None:
            center = np.asarray(self.s.box_center, dtype=float)
        elif frame.interaction_box is not None:
            center = np.asarray(frame.interaction_box.center, dtype=float)
        else:
            center = np.array([0.0, 0.2, 0.0])
        region = self.region_of(self._palm, center)
        if region != "home":
            self._clutch = None
        self._region = region
        if region is None:
            return GestureCommand(None, False, False, None, "idle")
        T = np.array(T_base_camera, dtype=float)
        if region != "home":  # Alg. 1 lines 5-8: translate along u_d by l
            u_d = self.R_base_sensor @ REGION_AXES[region]
            T[:3, 3] = T[:3, 3] + u_d * self.s.speed * dt
            return GestureCommand(T, False, False, region, "translate")
        # Alg. 1 lines 11-15: rotation mode, position kept
        R_base_hand = self.R_base_sensor @ hand_rotation(left)
        if self.s.rotation == "absolute":
            R_target = R_base_hand
        else:
            if self._clutch is None:
                self._clutch = (R_base_hand, T[:3, :3].copy())
            R_hand0, R_cam0 = self._clutch
            R_target = (R_base_hand @ R_hand0.T) @ R_cam0
        dR = Rotation.from_matrix(T[:3, :3].T @ R_target).as_rotvec()
        angle = float(np.linalg.norm(dR))
        if angle < self.s.rotation_deadband:
            return GestureCommand(None, False, False, region, "rotate")
        step = min(angle, self.s.max_angular_speed * dt)
        T[:3, :3] = orthonormalize(T[:3, :3] @ Rotation.from_rotvec(dR / angle * step).as_matrix())
        return GestureCommand(T, False, False, region, "rotate")
