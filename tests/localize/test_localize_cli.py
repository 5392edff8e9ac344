"""The offline commands `weldcell template CAD -o T.json` and `weldcell localize TEMPLATE SCAN -o R.json`."""

from __future__ import annotations

import json
import math

import ezdxf
import numpy as np
import pytest
from click.testing import CliRunner
from weldcell.plugins.localize.pose import transform_template
from weldcell.plugins.localize.scan_io import write_laser_scan
from weldcell.plugins.localize.synth import SensorModel, scan_lines, zigzag_plan
from weldcell.plugins.localize.template import load_template
from weldcell.sdk.cli import main


@pytest.fixture(scope="module")
def ladder_dxf(tmp_path_factory):
    """A ladder frame in millimetres: rails and rungs as closed polylines on layers named with their tops."""
    f = tmp_path_factory.mktemp("cad") / "ladder.dxf"
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4
    msp = doc.modelspace()
    for name, y in (("rail-a_top50", 0), ("rail-b_top50", 450)):
        msp.add_lwpolyline(
            [(500, y - 250), (1500, y - 250), (1500, y - 200), (500, y - 200)],
            close=True,
            dxfattribs={"layer": name},
        )
    for k, x in enumerate((540, 830, 1110, 1420)):
        msp.add_lwpolyline(
            [(x, -200), (x + 40, -200), (x + 40, 200), (x, 200)],
            close=True,
            dxfattribs={"layer": f"rung-{k + 1}_top40"},
        )
    doc.saveas(f)
    return f


def _scan(tmp_path, tpl, pose, name):
    placed = transform_template(tpl, pose, tpl.centroid)
    scan = scan_lines(placed, zigzag_plan(tpl, 0.04, 0.16), np.random.default_rng(1), SensorModel(speed=0.5))
    return write_laser_scan(tmp_path / name, scan)


def test_template_then_localize(tmp_path, ladder_dxf):
    runner = CliRunner()
    out = tmp_path / "template.json"
    res = runner.invoke(main, ["template", str(ladder_dxf), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "6 members" in res.output
    doc = json.loads(out.read_text())
    assert doc["schema"] == "weldcell/template@1" and doc["units"] == "m" and len(doc["welds"]) == 8
    tpl = load_template(out)
    pose = (0.011, -0.007, math.radians(-12.0))
    scan = _scan(tmp_path, tpl, pose, "scan.csv")
    result = tmp_path / "result.json"
    res = runner.invoke(main, ["localize", str(ladder_dxf), str(scan), "-o", str(result)])
    assert res.exit_code == 0, res.output
    loc = json.loads(result.read_text())
    assert loc["schema"] == "weldcell/localization@1" and loc["status"] == "ok"
    assert loc["x"] == pytest.approx(pose[0], abs=3e-4) and loc["y"] == pytest.approx(pose[1], abs=3e-4)
    assert loc["theta"] == pytest.approx(pose[2], abs=math.radians(0.05))
    M = np.array(loc["M"])
    assert M.shape == (4, 4) and np.allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3))
    assert len(loc["members"]) == 6 and len(loc["welds"]) == 8


def test_failed_localization_exits_1_and_keeps_the_result(tmp_path, ladder_dxf):
    tpl = load_template(ladder_dxf)
    scan = _scan(tmp_path, tpl, (0.1, 0.0, 0.0), "far.csv")  # 100 mm off: outside the window
    result = tmp_path / "result.json"
    res = CliRunner().invoke(
        main, ["localize", str(ladder_dxf), str(scan), "-o", str(result), "--set", "window_center='planned'"]
    )
    assert res.exit_code == 1, res.output
    assert "by hand" in res.output
    assert json.loads(result.read_text())["status"] == "failed"


def test_bad_input_exits_2(tmp_path, ladder_dxf):
    runner = CliRunner()
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x,y,z\n0,0,0,0\n")
    res = runner.invoke(main, ["localize", str(ladder_dxf), str(bad), "-o", str(tmp_path / "r.json")])
    assert res.exit_code == 2 and "header" in res.output
    res = runner.invoke(
        main,
        [
            "localize",
            str(ladder_dxf),
            str(bad),
            "-o",
            str(tmp_path / "r.json"),
            "--set",
            "window_xy=12 parsecs",
        ],
    )
    assert res.exit_code == 2 and "window_xy" in res.output
    empty = tmp_path / "empty.dxf"
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4
    doc.saveas(empty)
    res = runner.invoke(main, ["template", str(empty), "-o", str(tmp_path / "t.json")])
    assert res.exit_code == 2 and "no closed outline" in " ".join(res.output.split())
