"""The simulated cell's devices, registered exactly like real adapters (``robot.sim``, ``camera.sim``...)."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.hookspecs import hookimpl

#: (name, kind, summary, settings class in .settings, factory in .factories), one row per device
DEVICES = (
    (
        "robot.sim",
        "robot",
        "kinematic robot model (UR5, UR10e, Panda, AUBO i5, IRB 2600) in the simulated cell",
        "SimRobotSettings",
        "robot",
    ),
    (
        "camera.sim",
        "depth_camera",
        "ray-cast depth camera with a real model's noise (D415, D435, PhoXi S/M, Azure Kinect, ZED 2i)",
        "SimCameraSettings",
        "camera",
    ),
    ("gesture.sim", "gesture_sensor", "scripted hands (Leap-like)", "SimGestureSettings", "gesture"),
    (
        "displacement.sim",
        "displacement_sensor",
        "ray-cast 1-D laser triangulation sensor (optoNCDT 1402: range, spot, edges, 1.5 kHz)",
        "SimDisplacementSettings",
        "displacement",
    ),
    (
        "projector.sim",
        "laser_projector",
        "pinhole projector on a world or flange frame; its light ray-cast onto the scene",
        "SimProjectorSettings",
        "projector",
    ),
    ("imu.sim", "imu", "IMU on a frame of the simulated world", "SimImuSettings", "imu"),
    ("gnss.sim", "gnss", "GNSS receiver on a frame of the simulated world", "SimGnssSettings", "gnss"),
)


@hookimpl
def weldcell_register_devices(register) -> None:
    from weldcell.plugins.sim import factories as f
    from weldcell.plugins.sim import settings as s

    for name, kind, summary, settings, factory in DEVICES:
        register(
            DeviceSpec(
                name=name,
                kind=kind,
                summary=summary,
                settings=getattr(s, settings),
                factory=getattr(f, factory),
                simulated=True,
                probe=f.probe,
            )
        )


@hookimpl
def weldcell_check_profile(profile):
    from weldcell.plugins.sim.factories import check_sim_section

    return check_sim_section(profile)
