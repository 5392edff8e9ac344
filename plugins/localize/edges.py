"""Edge extraction from laser scan lines (paper 002, §III-D).

Along each scan line (readings in acquisition order):

1. **Stage 1, heights.** The step kernel (-1, 1) on z between consecutive valid readings gives the height
   differential; each reading is classified by the CAD heights used as thresholds: it belongs to a surface
   level (the table or a member top) when it lies within ``level_fraction`` of the smallest CAD step from
   it, else it is unknown (sheared, mixed or clutter). Levels held for fewer than ``min_run`` consecutive
   readings are spikes and become unknown too. Out-of-range readings (NaN z) are gaps, never zeros.
2. **Stage 2, drops.** The same kernel on the level sequence of the known readings of a line: a non-zero
   response is a drop between the last reading on one level (top or bottom) and the first on the other.
   Its stage-1 height change must match the CAD step (sign and size within the tolerance).
3. **Slot.** The top and bottom readings of the drop bound a slot in which the true edge lies (shearing
   makes the edge itself unreadable); a slot wider than the maximum XY gap is refused; the edge point is
   the mean XY of the slot's two ends.

The maximum gap is the paper's 0.6 mm, widened where the scan's own sampling cannot reach it: a clean
drop spans one along-line sample plus the sensor's spot, so the gap used is
``max(max_gap, spot_size + gap_spacing_factor * median along-line spacing)`` (see
docs/methods/localization.md). Everything is vectorised over all readings at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field
from weldcell.sdk.errors import DataError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length

from .scan_io import LaserScan
from .template import Template


class EdgeSettings(Settings):
    """Edge extraction (§III-D)."""

    max_gap: Length = Field(0.6e-3, description="maximum XY width of a slot (paper: 0.6 mm)")
    spot_size: Length = Field(0.0, description="laser spot diameter on the part (widens the slot)")
    gap_spacing_factor: float = Field(
        2.5, gt=0, description="slot may span this many along-line samples when they are coarser than max_gap"
    )
    level_fraction: float = Field(
        0.35,
        gt=0,
        lt=0.5,
        description="a reading is on a CAD level within this fraction of the smallest step",
    )
    min_run: int = Field(2, ge=1, description="readings a level must hold on each side of a drop")


@dataclass
class EdgePoints:
    """Edge points in the base frame: ``xy`` (M, 2) m; ``line`` (M,) scan-line index; ``top`` (M,) z of the
    upper level and ``bottom`` (M,) z of the lower level of the drop; ``sign`` (M,) -1 where the line goes
    down the drop, +1 where it goes up; ``gap`` (M,) slot width (m). ``max_gap`` is the limit used,
    ``spacing`` the median along-line sample spacing, ``n_readings`` the readings examined."""

    xy: np.ndarray
    line: np.ndarray
    top: np.ndarray
    bottom: np.ndarray
    sign: np.ndarray
    gap: np.ndarray
    max_gap: float = 0.0
    spacing: float = 0.0
    n_readings: int = 0
    n_refused: int = 0

    def __len__(self) -> int:
        return len(self.xy)

    def subset(self, keep: np.ndarray) -> EdgePoints:
        return EdgePoints(
            self.xy[keep],
            self.line[keep],
            self.top[keep],
            self.bottom[keep],
            self.sign[keep],
            self.gap[keep],
            self.max_gap,
            self.spacing,
            self.n_readings,
            self.n_refused,
        )


def along_line_spacing(scan: LaserScan) -> float:
    """Median XY distance between consecutive readings of the same line (m)."""
    same = scan.line[1:] == scan.line[:-1]
    d = np.linalg.norm(np.diff(scan.xyz[:, :2], axis=0), axis=1)[same]
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 0.0


def extract_edges(scan: LaserScan, template: Template, settings: EdgeSettings | None = None) -> EdgePoints:
    """Edge points of ``scan`` with ``template``'s heights as thresholds (see the module docstring)."""
    s = settings or EdgeSettings()
    levels = template.levels()
    if len(levels) < 2:
        raise DataError("the template has no member above the table", "give members a top height")
    step = float(np.diff(levels).min())
    tol = s.level_fraction * step
    z = scan.xyz[:, 2]
    idx = np.flatnonzero(np.isfinite(z))
    spacing = along_line_spacing(scan)
    max_gap = max(s.max_gap, s.spot_size + s.gap_spacing_factor * spacing)
    empty = EdgePoints(
        np.zeros((0, 2)),
        np.zeros(0, int),
        np.zeros(0),
        np.zeros(0),
        np.zeros(0, int),
        np.zeros(0),
        max_gap,
        spacing,
        len(scan),
        0,
    )
    if len(idx) < 2:
        return empty
    # stage 1: heights -> CAD levels (unknown when between levels)
    zi = z[idx]
    lev = np.clip(np.searchsorted(levels, zi), 1, len(levels) - 1)
    lev = np.where(np.abs(zi - levels[lev - 1]) <= np.abs(zi - levels[lev]), lev - 1, lev)
    known = np.abs(zi - levels[lev]) <= tol
    ki, kl = idx[known], lev[known]
    # spikes: runs of one level on one line shorter than min_run become unknown
    for _ in range(2):
        if len(ki) < 2:
            return empty
        kline = scan.line[ki]
        brk = (kl[1:] != kl[:-1]) | (kline[1:] != kline[:-1])
        run = np.concatenate([[0], np.cumsum(brk)])
        keep = np.bincount(run)[run] >= s.min_run
        ki, kl = ki[keep], kl[keep]
    if len(ki) < 2:
        return empty
    kline = scan.line[ki]
    # stage 2: (-1, 1) on the level sequence -> drops between consecutive known readings of a line
    dl = np.diff(kl)
    t = (dl != 0) & (kline[1:] == kline[:-1])
    a, b = ki[:-1][t], ki[1:][t]
    la, lb = kl[:-1][t], kl[1:][t]
    dz = z[b] - z[a]  # the stage-1 differential summed over the slot
    expect = levels[lb] - levels[la]
    consistent = np.abs(dz - expect) <= 2 * tol
    xy = scan.xyz[:, :2]
    gap = np.linalg.norm(xy[b] - xy[a], axis=1)
    ok = consistent & (gap <= max_gap)
    a, b, la, lb, gap = a[ok], b[ok], la[ok], lb[ok], gap[ok]
    return EdgePoints(
        xy=0.5 * (xy[a] + xy[b]),
        line=scan.line[a],
        top=levels[np.maximum(la, lb)],
        bottom=levels[np.minimum(la, lb)],
        sign=np.where(lb < la, -1, 1),
        gap=gap,
        max_gap=max_gap,
        spacing=spacing,
        n_readings=len(scan),
        n_refused=int((~ok).sum()),
    )
