"""Settings of the mapping job and its stages (paper 004 §II-A to §II-C)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.plugins.mapping.prior_map import PriorMapRef
from weldcell.plugins.mapping.segmentation import SegmentationSettings
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Length, Speed


class FrontEndSettings(Settings):
    """ORB + matching + RANSAC PnP."""

    n_features: int = Field(
        2000, ge=50, le=10000, description="ORB features per image (2000: see docs/methods/mapping.md)"
    )
    fast_threshold: int = Field(12, ge=1, le=100, description="ORB FAST threshold")
    ratio: float = Field(0.8, gt=0, le=1, description="Lowe's ratio test")
    min_inliers: int = Field(20, ge=6, description="PnP inliers needed to accept a pose")
    reprojection_px: float = Field(2.5, gt=0, description="RANSAC reprojection threshold [px]")
    ransac_iterations: int = Field(200, ge=10, description="RANSAC iterations")
    max_depth: Length = Field(12.0, gt=0, description="ignore depth beyond this (stereo noise ~ z^2) [m]")
    depth_noise: float = Field(
        1.5e-3,
        gt=0,
        description="stereo depth noise sigma_z = depth_noise * z^2 [1/m] (the camera's model; ZED 2i "
        "HD720: 0.08 px subpixel / (448 px * 0.12 m baseline))",
    )
    incidence_noise: bool = Field(
        True,
        description="grow each feature's depth sigma by 1/cos of its incidence angle (surface normal from "
        "the depth image), as stereo noise grows; off: the head-on depth_noise * z^2 for every feature",
    )
    depth_fit: bool = Field(
        True,
        description="a key frame's point on a surface that is planar within the noise takes the depth of "
        "the plane fitted to the 7 x 7 depth samples around it (ML for independent pixel noise, as the "
        "simulated ZED; turn off for a depth map filtered across pixels)",
    )


class EstimatorSettings(Settings):
    """Visual-inertial(-GNSS) key-frame smoother (gtsam)."""

    keyframe_distance: Length = Field(
        0.2, gt=0, description="new key frame after this translation [m] (paper)"
    )
    keyframe_angle: Angle = Field(0.05, gt=0, description="... or this rotation [rad] (paper)")
    keyframe_max_interval: float = Field(
        2.0, gt=0, description="... or this time [s] (keeps IMU factors short when standing)"
    )
    window: float = Field(6.0, gt=0, description="fixed-lag smoother window [s of key frames]")
    use_imu: bool = Field(True, description="IMU preintegration factors (off: visual-only ablation)")
    use_gnss: bool = Field(True, description="GNSS position factors when a fix exists")
    use_vision: bool = Field(True, description="visual PnP factors (off: IMU-only ablation)")
    links: int = Field(
        3, ge=1, le=8, description="PnP factors from a new key frame to this many previous ones"
    )
    interpolation: Literal["slerp", "linear"] = Field(
        "slerp", description="camera poses between IMU poses (eq. 2): SO(3) slerp or the paper's linear"
    )
    init_time: float = Field(1.5, gt=0, description="standstill at the start for gravity/bias init [s]")
    pnp_sigma_t: Length = Field(0.005, gt=0, description="floor of the PnP factor translation sigma [m]")
    pnp_sigma_r: Angle = Field(0.002, gt=0, description="floor of the PnP factor rotation sigma [rad]")
    gnss_min_spread: Length = Field(8.0, gt=0, description="travel before GNSS is aligned to the world [m]")
    gnss_correlation_time: float = Field(
        60.0,
        gt=0,
        description="correlation time of the GNSS error [s] (M8T standalone: wandering bias, ~60 s; "
        "RTK fixed: ~1 s): fixes within it share one fix's information",
    )
    lost_after: int = Field(3, ge=1, description="frames without a visual pose before 'tracking lost'")
    loop_closure: bool = Field(True, description="match key frames against marginalised ones near them")
    loop_radius: Length = Field(3.0, gt=0, description="search radius for loop closures (> drift) [m]")
    global_optimization: bool = Field(
        True, description="batch optimisation of every key frame (with the loops) at the end of the drive"
    )


class MapSettings(Settings):
    """Global map (eq. 3 back-projection of key frames)."""

    voxel: Length = Field(0.05, gt=0, description="voxel size of the global coloured map [m]")
    max_depth: Length = Field(8.0, gt=0, description="depth used for the map [m]")
    pixel_step: int = Field(2, ge=1, le=16, description="use every n-th pixel row/column of a key frame")
    tsdf: bool = Field(
        True, description="dense TSDF (Open3D UniformTSDFVolume over each region's box) of the weld regions"
    )
    tsdf_voxel: Length = Field(0.01, gt=0, description="TSDF voxel size [m]")
    region_margin: Length = Field(0.3, ge=0, description="TSDF box margin around a weld region [m]")


class RouteDriveSettings(Settings):
    """How the simulated base drives (ignored on hardware, where an operator drives)."""

    length: Length = Field(100.0, gt=1, description="route length [m] (the issue: 50-150 m)")
    cruise_speed: Speed = Field(1.2, gt=0, le=5, description="speed between work areas [m/s]")
    work_speed: Speed = Field(0.3, gt=0, le=5, description="speed near weld regions [m/s]")
    standstill: float = Field(2.0, ge=1.0, description="standing still at both ends [s]")


class ImuNoiseSettings(Settings):
    """The IMU's noise densities as the estimator assumes them (from its datasheet; defaults: BMI088)."""

    gyro_noise_density: float = Field(2.4e-4, gt=0, description="[rad/s/sqrt(Hz)]")
    accel_noise_density: float = Field(1.7e-3, gt=0, description="[m/s^2/sqrt(Hz)]")
    gyro_random_walk: float = Field(2.0e-5, gt=0, description="[rad/s^2/sqrt(Hz)]")
    accel_random_walk: float = Field(3.0e-4, gt=0, description="[m/s^3/sqrt(Hz)]")
    inflate: float = Field(2.0, ge=1, description="factor on every sigma (unmodelled effects)")


class RevisitSettings(Settings):
    """The second visit (simulation): the robot comes back, drives a second route over the mapped part of
    the site from another start, relocalizes against the first visit's map and updates it (§II-E)."""

    enabled: bool = Field(False, description="drive a second visit after the map is made (simulation)")
    length: Length = Field(10.0, gt=1, description="second route's length [m]")
    start_waypoint: int = Field(1, ge=0, description="the second route starts at this waypoint of the loop")
    change_scene: bool = Field(True, description="add a box and remove a column before the visit")
    yaw_sigma: Angle = Field(0.1745, gt=0, description="1-sigma of the magnetometer heading prior [rad]")
    position_sigma: Length = Field(2.0, gt=0, description="1-sigma of the GNSS position prior [m]")
    use_gnss: bool = Field(True, description="GNSS position prior when both visits aligned GNSS")
    use_magnetometer: bool = Field(True, description="magnetometer heading prior")
    change_distance: Length = Field(
        0.15, gt=0, description="a point this far from the other map has changed [m]"
    )
    min_change_points: int = Field(30, ge=1, description="smallest cluster of changed map points reported")
    change_max_depth: Length = Field(
        5.0, gt=0, description="free-space evidence only from depth up to this range (noise ~ z^2) [m]"
    )
    min_views: int = Field(3, ge=1, description="key frames that must see through a point to call it changed")
    prior_map: PriorMapRef = Field(
        None,
        description="hardware: this run is the second visit; relocalize on and update this prior map: a "
        "map folder (RUN/map of an earlier run, or RUN; relative to the profile) or a map server "
        "tcp://HOST:PORT; checked at load (a relative folder: when the job starts, before driving)",
    )


class MapJobSettings(Settings):
    """The ``map`` job: drive, estimate the trajectory, build the map, find the weld regions."""

    route: RouteDriveSettings = Field(
        default_factory=RouteDriveSettings, description="the simulated route: length, speeds, seed"
    )
    frontend: FrontEndSettings = Field(
        default_factory=FrontEndSettings, description="visual front end: ORB features, matching, RANSAC PnP"
    )
    estimator: EstimatorSettings = Field(
        default_factory=EstimatorSettings,
        description="back end: key-frame thresholds, smoother window, GNSS use, interpolation",
    )
    imu_noise: ImuNoiseSettings = Field(
        default_factory=ImuNoiseSettings,
        description="IMU noise densities and bias random walks the estimator assumes",
    )
    map: MapSettings = Field(
        default_factory=MapSettings,
        description="global map: voxel size, depth range, TSDF of the weld regions",
    )
    detect_every: int = Field(1, ge=1, description="run the detector on every n-th key frame")
    decisions: str | None = Field(
        None, description="operator decisions file (JSON: confirm/reject/add regions); see docs/jobs/map.md"
    )
    max_frames: int | None = Field(None, ge=1, description="stop after this many camera frames")
    imu_wait: float = Field(1.0, gt=0, description="longest wait for IMU data covering a frame [s]")
    segmentation: SegmentationSettings = Field(
        default_factory=SegmentationSettings,
        description="local maps while driving (§II-D): distance / point thresholds, ORB + NDT hand-over",
    )
    serve_map: bool = Field(True, description="serve the local maps while driving and fetch them on loopback")
    revisit: RevisitSettings = Field(
        default_factory=RevisitSettings, description="second visit: relocalize and update the map (§II-E)"
    )
