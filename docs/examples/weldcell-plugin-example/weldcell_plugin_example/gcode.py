"""``export.gcode-like``: a ``weldcell/weld-path@1`` document as G-code-like text.

Positions in millimetres, feed in mm/min, torch orientation as A/B/C = roll/pitch/yaw in degrees
(the torch frame of the weld path: z toward the work, x along travel). ``M3``/``M5`` switch the arc.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from weldcell.sdk.geometry import T_to_rpy
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length, Speed
from weldcell.sdk.weldpath import WeldPath


class GcodeSettings(Settings):
    """Settings of the G-code-like exporter."""

    feed: Speed = Field(0.008, gt=0, description="welding travel speed [m/s] (written as mm/min)")
    retract: Length = Field(0.03, ge=0, description="approach/retract distance along -z of the torch [m]")
    decimals: int = Field(3, ge=0, le=6, description="decimals of the numbers written")


def _move(code: str, T: np.ndarray, decimals: int, feed: float | None = None) -> str:
    x, y, z = T[:3, 3] * 1000.0
    a, b, c = T_to_rpy(T, degrees=True)
    f = f" F{feed * 60000.0:.0f}" if feed is not None else ""
    return f"{code} X{x:.{decimals}f} Y{y:.{decimals}f} Z{z:.{decimals}f} A{a:.2f} B{b:.2f} C{c:.2f}{f}"


def to_gcode(data: dict, settings: GcodeSettings | None = None) -> str:
    """One block per seam: rapid to the retract pose, approach, arc on, weld, arc off, retract."""
    s = settings or GcodeSettings()
    path = WeldPath.from_json(data)  # validates the document (DataError with a fix when malformed)
    lines = [f"( weldcell weld path: {len(path.seams)} seam(s), frame {path.frame} )", "G21 G90"]
    for seam in path.seams:
        if len(seam.poses) == 0:
            continue
        first, last = seam.poses[0].copy(), seam.poses[-1].copy()
        first[:3, 3] -= s.retract * first[:3, 2]
        last[:3, 3] -= s.retract * last[:3, 2]
        lines += [
            f"( seam {seam.id} {seam.joint} {seam.length * 1000:.1f} mm )",
            _move("G0", first, s.decimals),
            _move("G1", seam.poses[0], s.decimals, s.feed),
            "M3",
        ]
        lines += [_move("G1", T, s.decimals, s.feed) for T in seam.poses[1:]]
        lines += ["M5", _move("G0", last, s.decimals)]
    lines.append("M2")
    return "\n".join(lines) + "\n"
