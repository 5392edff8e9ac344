"""Settings of the ZED 2i adapter (no vendor import: profiles validate without pyzed or a camera)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration, Length


class ZedSettings(Settings):
    """A Stereolabs ZED 2i (also ZED 2 / ZED / ZED Mini) as an RGB-D camera.

    ``backend = "sdk"`` uses the ZED SDK (pyzed: live camera or SVO playback, the SDK's depth);
    ``"uvc"`` reads the camera's standard UVC side-by-side stream with OpenCV, rectifies it with the
    factory calibration file and computes depth with StereoSGBM; ``"auto"`` picks the SDK when installed.
    """

    backend: Literal["auto", "sdk", "uvc"] = Field("auto", description="SDK, UVC + OpenCV, or auto")
    device: int | str = Field(
        0, description="UVC: video device index, /dev/videoN, or a side-by-side video file; SDK: camera id"
    )
    serial: int | None = Field(
        None, description="camera serial number (finds SN<serial>.conf; SDK: opens it)"
    )
    calibration_file: str | None = Field(
        None,
        description="factory calibration SN<serial>.conf (UVC backend); default: ZED SDK settings folder",
    )
    svo_file: str | None = Field(None, description="SDK backend: play back this SVO recording")
    resolution: Literal["2K", "FHD", "HD", "VGA"] = Field("HD", description="per-eye resolution")
    fps: int = Field(15, gt=0, le=100, description="frame rate [Hz]")
    min_depth: Length = Field(0.3, gt=0, description="nearest depth kept [m] (ZED 2i: 0.3 m)")
    max_depth: Length = Field(20.0, gt=0, description="farthest depth kept [m] (ZED 2i: 20 m)")
    block_size: int = Field(5, ge=1, le=15, description="UVC: SGBM block size [px] (odd)")
    uniqueness: int = Field(10, ge=0, le=50, description="UVC: SGBM uniqueness ratio [%]")
    sdk_depth_mode: Literal["PERFORMANCE", "QUALITY", "ULTRA", "NEURAL"] = Field(
        "NEURAL", description="SDK depth mode"
    )
    loop: bool = Field(False, description="UVC file source / SVO: start again at the end")
    timeout: Duration = Field(2.0, gt=0, description="a frame not delivered within this is a fault [s]")
