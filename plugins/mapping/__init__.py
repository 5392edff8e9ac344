"""Cell 4, map (paper 004 §II-A to §II-C): visual-inertial-GNSS pose estimation of a mobile welding
robot on key frames, 3-D reconstruction (voxel map + TSDF of the weld regions), weld-region detection
with a pluggable detector, and the ``map`` job."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceRole, JobSpec, StageRole, StageSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell.plugins.mapping import regions

    register(
        StageSpec(
            name="detector.sim",
            kind="detector",
            summary="simulated weld-region detector: ground truth projected, with misses and false alarms",
            settings=regions.SimDetectorSettings,
            factory=regions.SimDetector,
        )
    )


@hookimpl
def weldcell_register_jobs(register) -> None:
    from weldcell.plugins.mapping import job, settings

    register(
        JobSpec(
            name="map",
            kind="job",
            summary="drive the mobile robot, estimate its trajectory (VIO + GNSS), "
            "build the map, find weld regions",
            settings=settings.MapJobSettings,
            run=job.run,
            devices=(
                DeviceRole("camera", "depth_camera", "the RGB-D camera on the mobile base (colour + depth)"),
                DeviceRole("imu", "imu", "the IMU on the mobile base"),
                DeviceRole("gnss", "gnss", "the GNSS receiver (optional)", optional=True),
            ),
            stages=(
                StageRole("detector", "detector", "detector.sim", "find weld regions in key frames"),
                StageRole(
                    "transfer", "map-transfer", "map-transfer.zmq", "write, serve and fetch the local maps"
                ),
                StageRole(
                    "relocalizer", "relocalizer", "relocalize.ndt", "relocalize a second visit on the map"
                ),
            ),
        )
    )
