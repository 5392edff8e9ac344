"""The SRM in-finger camera through ``cv2.VideoCapture``: BGR frames with their intrinsics.

Reads run on a single worker thread so a camera that stops delivering (unplugged, stalled stream) gives a
:class:`DeviceError` after ``timeout`` instead of blocking the caller; the device then enters ERROR and
``recover()`` releases and reopens the capture.
"""

from __future__ import annotations

import concurrent.futures as cf
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
from weldcell.hal.interfaces import TactileCamera
from weldcell.hal.readings import Image, Intrinsics
from weldcell.sdk.errors import DataError, DeviceError

from .intrinsics_io import read_opencv_intrinsics, scaled
from .settings import ArucoCameraSettings

BACKENDS = {
    "any": "CAP_ANY",
    "v4l2": "CAP_V4L2",
    "dshow": "CAP_DSHOW",
    "msmf": "CAP_MSMF",
    "avfoundation": "CAP_AVFOUNDATION",
    "gstreamer": "CAP_GSTREAMER",
    "ffmpeg": "CAP_FFMPEG",
    "images": "CAP_IMAGES",
}


def open_capture(settings: ArucoCameraSettings) -> Any:
    """A ``cv2.VideoCapture`` for the settings' source (index, file, image pattern or URL)."""
    if settings.backend not in BACKENDS:
        raise DeviceError(
            f"unknown VideoCapture backend {settings.backend!r}", f"use one of {', '.join(BACKENDS)}"
        )
    api = getattr(cv2, BACKENDS[settings.backend], cv2.CAP_ANY)
    src: int | str = int(settings.source) if settings.source.strip().isdigit() else settings.source
    cap = cv2.VideoCapture(src, api)
    if isinstance(src, int):
        if settings.width:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, settings.width)
        if settings.height:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, settings.height)
        if settings.fps:
            cap.set(cv2.CAP_PROP_FPS, settings.fps)
    return cap


class ArucoCamera(TactileCamera):
    """The finger camera: ``capture()`` returns the next BGR frame (OpenCV order) with its intrinsics."""

    def __init__(
        self,
        settings: ArucoCameraSettings,
        name: str = "finger-camera",
        frame: str | None = None,
        capture_factory: Callable[[ArucoCameraSettings], Any] = open_capture,
    ) -> None:
        super().__init__(name, frame)
        self.settings = settings
        self._factory = capture_factory
        self._cap: Any = None
        self._pool: cf.ThreadPoolExecutor | None = None
        self._calib: Intrinsics | None = None
        self._intr: Intrinsics | None = None
        self.frames_read = 0

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        s = self.settings
        try:
            if s.intrinsics_file:
                self._calib = read_opencv_intrinsics(s.intrinsics_file)
            elif s.intrinsics is not None:
                b = s.intrinsics
                self._calib = Intrinsics(b.width, b.height, b.fx, b.fy, b.cx, b.cy, tuple(b.dist))
        except DataError as e:
            raise DeviceError(f"camera intrinsics: {e.message}", e.fix) from e
        self._pool = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"{self.name}-read")
        fut = self._pool.submit(self._factory, s)
        try:
            self._cap = fut.result(timeout=s.open_timeout)
        except cf.TimeoutError:
            raise DeviceError(
                f"camera {s.source!r} did not open within {s.open_timeout:.1f} s",
                "check the index / URL; is another program holding the camera?",
            ) from None
        if not self._cap.isOpened():
            raise DeviceError(
                f"cannot open camera source {s.source!r}",
                "check the index, file path, pattern (e.g. img_%02d.jpg) or stream URL",
            )
        w = int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH) or 0)
        h = int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT) or 0)
        self._intr = (
            scaled(self._calib, w, h) if (self._calib is not None and w > 0 and h > 0) else self._calib
        )

    def on_close(self) -> None:
        cap, pool = self._cap, self._pool
        self._cap = self._pool = None
        if cap is not None:
            try:
                cap.release()
            except Exception:
                pass
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    # -- readings --------------------------------------------------------------------------------
    def _read(self) -> tuple[bool, Any]:
        ok, img = self._cap.read()
        if not ok and self.settings.loop and self.frames_read > 0:
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, img = self._cap.read()
        return ok, img

    def _capture(self, timeout: float) -> Image:
        fut = self._pool.submit(self._read)
        try:
            ok, img = fut.result(timeout=timeout)
        except cf.TimeoutError:
            raise self.fault(f"no frame from {self.settings.source!r} within {timeout:.2f} s") from None
        except Exception as e:
            raise self.fault(f"reading {self.settings.source!r} failed: {e}") from e
        if not ok or img is None:
            raise self.fault(f"camera {self.settings.source!r} delivered no frame (unplugged / end)")
        img = np.ascontiguousarray(img)
        self.frames_read += 1
        k = self._intr
        if k is not None and (k.width, k.height) != (img.shape[1], img.shape[0]) and self._calib is not None:
            k = self._intr = scaled(self._calib, img.shape[1], img.shape[0])
        return Image(stamp=time.time(), image=img, intrinsics=k, frame=self.frame)

    def intrinsics(self) -> Intrinsics | None:
        """Intrinsics at the delivered resolution (None when none were configured)."""
        return self._intr


def probe_camera(settings: ArucoCameraSettings) -> str:
    """Open the source, read one frame, release it."""
    cap = open_capture(settings)
    try:
        if not cap.isOpened():
            raise DeviceError(f"cannot open camera source {settings.source!r}", "check the index/path/URL")
        ok, img = cap.read()
        if not ok or img is None:
            raise DeviceError(f"camera {settings.source!r} opened but delivered no frame", "check the camera")
        return f"camera {settings.source!r}: {img.shape[1]}x{img.shape[0]}"
    finally:
        cap.release()
