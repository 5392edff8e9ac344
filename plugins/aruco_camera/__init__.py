"""The SRM soft finger's in-finger ArUco camera (``tactile.aruco-camera``) through OpenCV."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec, import_adapter
from weldcell.sdk.hookspecs import hookimpl


def _adapter():
    return import_adapter(f"{__name__}.adapter", {"cv2": "vision"}, "device 'tactile.aruco-camera'")


def _factory(settings, ctx):
    name = getattr(ctx, "role", "finger-camera") if ctx is not None else "finger-camera"
    return _adapter().ArucoCamera(settings, name=name)


def _probe(settings) -> str:
    return _adapter().probe_camera(settings)


@hookimpl
def weldcell_register_devices(register):
    from .settings import ArucoCameraSettings

    register(
        DeviceSpec(
            name="tactile.aruco-camera",
            kind="tactile_camera",
            summary="SRM in-finger camera watching the ArUco tag (OpenCV VideoCapture)",
            settings=ArucoCameraSettings,
            factory=_factory,
            requires={"cv2": "vision"},
            probe=_probe,
        )
    )
