"""Laser scans and edge extraction (paper 002, §III-D)."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.plugins.localize.edges import EdgeSettings, extract_edges
from weldcell.plugins.localize.scan_io import LaserScan, read_laser_scan, write_laser_scan
from weldcell.plugins.localize.synth import SensorModel, scan_lines
from weldcell.plugins.localize.template import Member, Template
from weldcell.sdk.errors import DataError


def _plate_template():
    """Two 100 mm wide plates (50 and 30 mm tall) side by side with a 100 mm gap."""
    return Template(
        [
            Member("a", 0.05, [[0.0, 0.0], [0.1, 0.0], [0.1, 0.5], [0.0, 0.5]]),
            Member("b", 0.03, [[0.2, 0.0], [0.3, 0.0], [0.3, 0.5], [0.2, 0.5]]),
        ]
    )


def _lines(ys, x0=-0.05, x1=0.35):
    return [np.array([[x0, y], [x1, y]]) for y in ys]


def test_edges_at_the_drops_with_noise_shearing_and_dropouts():
    tpl = _plate_template()
    rng = np.random.default_rng(0)
    scan = scan_lines(tpl, _lines(np.linspace(0.05, 0.45, 9)), rng, SensorModel(coupling=0.0))
    e = extract_edges(scan, tpl)
    assert np.isnan(scan.xyz[:, 2]).any()  # dropouts at the edges are gaps ...
    assert np.nanmin(scan.xyz[:, 2]) > -0.01  # ... never zeros
    # every line crosses four drops: x = 0 (up to 50), 0.1 (down), 0.2 (up to 30), 0.3 (down)
    assert len(e) >= 32
    truth = np.array([0.0, 0.1, 0.2, 0.3])
    err = np.abs(e.xy[:, 0, None] - truth[None]).min(axis=1)
    assert err.max() < 0.5e-3  # inside the slot (<= 0.6 mm wide)
    assert np.all(e.gap <= e.max_gap)
    at = np.abs(e.xy[:, 0] - 0.1) < 1e-3
    assert np.all(e.sign[at] == -1) and np.allclose(e.top[at], 0.05) and np.allclose(e.bottom[at], 0.0)
    at = np.abs(e.xy[:, 0] - 0.2) < 1e-3
    assert np.all(e.sign[at] == 1) and np.allclose(e.top[at], 0.03)


def test_spikes_and_mixed_readings_make_no_edge():
    tpl = _plate_template()
    x = np.linspace(0.12, 0.18, 600)  # on the table between the plates
    z = np.zeros_like(x) + np.random.default_rng(1).normal(0, 0.288e-3, len(x))
    z[100] = 0.05  # a single-reading spike to a member's height
    z[300] = 0.02  # a mixed reading between levels
    z[400:405] = np.nan
    scan = LaserScan(
        np.arange(len(x)) / 1500, np.column_stack([x, np.full_like(x, 0.2), z]), np.zeros(len(x))
    )
    assert len(extract_edges(scan, tpl)) == 0


def test_slot_limit_and_coarse_sampling():
    tpl = _plate_template()
    rng = np.random.default_rng(2)
    # a 3 mm dropout hole at the edge: the slot is too wide, the edge is refused, not guessed
    scan = scan_lines(
        tpl, _lines([0.25], -0.05, 0.05), rng, SensorModel(coupling=0.0, noise=1e-5, dropout=0.0)
    )
    hole = np.abs(scan.xyz[:, 0]) < 1.5e-3
    scan.xyz[hole, 2] = np.nan
    e = extract_edges(scan, tpl)
    assert len(e) == 0 and e.n_refused == 1
    # sampled every 0.5 mm the paper's 0.6 mm cannot hold a drop: the limit follows the spacing
    coarse = scan_lines(tpl, _lines([0.25]), rng, SensorModel(coupling=0.0, rate=400.0))
    e = extract_edges(coarse, tpl)
    assert e.spacing == pytest.approx(0.5e-3, rel=0.01)
    assert e.max_gap == pytest.approx(2.5 * 0.5e-3, rel=0.01)
    assert len(e) == 4
    paper = extract_edges(coarse, tpl, EdgeSettings(gap_spacing_factor=1.0))
    assert paper.max_gap == pytest.approx(0.6e-3) and len(paper) < 4


def test_laser_scan_csv_round_trip_and_errors(tmp_path):
    tpl = _plate_template()
    scan = scan_lines(tpl, _lines([0.1, 0.2]), np.random.default_rng(3), SensorModel(speed=1.0))
    f = write_laser_scan(tmp_path / "scan.csv", scan)
    back = read_laser_scan(f)
    assert np.allclose(back.xyz, scan.xyz, atol=1e-7, equal_nan=True)
    assert np.array_equal(back.line, scan.line)
    text = f.read_text().splitlines()
    assert text[1] == "t,x,y,z,line"
    assert any(",," in row for row in text)  # out of range written empty, not zero
    (tmp_path / "bad.csv").write_text("t,x,y,line\n0,0,0,0\n")
    with pytest.raises(DataError, match="header"):
        read_laser_scan(tmp_path / "bad.csv")
    (tmp_path / "back.csv").write_text("t,x,y,z,line\n0,0,0,0.01,1\n0.1,0,0,0.01,0\n")
    with pytest.raises(DataError, match="line index decreases"):
        read_laser_scan(tmp_path / "back.csv")
    (tmp_path / "none.csv").write_text("t,x,y,z,line\n0,0,0,,0\n0.1,0,0,nan,0\n")
    with pytest.raises(DataError, match="every reading is out of range"):
        read_laser_scan(tmp_path / "none.csv")
    (tmp_path / "frac.csv").write_text("t,x,y,z,line\n0,0,0,0.1,0.5\n")
    with pytest.raises(DataError, match="line column"):
        read_laser_scan(tmp_path / "frac.csv")
