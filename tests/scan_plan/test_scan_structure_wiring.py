"""The scan's structure travels typed with the cloud (sdk ``PointCloud.structure``) from the denoiser to the
seam stage, which takes a line scan's spacing along its lines and its noise from it; area scans unchanged."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan.cloud_numerics import noise_level, sampling_spacings
from weldcell.plugins.scan_plan.scan_structure import scan_structure
from weldcell.plugins.scan_plan.seams import extract_seams
from weldcell.plugins.scan_plan.seams.pipeline import _sampling
from weldcell.plugins.scan_plan.stages import BilateralDenoiser, BilateralSettings
from weldcell.sdk.cloud import PointCloud, ScanStructure
from weldcell.sdk.errors import DataError
from weldcell.sdk.stages import denoised_scan

from .test_scan_structure import _pose, area_scan, line_scan

GAP = 0.006  # between the lidar's profiles on the surface (m)
SIGMA = 8e-4  # its range noise (m), along the ray: inside each profile's sheet


def _lidar(seed: int = 0) -> np.ndarray:
    """A 2-D lidar swept over a plate: profiles 6 mm apart, each a band of returns 0.5 mm apart with
    0.8 mm range noise inside the sheet (the real Aubo scans' kind, seams doc)."""
    rng = np.random.default_rng(seed)
    return _pose(line_scan(rng, GAP, 0.0005, SIGMA, tilt_deg=20.0, band=2), rng)


def test_the_stage_reads_a_line_scans_spacing_and_noise_from_its_structure():
    P = _lidar()
    tree = cKDTree(P)
    # measured within the cloud, the k-nearest estimates see one sheet: the band, not the next line
    fine, coarse = sampling_spacings(P, tree)
    assert coarse < 0.5 * GAP
    assert noise_level(P, max(3 * fine, 1.25 * coarse)) < 0.5 * SIGMA
    st = scan_structure(P)
    assert st.line_structured
    f2, c2, noise = _sampling(P, tree, st)
    assert f2 == min(fine, st.along_spacing) and c2 == coarse
    assert noise == pytest.approx(SIGMA, rel=0.25)  # across lines: the surface's noise
    assert st.line_spacing == pytest.approx(GAP, rel=0.1)
    # an area scan's structure changes nothing
    A = _pose(area_scan(np.random.default_rng(1), 0.0012, 2e-4), np.random.default_rng(2))
    sa = scan_structure(A)
    assert not sa.line_structured
    ta = cKDTree(A)
    assert _sampling(A, ta, sa) == (*sampling_spacings(A, ta), None)


def test_the_denoiser_measures_the_structure_before_its_voxel_grid_and_hands_it_on():
    cloud = PointCloud(_lidar(1), frame="base")
    out = denoised_scan(cloud, BilateralDenoiser(BilateralSettings())(cloud))
    st = out.structure
    assert isinstance(st, ScanStructure) and st.line_structured
    assert st.line_spacing == pytest.approx(GAP, rel=0.1)
    assert len(out) < len(cloud)  # the voxel grid thinned it; the structure is the captured scan's
    # a denoise stage that drops it: the pipeline carries the scan's structure over, as the viewpoints
    bare = PointCloud(out.points, frame="base")
    assert denoised_scan(out, bare).structure is st
    # crops, transforms and unit changes
    assert out.select(np.arange(100)).structure is st
    T = np.eye(4)
    T[:3, 3] = (1.0, 2.0, 3.0)
    assert out.transformed(T).structure is st
    mm = out.scaled(1000.0).structure
    assert mm.line_spacing == pytest.approx(1000.0 * st.line_spacing)
    assert mm.noise == pytest.approx(1000.0 * st.noise) and mm.line_share == st.line_share
    with pytest.raises(DataError):
        PointCloud(out.points, structure={"line_spacing": 0.006})  # type: ignore[arg-type]


def test_an_area_scans_seams_are_the_same_with_or_without_its_structure():
    rng = np.random.default_rng(3)
    g = np.arange(-0.025, 0.025, 0.002)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    z = np.abs(x)  # a 90 deg V: a concave crease along y
    P = np.column_stack([x, y, z]) + rng.normal(0.0, 5e-5, (len(x), 3))
    st = scan_structure(P)
    assert not st.line_structured
    a = extract_seams(P, up=(0.0, 0.0, 1.0))
    b = extract_seams(P, up=(0.0, 0.0, 1.0), structure=st)
    assert len(a.seams) == len(b.seams) >= 1
    for s, t in zip(a.seams, b.seams, strict=True):
        np.testing.assert_array_equal(s.points, t.points)
    assert a.params["spacing"] == b.params["spacing"]
