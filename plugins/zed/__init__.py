"""Stereolabs ZED 2i as an RGB-D camera (device ``camera.zed``). Registration only: no vendor import here.

Backends: the ZED SDK (pyzed, import-gated) or, without it, the UVC side-by-side stream + the factory
calibration file + OpenCV StereoSGBM (extra ``vision``).
"""

from __future__ import annotations

import importlib.util

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.hookspecs import hookimpl

NAME = "camera.zed"


def sdk_available() -> bool:
    """True when the ZED SDK's Python API (pyzed) is installed."""
    try:
        return importlib.util.find_spec("pyzed") is not None
    except (ImportError, ValueError):
        return False


def _factory(settings, ctx):
    backend = settings.backend
    if backend == "auto":
        backend = "sdk" if sdk_available() else "uvc"
    if backend == "sdk":
        if not sdk_available():
            raise DeviceError(
                "backend 'sdk' needs the ZED SDK's Python API (pyzed), which is not installed",
                "install the ZED SDK and its get_python_api.py, or set backend = 'uvc'",
            )
        from weldcell.plugins.zed.adapter_sdk import ZedSdkCamera

        return ZedSdkCamera(settings, name=ctx.role)
    from weldcell.plugins.zed.adapter_uvc import ZedUvcCamera

    return ZedUvcCamera(settings, name=ctx.role)


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.zed.settings import ZedSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="depth_camera",
            summary="Stereolabs ZED 2i RGB-D: ZED SDK (pyzed) or UVC side-by-side + OpenCV stereo",
            settings=ZedSettings,
            factory=_factory,
            requires={"cv2": "vision"},
        )
    )
