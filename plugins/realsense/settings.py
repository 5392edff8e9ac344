"""Settings of the RealSense adapter (no vendor import here)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration

Preset = Literal["default", "custom", "hand", "high_accuracy", "high_density", "medium_density"]


class RealSenseSettings(Settings):
    """An Intel RealSense depth camera (D400 family; the paper's D415) or a recording of one."""

    serial: str | None = Field(
        None, description="serial number of the camera to open; default: the only one connected"
    )
    recording: str | None = Field(
        None,
        description="play back this recording instead of a live camera: .bag (RealSense Viewer / "
        "librealsense < 2.56) or .db3 (librealsense >= 2.56); its streams and resolutions are used",
    )
    playback_repeat: bool = Field(False, description="loop the recording")
    playback_realtime: bool = Field(
        True,
        description="play the recording at its recorded pace (False: as fast as frames are read; "
        "librealsense's pipeline may still drop a frameset under CPU load)",
    )
    depth_width: int = Field(1280, gt=0, description="depth stream width [px] (D415: 1280x720 native)")
    depth_height: int = Field(720, gt=0, description="depth stream height [px]")
    depth_fps: int = Field(30, gt=0, description="depth stream rate [frames/s]")
    color: bool = Field(True, description="also stream colour (RGB8)")
    color_width: int = Field(1280, gt=0, description="colour stream width [px]")
    color_height: int = Field(720, gt=0, description="colour stream height [px]")
    color_fps: int = Field(30, gt=0, description="colour stream rate [frames/s]")
    align_to_color: bool = Field(
        False,
        description="reproject depth into the colour camera (needs color); "
        "readings are then in the colour optical frame",
    )
    preset: Preset | None = Field(None, description="D400 visual preset (high_accuracy suits scanning parts)")
    laser_power: float | None = Field(None, ge=0, description="projector power [mW] (D415: 0..360)")
    emitter_enabled: bool | None = Field(None, description="turn the IR projector on/off")
    decimation: int = Field(1, ge=1, le=8, description="decimation filter magnitude (1 = off)")
    spatial_filter: bool = Field(False, description="edge-preserving spatial filter (in disparity space)")
    temporal_filter: bool = Field(False, description="temporal filter (in disparity space)")
    warmup_frames: int = Field(
        15, ge=0, description="frames dropped after start on a live camera (auto-exposure)"
    )
    start_timeout: Duration = Field(5.0, gt=0, description="time allowed for the first frame after start [s]")
