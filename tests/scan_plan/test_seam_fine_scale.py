"""A joint whose faces are narrower than the side fits' radius: the thin outside corner's notch
(seams/scales.py, issue 16)."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.plugins.scan_plan.seams import extract_seams, scales


def _thin_corner(thickness: float, spacing: float = 0.001, noise: float = 5e-5, seed: int = 0):
    """Points (a jittered grid of ``spacing``: after the voxel grid ~0.8 of it between neighbours, like the
    evaluation set's denoised area scans) and outward normals of a thin outside corner (two plates of
    ``thickness`` meeting at 90 deg, their edge faces forming a notch) seen from above: the notch opens
    to +z, its bottom runs along x at the origin (approach -z), 120 mm long; the outer faces run 25 mm
    down."""
    rng = np.random.default_rng(seed)
    c = np.sqrt(0.5)
    top = thickness * c  # the notch walls' outer ends, at +-top in y and +top in z
    # the profile in (y, z): left outer face, left wall, right wall, right outer face
    segs = [
        ((-top - 0.025 * c, top - 0.025 * c), (-top, top)),
        ((-top, top), (0.0, 0.0)),
        ((0.0, 0.0), (top, top)),
        ((top, top), (top + 0.025 * c, top - 0.025 * c)),
    ]
    P, N = [], []
    for (y0, z0), (y1, z1) in segs:
        d = np.hypot(y1 - y0, z1 - z0)
        grid = np.meshgrid(np.arange(0.5, d / spacing) * spacing / d, np.arange(-0.06, 0.06, spacing))
        s, x = (g.ravel() for g in grid)  # a grid of ``spacing``, jittered by 0.2 of it
        n = len(s)
        s, x = s + rng.uniform(-0.2, 0.2, n) * spacing / d, x + rng.uniform(-0.2, 0.2, n) * spacing
        nrm = np.array([0.0, -(z1 - z0), y1 - y0]) / d
        nrm = nrm if nrm[2] > 0 else -nrm  # facing the sensor above
        Q = np.column_stack([x, y0 + s * (y1 - y0), z0 + s * (z1 - z0)])
        P.append(Q + noise * rng.normal(size=(n, 3)))
        N.append(np.tile(nrm, (n, 1)))
    return np.vstack(P), np.vstack(N)


def test_thin_corner_notch_is_found_at_the_fine_radius(monkeypatch: pytest.MonkeyPatch):
    P, N = _thin_corner(0.0025)
    res = extract_seams(P, N, min_seam_length=0.02)
    assert len(res.seams) == 1
    s = res.seams[0]
    off = np.hypot(s.points[:, 1], s.points[:, 2])  # from the notch bottom (the x axis)
    assert np.sqrt(np.mean(off**2)) < 0.6e-3
    assert s.length > 0.09
    assert np.degrees(np.arccos(-np.median(s.approach[:, 2]))) < 8.0
    # the stage's own scale (the 6 mm side fits) sees the roof the outer faces form: no seam
    monkeypatch.setattr(scales, "FINE_GAIN", 0.0)
    assert extract_seams(P, N, min_seam_length=0.02).seams == []


def test_a_thick_corner_is_read_at_the_stage_scale_only(monkeypatch: pytest.MonkeyPatch):
    """A notch as wide as the side fits see is found by the stage's own scale; the fine reading never runs."""
    calls = []
    monkeypatch.setattr(scales, "fine_candidates", lambda *a, **k: calls.append(1))
    P, N = _thin_corner(0.008)
    res = extract_seams(P, N, min_seam_length=0.02)
    assert len(res.seams) == 1 and not calls


def test_fine_radius_follows_the_spacing_and_noisy_clouds_are_not_read_finer():
    assert scales.fine_radius(0.001, 0.0012, 1.25) == pytest.approx(0.002)  # 2 spacings
    assert scales.fine_radius(0.0014, 0.006, 1.25) == pytest.approx(0.0075)  # across scan lines
    assert scales.resolvable(0.002, 1e-5)  # structured light: noise 1/200 of the radius
    assert not scales.resolvable(0.0019, 1.5e-4)  # RGB-D: noise 1/12 of it


def test_a_noise_bound_cloud_keeps_no_seam(monkeypatch: pytest.MonkeyPatch):
    """A thin corner whose noise is 1/8 of the fine radius (like the RGB-D clouds): the stage's scale finds
    nothing and the fine reading is not run -- no seam rather than a guess."""
    asked = []
    resolvable = scales.resolvable
    monkeypatch.setattr(scales, "resolvable", lambda r, n: asked.append(resolvable(r, n)) or asked[-1])
    P, N = _thin_corner(0.0025, spacing=0.0013, noise=2.5e-4)
    assert extract_seams(P, N, min_seam_length=0.02).seams == []
    assert asked == [False]
