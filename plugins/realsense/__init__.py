"""Intel RealSense depth cameras through pyrealsense2 (device ``camera.realsense``). Registration only."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import DeviceError, MissingExtraError
from weldcell.sdk.hookspecs import hookimpl

NAME = "camera.realsense"


def _rs():
    try:
        import pyrealsense2 as rs
    except ImportError:
        raise MissingExtraError(f"device '{NAME}'", "pyrealsense2", "realsense") from None
    return rs


def _factory(settings, ctx):
    _rs()
    from weldcell.plugins.realsense.adapter import RealSenseCamera

    return RealSenseCamera(settings, name=ctx.role)


def probe(settings) -> str:
    """List the connected cameras, or the recorded camera and streams of a recording; DeviceError when the
    asked camera is absent or the recording cannot be read."""
    from pathlib import Path

    rs = _rs()
    from weldcell.plugins.realsense.adapter import connected_cameras, describe_recording

    if settings.recording:
        return describe_recording(Path(settings.recording))
    cams = connected_cameras(rs.context())
    if not cams:
        raise DeviceError("no RealSense camera is connected", "plug the camera into a USB 3 port")
    if settings.serial and settings.serial not in cams:
        raise DeviceError(
            f"no RealSense with serial {settings.serial}; connected: {', '.join(cams)}",
            "set serial to one of the connected cameras",
        )
    return ", ".join(f"{name} #{serial}" for serial, name in cams.items())


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.realsense.settings import RealSenseSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="depth_camera",
            summary="Intel RealSense D400 depth camera (pyrealsense2)",
            settings=RealSenseSettings,
            factory=_factory,
            probe=probe,
            requires={"pyrealsense2": "realsense"},
        )
    )
