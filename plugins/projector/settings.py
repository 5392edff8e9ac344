"""Settings of the window projector adapter (no vendor import: profiles validate without pygame)."""

from __future__ import annotations

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length


class WindowProjectorSettings(Settings):
    """A video laser projector (Microvision ShowWX+ class) driven as a fullscreen display output.

    The projector is a pinhole "inverse camera": intrinsics (from its calibration) and its mount
    (the profile's ``mount``: on the world, or on ``<robot role>.flange``).
    """

    display: int = Field(0, ge=0, description="display output index (pygame/SDL display number)")
    fullscreen: bool = Field(True, description="borderless fullscreen on that display")
    width: int = Field(848, gt=0, description="projector resolution, width [px] (ShowWX+: 848)")
    height: int = Field(480, gt=0, description="projector resolution, height [px] (ShowWX+: 480)")
    fx: float = Field(1000.0, gt=0, description="focal length [px] (from the projector calibration)")
    fy: float = Field(1000.0, gt=0, description="focal length [px]")
    cx: float | None = Field(None, description="principal point x [px]; default: image centre")
    cy: float | None = Field(None, description="principal point y [px]; default: image centre")
    dist: tuple[float, ...] = Field(
        (), description="distortion, OpenCV order (k1, k2, p1, p2[, k3...]); empty: none"
    )
    color: tuple[int, int, int] = Field((0, 255, 0), description="line colour (R, G, B), 0..255")
    line_width: int = Field(2, ge=1, le=50, description="line width [px]")
    near: Length = Field(0.05, gt=0, description="near clipping distance in front of the lens [m]")
