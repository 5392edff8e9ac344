"""Scan structure from the cloud alone: line scans (planar slices) and area scans, tilted at random."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from weldcell.plugins.scan_plan.cloud_numerics import noise_level
from weldcell.plugins.scan_plan.scan_structure import ScanStructure, scan_structure
from weldcell.sdk.errors import DataError

SIZE = 0.09  # patch side (m)


def _surface(x: np.ndarray, y: np.ndarray, curved: bool) -> np.ndarray:
    """Height of the scanned surface: a plane, or a cylinder of radius 0.15 m (axis along y)."""
    return (x**2) / (2 * 0.15) if curved else np.zeros_like(x)


def _pose(P: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``P`` turned at random and moved to metre-level coordinates (nothing is z up)."""
    return P @ Rotation.random(random_state=rng).as_matrix().T + rng.uniform(-1.0, 1.0, 3)


def line_scan(rng, gap, along, sigma, tilt_deg=0.0, band=0.0, curved=False) -> np.ndarray:
    """A profiler swept along y: one profile every ``gap`` (m) along the surface, in a sheet tilted
    ``tilt_deg`` from the surface normal about x, points every ``along`` (m) along it; the noise
    (``sigma`` along the surface normal) is along the ray, inside the sheet, so each profile stays
    exactly planar. ``band`` > 0 adds that many repeated points per position (a 2-D lidar's band:
    several returns per angle)."""
    t = np.deg2rad(tilt_deg)
    ray = np.array([0.0, np.sin(t), np.cos(t)])  # in the sheet, towards the surface
    pts = []
    for y0 in np.arange(-SIZE / 2, SIZE / 2, gap) + rng.uniform(0, gap):
        x = np.arange(-SIZE / 2, SIZE / 2, along) + rng.uniform(0, along)
        for _ in range(max(1, int(band))):
            xs = x + rng.uniform(-along / 2, along / 2, len(x)) * (band > 0)
            # where the ray through (xs, y0, 0) meets the surface (small slope: one fixed-point step)
            z = _surface(xs, np.full_like(xs, y0), curved)
            P = np.column_stack([xs, y0 + z * np.tan(t), z])
            pts.append(P + np.outer(rng.normal(0.0, sigma, len(xs)) / np.cos(t), ray))
    return np.vstack(pts)


def area_scan(rng, spacing, sigma, curved=False) -> np.ndarray:
    """A jittered grid at ``spacing`` on the surface, noise ``sigma`` along z."""
    g = np.arange(-SIZE / 2, SIZE / 2, spacing)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    x = x + rng.uniform(-0.3, 0.3, len(x)) * spacing
    y = y + rng.uniform(-0.3, 0.3, len(y)) * spacing
    return np.column_stack([x, y, _surface(x, y, curved) + rng.normal(0.0, sigma, len(x))])


@pytest.mark.parametrize(
    "seed, gap, along, sigma, tilt, curved",
    [
        (0, 0.005, 0.001, 3e-4, 0.0, False),  # the evaluation set's profiler
        (1, 0.007, 0.0008, 3e-4, 25.0, True),
        (2, 0.0045, 0.0005, 1e-4, 40.0, False),
        (3, 0.006, 0.001, 5e-5, 10.0, False),  # a precise profiler: lines nearly straight
    ],
)
def test_line_scan_spacings_and_noise(seed, gap, along, sigma, tilt, curved):
    rng = np.random.default_rng(seed)
    P = _pose(line_scan(rng, gap, along, sigma, tilt, curved=curved), rng)
    st = scan_structure(P)
    assert isinstance(st, ScanStructure)
    assert st.line_structured and st.line_share > 0.5
    # the sheets are tilt degrees off the surface normal: gap apart on the surface, gap cos(tilt) apart
    assert st.sheet_gap == pytest.approx(gap * np.cos(np.deg2rad(tilt)), rel=0.02)
    assert st.line_spacing == pytest.approx(gap, rel=0.06)
    assert 0.6 * along <= st.along_spacing <= 1.6 * along
    assert st.noise == pytest.approx(sigma, rel=0.2)
    assert st.sheet_thickness < 0.05 * sigma
    # a neighbourhood of span_radius reaches the next line on both sides, and holds what the density says
    assert st.line_spacing * 1.2 <= st.span_radius <= st.line_spacing * 2.0
    expect = np.pi * st.span_radius**2 / (along * st.line_spacing)
    assert 0.6 * expect <= st.span_neighbours <= 1.6 * expect
    assert st.anisotropy > 2.5


def test_lidar_band_where_nearest_neighbours_see_the_laser_sheet():
    """The real scans' case: points 0.3 mm apart in a 2-D band as wide as the noise (0.8 mm), profiles
    4.6 mm apart. Today's k-NN noise estimate reads the sheet's flatness; the structure reads the surface."""
    rng = np.random.default_rng(7)
    P = _pose(line_scan(rng, 0.0046, 0.0009, 8e-4, tilt_deg=20.0, band=3), rng)
    st = scan_structure(P)
    assert st.line_structured
    assert st.sheet_gap == pytest.approx(0.0046 * np.cos(np.deg2rad(20.0)), rel=0.02)
    assert st.line_spacing == pytest.approx(0.0046, rel=0.06)
    assert st.noise == pytest.approx(8e-4, rel=0.2)
    assert noise_level(P, 3.0 * st.spacing) < 0.1 * st.noise  # the failure this module exists for


@pytest.mark.parametrize(
    "seed, spacing, sigma, curved",
    [(0, 0.001, 3e-4, False), (1, 0.0015, 8e-4, True), (2, 0.0007, 5e-5, False), (3, 0.002, 1e-5, True)],
)
def test_area_scan_is_not_line_structured(seed, spacing, sigma, curved):
    rng = np.random.default_rng(seed)
    P = _pose(area_scan(rng, spacing, sigma, curved), rng)
    st = scan_structure(P)
    assert not st.line_structured and st.line_share < 0.04
    assert st.along_spacing == st.line_spacing == st.sheet_gap == st.spacing
    assert 0.5 * spacing <= st.spacing <= 1.1 * spacing
    assert st.mean_spacing == pytest.approx(st.spacing, rel=0.25)
    today = noise_level(P, 3.0 * st.spacing)
    assert 0.9 <= st.noise / today <= 1.3  # today's estimate, bias-corrected (k / (k - 3))
    if sigma >= 5e-5:  # (a noise-free cylinder's residual is its curvature)
        assert st.noise == pytest.approx(sigma, rel=0.2)


def test_step_between_parallel_faces_is_not_a_slice():
    """A lap joint's two parallel plates: the lower plate sees the upper one at a clean offset, on one
    side only -- not a stack of slices."""
    rng = np.random.default_rng(4)
    low = area_scan(rng, 0.001, 2e-4)
    high = area_scan(rng, 0.001, 2e-4)
    P = np.vstack([low[low[:, 0] < 0.01], high[high[:, 0] > 0] + (0, 0, 0.006)])
    assert not scan_structure(_pose(P, rng)).line_structured


def test_seeded_and_reuses_a_tree():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(5)
    P = _pose(line_scan(rng, 0.005, 0.001, 3e-4), rng)
    a, b = scan_structure(P, seed=3), scan_structure(P, tree=cKDTree(P), seed=3)
    assert a == b
    assert "line scan" in a.summary()


def test_bad_clouds_get_one_clear_error():
    with pytest.raises(DataError):
        scan_structure(np.zeros((100, 3)))
    P = np.random.default_rng(0).normal(size=(100, 3))
    P[3, 1] = np.nan
    with pytest.raises(DataError):
        scan_structure(P)
    with pytest.raises(DataError):
        scan_structure(np.ones((5, 3)))
    with pytest.raises(DataError):
        scan_structure(np.random.default_rng(1).normal(size=(100, 3)), sample=0)
