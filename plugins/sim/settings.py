"""Settings of the simulated cell's devices."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator
from weldcell.hal.robot import RobotMotionSettings
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Duration, Frequency, Length

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
    color: bool = Field(
        False, description="also render a registered colour image (textured surfaces; RGB-D cameras)"
    )
    fps: Frequency = Field(30.0, gt=0, le=100, description="frame rate: simulated time per frame [Hz]")
    resolution: Literal["2K", "FHD", "HD", "VGA"] | None = Field(
        None,
        description="a ZED's video mode (preset zed2i only): its image size, focal length and the stereo "
        "noise of depth computed at that mode (docs/simulated-cell.md); none: the preset's native mode",
    )

    @model_validator(mode="after")
    def _resolution_needs_a_zed(self) -> SimCameraSettings:
        if self.resolution is not None and not self.preset.startswith("zed"):
            raise ValueError(
                f"resolution {self.resolution!r} is a ZED video mode but preset is {self.preset!r}: "
                "use preset = 'zed2i' or remove resolution"
            )
        return self


class SimGestureSettings(Settings):
    """A Leap-like hand tracker playing a scripted hand."""

    script: str = Field(
        "survey", description="built-in script name ('survey', 'survey-sides', 'single') or a .json file"
    )
    rate: Frequency = Field(60.0, gt=0, description="frames per second of simulated time [Hz]")
    disconnect_after: int | None = Field(None, ge=0, description="drop the connection after this many frames")


class SimDisplacementSettings(Settings):
    """A 1-D laser triangulation sensor with an optoNCDT 1402's characteristics (docs/simulated-cell.md)."""

    model: Literal["ild1402-100", "ild1402-200", "ild1402-600"] = Field(
        "ild1402-200", description="sensor model: measuring range, spot size and rate from its data sheet"
    )
    min_range: Length | None = Field(None, gt=0, description="start of measuring range [m]; default: model")
    max_range: Length | None = Field(None, gt=0, description="end of the measuring range [m]; default: model")
    noise: Length | None = Field(
        None, ge=0, description="distance noise on a flat matte surface, 1 sigma [m]; default 0.288 mm (§II)"
    )
    spot_diameter: Length | None = Field(None, gt=0, description="laser spot diameter [m]; default: model's")
    coupling: Length = Field(
        0.4e-3, ge=0, description="bound of the robot-sensor coupling error when carried by a robot [m] (§II)"
    )
    edge_dropout: float = Field(
        0.5, ge=0, le=1, description="probability that a spot straddling an edge gives no reading"
    )
    rate: Frequency = Field(1500.0, gt=0, description="measuring rate of the stream [Hz]")
    latency: Duration = Field(
        0.003, ge=0, description="how late the readings are stamped versus the robot's poses [s]"
    )
    stop_after: Duration | None = Field(
        None, ge=0, description="stop answering after this much simulated time (fault tests) [s]"
    )


class SimProjectorSettings(Settings):
    """A video laser projector (ShowWX+ class) as a pinhole inverse camera."""

    width: int = Field(848, gt=0, description="image width [px]")
    height: int = Field(480, gt=0, description="image height [px]")
    fx: float = Field(1000.0, gt=0, description="focal length [px]")
    fy: float = Field(1000.0, gt=0, description="focal length [px]")
    cx: float | None = Field(None, description="principal point x [px]; default: image centre")
    cy: float | None = Field(None, description="principal point y [px]; default: image centre")
    mount_error: Length = Field(
        0.0, ge=0, description="the true mount is off the profile's by this much (calibration finds it) [m]"
    )
    mount_error_angle: Angle = Field(0.0, ge=0, description="rotation part of the mount error [rad]")


class SimImuSettings(Settings):
    """A 9-axis IMU (BMI088/ICM-20948 class by default; see hal/sim/inertial.py for the model)."""

    rate: Frequency = Field(200.0, gt=0, le=2000, description="sample rate [Hz]")
    gyro_noise_density: float = Field(2.4e-4, ge=0, description="gyro white noise [rad/s/sqrt(Hz)]")
    accel_noise_density: float = Field(1.7e-3, ge=0, description="accelerometer white noise [m/s^2/sqrt(Hz)]")
    gyro_random_walk: float = Field(2.0e-5, ge=0, description="gyro bias random walk [rad/s^2/sqrt(Hz)]")
    accel_random_walk: float = Field(3.0e-4, ge=0, description="accel bias random walk [m/s^3/sqrt(Hz)]")
    gyro_turn_on_bias: float = Field(
        0.0, ge=0, description="1-sigma gyro bias at power-on [rad/s] (0: factory-compensated)"
    )
    accel_turn_on_bias: float = Field(
        0.0, ge=0, description="1-sigma accelerometer bias at power-on [m/s^2] (0: factory-compensated)"
    )
    hard_iron: float = Field(8.0, ge=0, description="1-sigma magnetometer hard-iron offset [uT]")
    soft_iron: float = Field(0.05, ge=0, description="1-sigma soft-iron matrix off-identity terms")
    steel_strength: float = Field(15.0, ge=0, description="field anomaly 1 m from steel [uT]")
    stop_after: float | None = Field(None, ge=0, description="fall silent after this simulated time [s]")


class SimGnssSettings(Settings):
    """A GNSS receiver (u-blox M8T standalone, or with RTK corrections); see hal/sim/gnss_model.py."""

    latitude: float = Field(22.5966, ge=-90, le=90, description="latitude of the world origin [deg]")
    longitude: float = Field(113.9976, ge=-180, le=180, description="longitude of the world origin [deg]")
    altitude: Length = Field(30.0, description="altitude of the world origin [m]")
    mode: Literal["rtk", "standalone"] = Field(
        "rtk", description="'standalone' (M8T alone: ~2 m wandering error) or 'rtk' (1-2 cm)"
    )
    rate: Frequency = Field(5.0, gt=0, le=20, description="solution rate [Hz]")
    sigma: Length = Field(2.1, gt=0, description="standalone horizontal 1-sigma per axis [m]")
    rtk_sigma: Length = Field(0.01, gt=0, description="RTK horizontal 1-sigma [m] (vertical: twice)")
