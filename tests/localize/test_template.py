"""Templates from CAD (paper 002, §III-A): DXF through ezdxf, meshes through trimesh, template JSON."""

from __future__ import annotations

import json

import ezdxf
import numpy as np
import pytest
import trimesh
from shapely.geometry import Polygon
from weldcell.plugins.localize.template import SCHEMA, load_template, template_from_json
from weldcell.sdk.errors import DataError


def _ladder_dxf(path, insunits=4):
    """Rails as closed LWPOLYLINEs, a rung as four LINEs, a plate with bulged (round) ends, a block member,
    a weld polyline: all in millimetres."""
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = insunits
    msp = doc.modelspace()
    msp.add_lwpolyline(
        [(0, 0), (1000, 0), (1000, 50), (0, 50)], close=True, dxfattribs={"layer": "rail-a_top50"}
    )
    msp.add_lwpolyline(
        [(0, 450), (1000, 450), (1000, 500), (0, 500)], close=True, dxfattribs={"layer": "rail-b_top50"}
    )
    for a, b in (
        ((300, 50), (340, 50)),
        ((340, 50), (340, 450)),
        ((340, 450), (300, 450)),
        ((300, 450), (300, 50)),
    ):
        msp.add_line(a, b, dxfattribs={"layer": "rung_top40"})
    # a 200 x 40 plate with semicircular ends: bulge 1 = half circle
    msp.add_lwpolyline(
        [(600, 230, 0, 0, 0), (800, 230, 0, 0, 1), (800, 270, 0, 0, 0), (600, 270, 0, 0, 1)],
        format="xyseb",
        close=True,
        dxfattribs={"layer": "plate_top30"},
    )
    blk = doc.blocks.new("GUSSET_TOP35")
    blk.add_lwpolyline([(0, 0), (40, 0), (0, 40)], close=True)
    msp.add_blockref("GUSSET_TOP35", (10, 60))
    doc.appids.new("WELDCELL")
    brace = msp.add_lwpolyline(
        [(500, 100), (560, 100), (560, 140), (500, 140)], close=True, dxfattribs={"layer": "BRACE"}
    )
    brace.set_xdata("WELDCELL", [(1000, "top=45")])  # the height from XDATA
    msp.add_line((300, 50, 50), (340, 50, 50), dxfattribs={"layer": "WELD"})
    doc.saveas(path)


def test_dxf_in_mm_with_layers_bulges_lines_and_blocks(tmp_path):
    f = tmp_path / "ladder.dxf"
    _ladder_dxf(f)
    tpl = load_template(f)
    ids = {m.id: m for m in tpl.members}
    assert set(ids) == {"rail-a_top50", "rail-b_top50", "rung_top40", "plate_top30", "GUSSET_TOP35", "BRACE"}
    assert ids["BRACE"].top == pytest.approx(0.045)
    assert ids["rail-a_top50"].top == pytest.approx(0.05)
    assert ids["rung_top40"].top == pytest.approx(0.04)  # four LINEs chained into one loop
    assert Polygon(ids["rung_top40"].outline).area == pytest.approx(0.04 * 0.4, rel=1e-6)
    plate = ids["plate_top30"]  # bulges flattened: a stadium of 200 x 40 mm
    assert len(plate.outline) > 20
    assert Polygon(plate.outline).area == pytest.approx(0.2 * 0.04 + np.pi * 0.02**2, rel=2e-3)
    gusset = ids["GUSSET_TOP35"]  # block insert, transformed
    assert gusset.top == pytest.approx(0.035)
    assert gusset.outline.min(axis=0) == pytest.approx([0.01, 0.06])
    assert len(tpl.welds) == 1 and tpl.welds[0].points[:, 2] == pytest.approx([0.05, 0.05])


def test_dxf_units_missing_refused_and_overridable(tmp_path):
    f = tmp_path / "nounits.dxf"
    _ladder_dxf(f, insunits=0)
    with pytest.raises(DataError, match="unitless"):
        load_template(f)
    tpl = load_template(f, units="mm")
    assert {m.id: m for m in tpl.members}["rail-a_top50"].outline.max() == pytest.approx(1.0)


def test_dxf_without_closed_outline_or_with_crossing_outline(tmp_path):
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4
    doc.modelspace().add_line((0, 0), (100, 0), dxfattribs={"layer": "a_top10"})
    doc.modelspace().add_line((100, 0), (100, 50), dxfattribs={"layer": "a_top10"})
    doc.saveas(tmp_path / "open.dxf")
    with pytest.raises(DataError, match="no closed outline"):
        load_template(tmp_path / "open.dxf")
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4
    doc.modelspace().add_lwpolyline(
        [(0, 0), (100, 100), (100, 0), (0, 100)], close=True, dxfattribs={"layer": "bow_top10"}
    )
    doc.modelspace().add_lwpolyline(
        [(200, 0), (300, 0), (300, 50)], close=True, dxfattribs={"layer": "b_top10"}
    )
    doc.saveas(tmp_path / "bow.dxf")
    with pytest.raises(DataError, match="self-intersecting"):
        load_template(tmp_path / "bow.dxf")


def test_dxf_member_without_height_needs_top_option(tmp_path):
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6  # metres
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0), (1, 0), (1, 0.05), (0, 0.05)], close=True, dxfattribs={"layer": "A"})
    msp.add_lwpolyline([(0, 0.3), (1, 0.3), (1, 0.35), (0, 0.35)], close=True, dxfattribs={"layer": "B"})
    doc.saveas(tmp_path / "m.dxf")
    with pytest.raises(DataError, match="no top height"):
        load_template(tmp_path / "m.dxf")
    assert {m.top for m in load_template(tmp_path / "m.dxf", top=0.04).members} == {0.04}


def test_single_member_is_under_constrained(tmp_path):
    data = {
        "schema": SCHEMA,
        "units": "m",
        "members": [{"id": "bar", "top": 0.05, "outline": [[0, 0], [1, 0], [1, 0.05], [0, 0.05]]}],
    }
    f = tmp_path / "one.json"
    f.write_text(json.dumps(data))
    with pytest.raises(DataError, match="single member"):
        load_template(f)
    with pytest.warns(UserWarning, match="under-constrained"):
        assert len(load_template(f, allow_single_member=True).members) == 1


def test_mesh_members_outlines_and_heights(tmp_path):
    rail = trimesh.creation.box(extents=(1000, 50, 50))
    rail.apply_translation((500, 25, 25))
    rail_b = rail.copy()
    rail_b.apply_translation((0, 450, 0))
    rung = trimesh.creation.box(extents=(40, 400, 40))
    rung.apply_translation((320, 250, 20))
    f = tmp_path / "ladder.stl"
    trimesh.util.concatenate([rail, rail_b, rung]).export(f)
    tpl = load_template(f)  # STL in mm by default
    assert len(tpl.members) == 3
    assert sorted(m.top for m in tpl.members) == pytest.approx([0.04, 0.05, 0.05])
    assert tpl.table_z == pytest.approx(0.0)
    areas = sorted(Polygon(m.outline).area for m in tpl.members)
    assert areas == pytest.approx([0.016, 0.05, 0.05], rel=1e-6)
    assert len(tpl.welds) == 2  # the rung touches both rails
    with pytest.raises(DataError, match="spans"):
        load_template(f, units="m")  # 1000 m wide: wrong units


def test_json_round_trip_units_and_unknown_keys(tmp_path):
    from weldcell.plugins.localize.workpieces import ladder_frame

    tpl = ladder_frame()
    f = tpl.save(tmp_path / "t.json")
    back = load_template(f)
    assert [m.id for m in back.members] == [m.id for m in tpl.members]
    assert np.allclose(back.members[2].outline, tpl.members[2].outline)
    assert np.allclose(back.welds[0].points, tpl.welds[0].points)
    data = tpl.to_json()
    mm = json.loads(json.dumps(data))
    mm["units"] = "mm"
    for m in mm["members"]:
        m["outline"] = (np.asarray(m["outline"]) * 1000).tolist()
        m["top"] *= 1000
    mm["welds"] = []
    assert np.allclose(template_from_json(mm).members[0].outline, tpl.members[0].outline)
    bad = dict(data, colour="red")
    with pytest.raises(DataError, match="unknown keys 'colour'"):
        template_from_json(bad)
    bad = json.loads(json.dumps(data))
    bad["members"][0]["height"] = 1
    with pytest.raises(DataError, match="members\\[0\\].*'height'"):
        template_from_json(bad)
    with pytest.raises(DataError, match="unknown units"):
        template_from_json(dict(data, units="furlong"))
