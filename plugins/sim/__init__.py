"""The simulated cell's devices, registered exactly like real adapters (``robot.sim``, ``camera.sim``...)."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_devices(register) -> None:
    from weldcell.plugins.sim import factories as f
    from weldcell.plugins.sim import settings as s

    register(
        DeviceSpec(
            name="robot.sim",
            kind="robot",
            summary="kinematic robot model (UR5, UR10e, Panda, AUBO i5, IRB 2600) in the simulated cell",
            settings=s.SimRobotSettings,
            factory=f.robot,
            simulated=True,
            probe=f.probe,
        )
    )
    register(
        DeviceSpec(
            name="camera.sim",
            kind="depth_camera",
            summary="ray-cast depth camera with a real model's "
            "noise (D415, D435, PhoXi S/M, Azure Kinect, ZED 2i)",
            settings=s.SimCameraSettings,
            factory=f.camera,
            simulated=True,
            probe=f.probe,
        )
    )
    register(
        DeviceSpec(
            name="gesture.sim",
            kind="gesture_sensor",
            summary="scripted hands (Leap-like)",
            settings=s.SimGestureSettings,
            factory=f.gesture,
            simulated=True,
            probe=f.probe,
        )
    )
    register(
        DeviceSpec(
            name="displacement.sim",
            kind="displacement_sensor",
            summary="ray-cast 1-D laser triangulation sensor (optoNCDT 1402: range, spot, edges, 1.5 kHz)",
            settings=s.SimDisplacementSettings,
            factory=f.displacement,
            simulated=True,
            probe=f.probe,
        )
    )
    register(
        DeviceSpec(
            name="projector.sim",
            kind="laser_projector",
            summary="pinhole projector on a world or flange frame; its light ray-cast onto the scene",
            settings=s.SimProjectorSettings,
            factory=f.projector,
            simulated=True,
            probe=f.probe,
        )
    )
    register(
        DeviceSpec(
            name="imu.sim",
            kind="imu",
            summary="IMU on a frame of the simulated world",
            settings=s.SimImuSettings,
            factory=f.imu,
            simulated=True,
            probe=f.probe,
        )
    )
    register(
        DeviceSpec(
            name="gnss.sim",
            kind="gnss",
            summary="GNSS receiver on a frame of the simulated world",
            settings=s.SimGnssSettings,
            factory=f.gnss,
            simulated=True,
            probe=f.probe,
        )
    )


@hookimpl
def weldcell_check_profile(profile):
    from weldcell.plugins.sim.factories import check_sim_section

    return check_sim_section(profile)
