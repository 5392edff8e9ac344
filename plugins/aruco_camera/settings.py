"""Settings of the in-finger ArUco camera (no vendor import here)."""

from __future__ import annotations

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration


class IntrinsicsBlock(Settings):
    """Pinhole intrinsics (pixels) of the calibration resolution, OpenCV distortion order."""

    width: int = Field(..., gt=0, description="image width the calibration was made at [px]")
    height: int = Field(..., gt=0, description="image height the calibration was made at [px]")
    fx: float = Field(..., gt=0, description="focal length x [px]")
    fy: float = Field(..., gt=0, description="focal length y [px]")
    cx: float = Field(..., description="principal point x [px]")
    cy: float = Field(..., description="principal point y [px]")
    dist: tuple[float, ...] = Field((), description="distortion k1 k2 p1 p2 [k3 ...] (OpenCV order)")


class ArucoCameraSettings(Settings):
    """``tactile.aruco-camera``: the SRM finger's camera through ``cv2.VideoCapture``."""

    source: str = Field(
        "0",
        description="camera index ('0'), a video file, an image sequence pattern "
        "('frames/img_%02d.jpg') or a stream URL",
    )
    backend: str = Field(
        "any", description="VideoCapture API: any, v4l2, dshow, msmf, avfoundation, gstreamer, ffmpeg, images"
    )
    width: int | None = Field(None, gt=0, description="requested frame width [px] (live cameras)")
    height: int | None = Field(None, gt=0, description="requested frame height [px] (live cameras)")
    fps: float | None = Field(None, gt=0, description="requested frame rate [Hz] (live cameras)")
    intrinsics_file: str = Field(
        "",
        description="OpenCV calibration file (YAML/XML with camera_matrix, "
        "distortion_coefficients, image_width, image_height)",
    )
    intrinsics: IntrinsicsBlock | None = Field(
        None, description="intrinsics given inline (instead of a file)"
    )
    loop: bool = Field(False, description="files: start again at the first frame at the end")
    open_timeout: Duration = Field(5.0, gt=0, description="longest wait for the camera to open [s]")
