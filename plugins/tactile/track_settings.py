"""Settings of the tactile jobs: the SRM finger's calibration, the vision step and the tracking run."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Duration, Frequency, Length, Speed

Vec3 = tuple[Length, Length, Length]


class SRMToolSettings(Settings):
    """The SRM finger's calibration as the job uses it: tag, camera-in-tool and tag-to-tip gains."""

    marker_size: Length = Field(0.010, gt=0, description="side of the tag's black square [m]")
    marker_id: int = Field(0, ge=0, description="ArUco id of the tag")
    dictionary: str = Field("DICT_4X4_50", description="ArUco dictionary of the tag")
    tag_gain: float = Field(
        0.85, gt=0, description="calibrated tag translation per metre of lateral tip deflection"
    )
    tag_axial_gain: float = Field(
        0.6, gt=0, description="calibrated tag translation per metre of axial deflection"
    )
    camera_rpy: tuple[Angle, Angle, Angle] = Field(
        (0.0, 0.0, 0.0), description="in-finger camera orientation in the tool frame [rad] (default: aligned)"
    )
    filter: Literal["one-euro", "none"] = Field("one-euro", description="smoothing of the tag displacement")
    min_cutoff: float = Field(3.0, gt=0, description="One-Euro cut-off at rest [Hz]")
    beta: float = Field(200.0, ge=0, description="One-Euro speed coefficient [s/m]")
    max_reprojection_error: float = Field(
        1.5, gt=0, description="tag poses re-projecting worse are lost [px]"
    )
    rest_frames: int = Field(5, ge=1, description="contact-free frames averaged for the tag's rest pose")


class ScanSettings(Settings):
    """The vision step: one scan of the fixed depth camera, seams in the robot base frame."""

    roi_min: Vec3 = Field(
        (-1.0, -1.0, -0.05), description="keep scan points above this corner, base frame [m]"
    )
    roi_max: Vec3 = Field((1.0, 1.0, 1.0), description="keep scan points below this corner, base frame [m]")
    park_xyz: Vec3 | None = Field(
        None,
        description="flange position to park at before scanning (out of the "
        "camera's view), base frame [m]; default: stay",
    )
    park_rpy: tuple[Angle, Angle, Angle] = Field(
        (3.14159265, 0.0, 0.0), description="flange orientation when parked [rad]"
    )
    min_points: int = Field(2000, ge=10, description="fewer valid points in the ROI is an error")
    wall_band: Length = Field(0.02, gt=0, description="how far beside a seam to look for its wall [m]")
    wall_rise: Length = Field(0.004, gt=0, description="points this far above the seam count as its wall [m]")
    min_wall_points: int = Field(30, ge=1, description="a seam with fewer wall points is not trackable")


class TrackSettings(Settings):
    """How the SRM tool is brought to the seam and driven along it."""

    plan_file: str | None = Field(
        None,
        description="weld-path@1 file with the planned seam (relative to the "
        "profile); default: the run's own vision step",
    )
    seam_id: str | None = Field(None, description="seam of the plan file to track; default: the first")
    rate: Frequency = Field(50.0, gt=0, description="in-finger camera rate = control rate [Hz]")
    command_duration: Duration | None = Field(
        None, gt=0, description="duration of each velocity command [s]; default 1/rate"
    )
    max_time: Duration | None = Field(
        None,
        gt=0,
        description="longest tracking time [s]; default from the plan's length and the servo speed",
    )
    tip_height: Length = Field(
        0.0035, gt=0, description="height of the tip centre (TCP) above the seam line [m]"
    )
    start_inset: Length = Field(
        0.005, ge=0, description="start this far along the plan from its first point [m]"
    )
    approach_clearance: Length = Field(
        0.004,
        ge=0,
        description="start this far from the planned seam, on the "
        "free side (the servo then seeks the wall) [m]",
    )
    approach_height: Length = Field(
        0.03,
        gt=0,
        description="come down to the start from this high [m]; the tag's rest pose is captured there",
    )
    approach_speed: Speed = Field(0.05, gt=0, description="speed of the approach and retract moves [m/s]")
    retract: Length = Field(0.03, ge=0, description="lift the tool this much after the stop [m]")
    srm: SRMToolSettings = Field(default_factory=SRMToolSettings, description="the SRM finger's calibration")
    fail_on_safe_stop: bool = Field(
        True,
        description="a safe stop (safety gate, lost marker, overload) fails "
        "the run after writing what was recorded",
    )
    plots: bool = Field(True, description="write the figures")


class TactileTrackSettings(TrackSettings):
    """Settings of the ``tactile-track`` job."""

    scan: ScanSettings = Field(
        default_factory=ScanSettings, description="the vision step (without plan_file)"
    )
