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
    """List the connected cameras (or check the recording); DeviceError when the asked one is absent."""
    from pathlib import Path

    if settings.recording:
        if not Path(settings.recording).is_file():
            raise DeviceError(
                f"recording {settings.recording} does not exist", "give the path of a .bag/.db3 file"
            )
        return f"recording {settings.recording}"
    from weldcell.plugins.realsense.adapter import connected_cameras

    cams = connected_cameras(_rs().context())
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
