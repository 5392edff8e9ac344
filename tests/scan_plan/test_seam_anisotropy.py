"""The seam stage tells a line-by-line scan from an area scan after the denoiser's voxel grid.

A swept laser line profiler's cloud needs normals over more neighbours (its lines lie 2-6 x farther
apart than its points along a line); an area scan must keep the 10-point normals: read as a line scan,
Table II's tilted V-groove lost 0.3 deg of rotation accuracy (0.67 -> 0.95 deg).
"""

from __future__ import annotations

import pytest
from weldcell.plugins.scan_plan.cloud_numerics import sampling_spacings
from weldcell.plugins.scan_plan.seams.pipeline import ANISOTROPIC
from weldcell.plugins.scan_plan.stages import BilateralDenoiser, BilateralSettings
from weldcell.sdk.cloud import PointCloud
from weldcell.testing.seam_cases import make_case


def _ratio(index: int) -> tuple[str, float]:
    case = make_case(index, 0)
    cloud = PointCloud(case.points, frame="base", viewpoints=case.viewpoints)
    clean = BilateralDenoiser(BilateralSettings())(cloud)
    fine, coarse = sampling_spacings(clean.points)
    return case.scanner, coarse / fine


@pytest.mark.parametrize(
    ("index", "scanner", "line_scan"),
    [
        (0, "rgbd", False),  # the RGB-D cloud with the largest ratio among cases 0-65 (1.71)
        (30, "line-laser", True),  # the line scan with the smallest ratio of the set (2.05)
    ],
)
def test_only_a_line_scan_reads_as_anisotropic(index: int, scanner: str, line_scan: bool) -> None:
    got_scanner, ratio = _ratio(index)
    assert got_scanner == scanner
    assert (ratio > ANISOTROPIC) is line_scan, f"coarse / fine spacing {ratio:.2f} vs {ANISOTROPIC}"
