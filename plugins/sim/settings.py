"""Settings of the simulated cell's devices."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.hal.robot import RobotMotionSettings
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Frequency, Length

CameraPresetName = Literal["realsense-d415", "realsense-d435", "phoxi-s", "phoxi-m", "azure-kinect", "zed2i"]
RobotModelName = Literal["ur5", "ur10e", "franka-panda", "aubo-i5", "abb-irb2600"]


class SimRobotSettings(RobotMotionSettings):
    """A kinematic model of a real arm, obeying the cell's safety gate."""

    model: RobotModelName = Field("ur5", description="which robot model (docs/robot-models.md)")
    start_xyz: tuple[Length, Length, Length] | None = Field(
        None,
        description="flange position to start at, in the robot base frame [m]; default: the model's home",
    )
    start_rpy: tuple[Angle, Angle, Angle] = Field(
        (3.14159265, 0.0, 0.0), description="flange orientation to start at (with start_xyz) [rad]"
    )
    flange_geometry: bool = Field(
        True,
        description="put the ISO 9409-1 flange and the last link into the depth cameras' scene (they "
        "move with the robot; hand-eye calibration scans them)",
    )
    joint_offset_error: Angle = Field(
        0.0,
        ge=0,
        description="std of the arm's true joint zero offsets [rad]: the reported pose uses the nominal "
        "model, "
        "what the sensors see uses the true one (a real arm's absolute-accuracy error)",
    )


class SimCameraSettings(Settings):
    """A ray-cast depth camera with a real model's resolution, range and noise."""

    preset: CameraPresetName = Field("realsense-d415", description="camera model (docs/simulated-cell.md)")
    noise: bool = Field(True, description="apply the model's depth noise and dropouts")
    decimation: int = Field(1, ge=1, le=8, description="keep every n-th pixel row and column")
    mount_error: Length = Field(
        0.0,
        ge=0,
        description="the true mount differs from the profile's mount by this much (a hand-eye error) [m]",
    )
    mount_error_angle: Angle = Field(0.0, ge=0, description="rotation part of the mount error [rad]")
    stop_after: int | None = Field(
        None, ge=0, description="stop delivering frames after this many (fault tests)"
    )


class SimGestureSettings(Settings):
    """A Leap-like hand tracker playing a scripted hand."""

    script: str = Field(
        "survey", description="built-in script name ('survey', 'survey-sides', 'single') or a .json file"
    )
    rate: Frequency = Field(60.0, gt=0, description="frames per second of simulated time [Hz]")
    disconnect_after: int | None = Field(None, ge=0, description="drop the connection after this many frames")


class SimDisplacementSettings(Settings):
    """A 1-D laser displacement sensor (optoNCDT-like)."""

    min_range: Length = Field(0.03, gt=0, description="start of the measuring range [m]")
    max_range: Length = Field(0.30, gt=0, description="end of the measuring range [m]")
    noise: Length = Field(2e-6, ge=0, description="reading noise, 1 sigma [m]")


class SimImuSettings(Settings):
    """An IMU on a world frame."""

    accel_noise: float = Field(0.02, ge=0, description="accelerometer noise [m/s^2]")
    gyro_noise: float = Field(0.002, ge=0, description="gyroscope noise [rad/s]")


class SimGnssSettings(Settings):
    """A GNSS receiver on a world frame."""

    latitude: float = Field(22.5966, ge=-90, le=90, description="latitude of the world origin [deg]")
    longitude: float = Field(113.9976, ge=-180, le=180, description="longitude of the world origin [deg]")
    altitude: Length = Field(30.0, description="altitude of the world origin [m]")
    sigma: Length = Field(0.02, ge=0, description="position noise, 1 sigma [m]")
