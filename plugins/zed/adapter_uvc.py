"""ZED without the SDK: the camera's UVC side-by-side stream through OpenCV, rectified with the factory
calibration file, depth from StereoSGBM (:mod:`.stereo`). Gives RGB-D with nothing but OpenCV."""

from __future__ import annotations

import concurrent.futures as cf
import logging
import time
from pathlib import Path

import cv2
import numpy as np
from weldcell.hal.interfaces import DepthCamera
from weldcell.hal.readings import DepthFrame, Intrinsics
from weldcell.plugins.zed.calibration import RESOLUTIONS, Rectification, load_conf, rectify
from weldcell.plugins.zed.settings import ZedSettings
from weldcell.plugins.zed.stereo import StereoDepth
from weldcell.sdk.errors import DataError, DeviceError

log = logging.getLogger("weldcell.zed")

SDK_SETTINGS = Path("/usr/local/zed/settings")


def calibration_path(s: ZedSettings) -> Path:
    """The factory calibration file the settings point to (explicit file, or the SDK's folder by serial)."""
    if s.calibration_file:
        return Path(s.calibration_file).expanduser()
    if s.serial is None:
        raise DeviceError(
            "the UVC backend needs the camera's factory calibration",
            "set calibration_file (SN<serial>.conf from https://calib.stereolabs.com/?SN=<serial>) or serial",
        )
    return SDK_SETTINGS / f"SN{s.serial}.conf"


class ZedUvcCamera(DepthCamera):
    """A ZED as a UVC side-by-side camera (device ``camera.zed``, backend ``uvc``)."""

    def __init__(self, settings: ZedSettings | None = None, name: str = "camera") -> None:
        super().__init__(name, frame=name)
        self.settings = settings or ZedSettings(backend="uvc")
        self._cap: cv2.VideoCapture | None = None
        self._rect: Rectification | None = None
        self._stereo: StereoDepth | None = None
        self._pool: cf.ThreadPoolExecutor | None = None
        self.frames = 0

    def _intrinsics(self) -> Intrinsics:
        if self._rect is None:
            raise DeviceError(f"camera '{self.name}' is not configured", "configure() first")
        return self._rect.intrinsics

    def on_configure(self) -> None:
        s = self.settings
        try:
            cal = load_conf(calibration_path(s), s.resolution)
        except DataError as e:
            raise DeviceError(e.message, e.fix) from e
        w, h = RESOLUTIONS[s.resolution]
        self._rect = rectify(cal)
        self._stereo = StereoDepth(
            self._rect.fx_baseline, s.min_depth, s.max_depth, s.block_size, s.uniqueness
        )
        dev = s.device
        if isinstance(dev, str) and dev.isdigit():
            dev = int(dev)
        cap = cv2.VideoCapture(dev, cv2.CAP_V4L2) if isinstance(dev, int) else cv2.VideoCapture(str(dev))
        if not cap.isOpened():
            raise DeviceError(
                f"cannot open the ZED's video source {s.device!r}",
                "plug the camera in (USB 3), check /dev/video* and its permissions, or the file path",
            )
        if isinstance(dev, int) or str(dev).startswith("/dev/"):
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, 2 * w)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, h)
            cap.set(cv2.CAP_PROP_FPS, s.fps)
        fw, fh = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if (fw, fh) != (2 * w, h):
            cap.release()
            raise DeviceError(
                f"the ZED source delivers {fw}x{fh}, not the side-by-side {2 * w}x{h} "
                f"of resolution {s.resolution}",
                "set resolution to the stream's (2K 4416x1242, FHD 3840x1080, HD 2560x720, VGA 1344x376)",
            )
        self._cap = cap
        self._pool = cf.ThreadPoolExecutor(1, thread_name_prefix=f"zed-{self.name}")

    def on_close(self) -> None:
        cap, pool = self._cap, self._pool
        self._cap = self._pool = None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)
        if cap is not None:
            cap.release()

    def _read(self) -> np.ndarray:
        cap = self._cap
        ok, img = cap.read()
        if not ok and self.settings.loop and cap.get(cv2.CAP_PROP_FRAME_COUNT) > 0:
            cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, img = cap.read()
        if not ok or img is None:
            raise RuntimeError("no frame")
        return img

    def _capture(self, timeout: float) -> DepthFrame:
        if self._cap is None or self._pool is None:
            raise self.fault("the ZED video source is closed")
        try:
            img = self._pool.submit(self._read).result(timeout=min(timeout, self.settings.timeout))
        except (cf.TimeoutError, RuntimeError) as e:
            raise self.fault(
                f"no frame from the ZED source {self.settings.device!r} ({e or 'timeout'})"
            ) from e
        stamp = time.time()
        return self.process(img, stamp)

    def process(self, sbs_bgr: np.ndarray, stamp: float) -> DepthFrame:
        """Rectify a side-by-side BGR frame and compute depth: an RGB-D frame in the rectified left camera."""
        r = self._rect
        w = sbs_bgr.shape[1] // 2
        left = cv2.remap(sbs_bgr[:, :w], *r.maps_left, cv2.INTER_LINEAR)
        right = cv2.remap(sbs_bgr[:, w:], *r.maps_right, cv2.INTER_LINEAR)
        gl = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
        gr = cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
        depth = self._stereo.depth(gl, gr)
        self.frames += 1
        return DepthFrame(
            stamp=stamp,
            depth=depth,
            intrinsics=r.intrinsics,
            frame=self.frame,
            color=cv2.cvtColor(left, cv2.COLOR_BGR2RGB),
            meta={"backend": "uvc", "frame_index": self.frames - 1, "fx_baseline": r.fx_baseline},
        )
