"""ZED through the ZED SDK's Python API (pyzed): live camera or SVO playback, the SDK's own depth.

Import-gated: this module imports ``pyzed.sl`` and is loaded only when the SDK is installed (it is not on
the CI machine; see docs/devices/zed.md for what was and was not tested).
"""

from __future__ import annotations

import time

import numpy as np
import pyzed.sl as sl
from weldcell.hal.interfaces import DepthCamera
from weldcell.hal.readings import DepthFrame, Intrinsics
from weldcell.plugins.zed.settings import ZedSettings
from weldcell.sdk.errors import DeviceError

_RES = {"2K": "HD2K", "FHD": "HD1080", "HD": "HD720", "VGA": "VGA"}


class ZedSdkCamera(DepthCamera):
    """A ZED through the ZED SDK (device ``camera.zed``, backend ``sdk``)."""

    def __init__(self, settings: ZedSettings | None = None, name: str = "camera") -> None:
        super().__init__(name, frame=name)
        self.settings = settings or ZedSettings(backend="sdk")
        self._zed = None
        self._intr: Intrinsics | None = None

    def _intrinsics(self) -> Intrinsics:
        if self._intr is None:
            raise DeviceError(f"camera '{self.name}' is not configured", "configure() first")
        return self._intr

    def on_configure(self) -> None:
        s = self.settings
        init = sl.InitParameters()
        init.camera_resolution = getattr(sl.RESOLUTION, _RES[s.resolution])
        init.camera_fps = s.fps
        init.depth_mode = getattr(sl.DEPTH_MODE, s.sdk_depth_mode)
        init.coordinate_units = sl.UNIT.METER
        init.depth_minimum_distance = s.min_depth
        init.depth_maximum_distance = s.max_depth
        if s.svo_file:
            init.set_from_svo_file(str(s.svo_file))
        elif s.serial is not None:
            init.set_from_serial_number(int(s.serial))
        zed = sl.Camera()
        err = zed.open(init)
        if err != sl.ERROR_CODE.SUCCESS:
            raise DeviceError(
                f"ZED SDK could not open {'SVO ' + s.svo_file if s.svo_file else 'the camera'}: {err}",
                "check the USB 3 connection (or the SVO path) and run ZED_Diagnostic",
            )
        info = zed.get_camera_information().camera_configuration
        c = info.calibration_parameters.left_cam
        self._intr = Intrinsics(
            int(info.resolution.width), int(info.resolution.height), c.fx, c.fy, c.cx, c.cy
        )
        self._zed = zed
        self._image, self._depth, self._rt = sl.Mat(), sl.Mat(), sl.RuntimeParameters()

    def on_close(self) -> None:
        zed, self._zed = self._zed, None
        if zed is not None:
            zed.close()

    def _capture(self, timeout: float) -> DepthFrame:
        zed = self._zed
        if zed is None:
            raise self.fault("the ZED is closed")
        err = zed.grab(self._rt)
        if err == sl.ERROR_CODE.END_OF_SVOFILE_REACHED and self.settings.loop:
            zed.set_svo_position(0)
            err = zed.grab(self._rt)
        if err != sl.ERROR_CODE.SUCCESS:
            raise self.fault(f"ZED grab failed: {err}")
        zed.retrieve_image(self._image, sl.VIEW.LEFT)
        zed.retrieve_measure(self._depth, sl.MEASURE.DEPTH)
        bgra = self._image.get_data()
        depth = np.array(self._depth.get_data(), dtype=np.float32)
        depth[~np.isfinite(depth)] = 0.0
        ts = zed.get_timestamp(sl.TIME_REFERENCE.IMAGE).get_nanoseconds() * 1e-9
        return DepthFrame(
            stamp=ts if ts > 0 else time.time(),
            depth=depth,
            intrinsics=self._intr,
            frame=self.frame,
            color=np.ascontiguousarray(bgra[:, :, 2::-1]),
            meta={"backend": "sdk", "svo": self.settings.svo_file},
        )
