"""The weld-path file (``weldcell/weld-path@1``) and the exporters: URScript, ABB RAPID, CSV, JSON.

The program exporters are checked in depth (grammars, blends, gate replay) in tests/exporters/; here with
``reduce=False`` every planned pose is visible in the program."""

from __future__ import annotations

import csv
import io
import json
import re

import numpy as np
import pytest
import weldcell.plugins.exporters as exporters_plugin
from weldcell.plugins.exporters import controllers, programs
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_quat, T_from_ur_pose, frame_from_axes, pose_error
from weldcell.sdk.weldpath import SCHEMA, SeamPath, WeldPath

RETRACT = 0.05


def torch_poses(points: np.ndarray, approach) -> np.ndarray:
    travel = np.gradient(points, axis=0)
    return np.stack([frame_from_axes(t, approach, p) for t, p in zip(travel, points, strict=True)])


@pytest.fixture
def path() -> WeldPath:
    p0 = np.column_stack([np.full(6, 0.45), np.linspace(-0.1, 0.1, 6), np.full(6, 0.01)])
    s0 = SeamPath("s0", "fillet", p0, torch_poses(p0, [0.0, 1.0, -1.0]), extra={"weld_speed": 0.008})
    angle = np.linspace(0, 2 * np.pi, 9)[:-1]
    p1 = np.column_stack([0.3 + 0.05 * np.cos(angle), 0.2 + 0.05 * np.sin(angle), np.full(8, 0.02)])
    s1 = SeamPath("s1", "saddle", p1, torch_poses(p1, [0.3, -0.2, -1.0]), closed=True)
    return WeldPath([s0, s1], frame="base", metrics={"f1": 0.93})


def all_poses(wp: WeldPath) -> list[np.ndarray]:
    return [T for s in wp.seams for T in s.poses]


def retracted(T: np.ndarray) -> np.ndarray:
    out = T.copy()
    out[:3, 3] -= RETRACT * T[:3, 2]
    return out


def expected_program(wp: WeldPath) -> list[np.ndarray]:
    """Approach, every pose (a closed seam back to its first), retract."""
    out = []
    for s in wp.seams:
        poses = [*s.poses, s.poses[0]] if s.closed else list(s.poses)
        out += [retracted(poses[0]), *poses, retracted(poses[-1])]
    return out


# -- the weld-path file --------------------------------------------------------------------------
def test_round_trip_through_json_and_a_file(path, tmp_path):
    doc = path.to_json()
    assert doc["schema"] == SCHEMA and doc["units"] == "m" and doc["frame"] == "base"
    assert doc["seams"][0]["weld_speed"] == 0.008
    assert doc["seams"][0]["length"] == pytest.approx(0.2)
    assert doc["seams"][1]["closed"] is True
    assert doc["seams"][1]["length"] == pytest.approx(8 * 2 * 0.05 * np.sin(np.pi / 8), abs=1e-6)
    assert all(len(p) == 7 for p in doc["seams"][0]["poses"])
    f = path.write(tmp_path / "weld_path.json")
    for back in (WeldPath.from_json(doc), WeldPath.from_json(f), WeldPath.from_json(str(f))):
        assert [s.id for s in back.seams] == ["s0", "s1"]
        assert [s.joint for s in back.seams] == ["fillet", "saddle"]
        assert back.metrics == {"f1": 0.93} and back.seams[1].closed
        assert back.seams[0].extra == {"weld_speed": 0.008}
        for a, b in zip(all_poses(back), all_poses(path), strict=True):
            dt, dr = pose_error(a, b)
            assert dt < 1e-6 and dr < 1e-6
        np.testing.assert_allclose(back.seams[0].points, path.seams[0].points, atol=1e-7)
    assert json.loads(f.read_text()) == json.loads(json.dumps(doc))


def test_quaternions_are_stored_with_non_negative_w(path):
    for seam in path.to_json()["seams"]:
        assert all(p[6] >= 0 for p in seam["poses"])


@pytest.mark.parametrize(
    ("doc", "words"),
    [
        ({"schema": "weldcell/weld-path@2", "seams": []}, "schema is 'weldcell/weld-path@2', expected"),
        ({"seams": []}, "schema is None"),
        ([1, 2], "expected a JSON object, got list"),
        ({"schema": SCHEMA, "units": "mm", "seams": []}, "units 'mm'; weld paths are stored in metres"),
        ({"schema": SCHEMA, "seams": [{"points": [[0, 0, 0]]}]}, "seams[0] is missing poses"),
        ({"schema": SCHEMA, "seams": [{"points": [[0, 0]], "poses": []}]}, "seams[0] is malformed"),
        (
            {
                "schema": SCHEMA,
                "seams": [
                    {"points": [[0, 0, 0]], "poses": [[0, 0, 0, 0, 0, 0, 1]]},
                    {"points": [[0, np.nan, 0]], "poses": []},
                ],
            },
            "seams[1] has NaN",
        ),
    ],
)
def test_invalid_documents_are_refused_with_a_reason(doc, words):
    with pytest.raises(DataError) as e:
        WeldPath.from_json(doc)
    assert words in e.value.message
    assert e.value.fix


def test_invalid_file_names_the_file(tmp_path):
    f = tmp_path / "path.json"
    f.write_text('{"schema": "nope"}')
    with pytest.raises(DataError, match=re.escape(f"{f}: schema is 'nope'")):
        WeldPath.from_json(f)
    f.write_text("{not json")
    with pytest.raises(DataError, match="not valid JSON"):
        WeldPath.from_json(f)
    with pytest.raises(DataError, match="file not found"):
        WeldPath.from_json(tmp_path / "absent.json")


def test_a_seam_without_poses_is_kept():
    wp = WeldPath.from_json({"schema": SCHEMA, "seams": [{"points": [[0, 0, 0], [0.1, 0, 0]], "poses": []}]})
    assert wp.seams[0].poses.shape == (0, 4, 4) and wp.seams[0].length == pytest.approx(0.1)
    assert wp.seams[0].id == "s0" and wp.seams[0].joint == "unknown"


# -- exporters -----------------------------------------------------------------------------------
UR_POSE = re.compile(r"\b(movej|movel|movep)\(p\[([^\]]+)\]")
ALL = programs.URScriptSettings(reduce=False)


def test_urscript_visits_every_pose_with_approach_and_retract(path):
    text = programs.to_urscript(path.to_json(), ALL)
    moves = UR_POSE.findall(text)
    expected = expected_program(path)
    assert len(moves) == len(expected) == sum(len(s.poses) + 2 + s.closed for s in path.seams)
    for (_, values), T in zip(moves, expected, strict=True):
        pose = np.array([float(v) for v in values.split(",")])
        assert len(pose) == 6
        np.testing.assert_allclose(pose[:3], T[:3, 3], atol=2e-6)  # metres, not mm
        assert np.linalg.norm(pose[3:]) <= np.pi + 1e-6  # a rotation vector
        dt, dr = pose_error(T_from_ur_pose(pose), T)
        assert dt < 2e-6 and dr < 1e-5
    kinds = [k for k, _ in moves]
    n0 = len(path.seams[0].poses)
    assert kinds[: n0 + 2] == ["movej", "movel", *["movep"] * (n0 - 1), "movel"]
    assert kinds[n0 + 2 : n0 + 4] == ["movej", "movel"]  # the next seam is approached by a joint move
    assert "def weldcell_path():" in text and text.rstrip().endswith("weldcell_path()")
    assert "v=0.01, r=0.001" in text  # welding speed and blend along the seam
    assert "v=0.008, r=0.001" in text  # the first seam's own weld speed
    on, off = "set_standard_digital_out(0, True)", "set_standard_digital_out(0, False)"
    assert text.count(on) == 2 == text.count(off)  # arc on and off per seam
    plain = programs.to_urscript(
        path.to_json(), programs.URScriptSettings(use_movep=False, program_name="weld", reduce=False)
    )
    assert "movep" not in plain and "def weld():" in plain


def test_urscript_retract_is_along_minus_z_of_the_torch(path):
    text = programs.to_urscript(path.to_json(), programs.URScriptSettings(retract="80 mm", reduce=False))
    first = np.array([float(v) for v in UR_POSE.findall(text)[0][1].split(",")])
    T0 = path.seams[0].poses[0]
    np.testing.assert_allclose(first[:3], T0[:3, 3] - 0.08 * T0[:3, 2], atol=2e-6)
    assert np.linalg.norm(first[:3] - T0[:3, 3]) == pytest.approx(0.08, abs=1e-5)


RAPID_TARGET = re.compile(r"CONST robtarget (\w+) := \[\[([^\]]+)\],\[([^\]]+)\]")


def test_rapid_robtargets_in_mm_with_wxyz_quaternions(path):
    text = programs.to_rapid(path.to_json(), programs.RapidSettings(reduce=False))
    targets = RAPID_TARGET.findall(text)
    expected = expected_program(path)
    assert len(targets) == len(expected)
    for (_name, xyz, quat), T in zip(targets, expected, strict=True):
        p = np.array([float(v) for v in xyz.split(",")])
        q1, q2, q3, q4 = (float(v) for v in quat.split(","))
        np.testing.assert_allclose(p, T[:3, 3] * 1000.0, atol=2e-3)  # millimetres
        assert q1 >= 0  # q1 is w
        dt, dr = pose_error(T_from_quat([q2, q3, q4, q1], p / 1000.0), T)
        assert dr < 1e-6
    moves = re.findall(
        r"(MoveJ|MoveL|ArcLStart|ArcL|ArcLEnd) (\w+), (\w+), (?:smWeld, wdWeld_\d, )?(\w+), "
        r"tWeldGun\\WObj:=wobj0;",
        text,
    )
    assert [m[1] for m in moves] == [t[0] for t in targets]  # every target is visited, in order
    n0 = len(path.seams[0].poses)
    assert moves[0] == ("MoveJ", "p0_0", "vApproach", "fine")
    assert moves[1] == ("ArcLStart", "p0_1", "vApproach", "fine")  # arc on at the first weld pose
    assert moves[2][0] == "ArcL" and moves[2][2] == "vWeld" and moves[2][3].startswith("zW")
    assert moves[n0][0] == "ArcLEnd" and moves[n0][3] == "fine"  # arc off, stopped
    assert moves[n0 + 1] == ("MoveL", f"p0_{n0 + 1}", "vApproach", "fine")
    assert "PERS tooldata tWeldGun :=" in text and "ConfL\\Off;" in text
    assert text.startswith("MODULE WeldcellPath") and text.rstrip().endswith("ENDMODULE")
    assert "PROC main()" in text and "ENDPROC" in text


def test_csv_has_one_row_per_pose(path):
    text = programs.to_csv(path.to_json())
    rows = list(csv.DictReader(io.StringIO(text)))
    assert len(rows) == sum(len(s.poses) for s in path.seams)
    assert list(rows[0]) == ["seam", "index", "x_mm", "y_mm", "z_mm", "qx", "qy", "qz", "qw"]
    for row, T, seam_id in zip(rows, all_poses(path), ["s0"] * 6 + ["s1"] * 8, strict=True):
        assert row["seam"] == seam_id
        p = np.array([float(row[k]) for k in ("x_mm", "y_mm", "z_mm")])
        np.testing.assert_allclose(p, T[:3, 3] * 1000, atol=1e-3)
        q = [float(row[k]) for k in ("qx", "qy", "qz", "qw")]
        assert pose_error(T_from_quat(q, T[:3, 3]), T)[1] < 1e-6
    metres = list(
        csv.DictReader(io.StringIO(programs.to_csv(path.to_json(), programs.CsvSettings(units="m"))))
    )
    assert float(metres[0]["x_m"]) == pytest.approx(0.45)


def test_json_exporter_writes_the_validated_document(path):
    text = programs.to_json(path.to_json())
    assert json.loads(text) == json.loads(json.dumps(WeldPath.from_json(path.to_json()).to_json()))


def test_exporters_refuse_an_invalid_weld_path():
    exporters = (programs.to_urscript, programs.to_rapid, controllers.to_krl, controllers.to_fanuc)
    for export in (*exporters, programs.to_csv, programs.to_json):
        with pytest.raises(DataError, match="schema"):
            export({"schema": "something-else"})


def test_exporters_are_registered_with_suffixes(weldcell_pm):
    weldcell_pm.register(exporters_plugin, "exporters")
    reg = weldcell_pm.registry
    suffixes = {n: reg.get("exporter", n).suffix for n in reg.names("exporter")}
    assert suffixes == {
        "export.urscript": ".script",
        "export.abb-rapid": ".mod",
        "export.kuka-krl": ".src",
        "export.fanuc-tp": ".ls",
        "export.csv": ".csv",
        "export.json": ".json",
    }
    spec = reg.get("exporter", "export.urscript")
    s = spec.settings.model_validate({"tool_speed": "6 mm/s"})
    assert s.tool_speed == pytest.approx(0.006)
