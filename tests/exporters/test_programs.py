"""Every robot program parses with its language's grammar, obeys the controller's rules, and replays
through the robot model and the safety gate onto the planned path (within the reduction tolerance)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from weldcell.hal.kinematics import get_model
from weldcell.hal.safety import SafetyGate
from weldcell.plugins.exporters import controllers, programs
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import SafetyError
from weldcell.sdk.geometry import T_from_rpy, invert

from . import grammars as g
from .conftest import WIDE, path_gap, weld_path

TCP = (0.0, 0.0, 0.2)


def read(lang: str, text: str):
    if lang == "urscript":
        return g.read_urscript(text)[0]
    if lang == "rapid":
        return g.read_rapid(text)[0]
    if lang == "krl":
        return g.read_krl(text)[0]
    return g.read_tp(text)[0]


CASES = {  # language: (export function, settings, robot model, cell limits)
    "urscript": (programs.export_urscript, programs.URScriptSettings, "ur5", {}),
    "rapid": (programs.export_rapid, programs.RapidSettings, "abb-irb2600", WIDE),
    "krl": (controllers.export_krl, controllers.KrlSettings, "abb-irb2600", WIDE),
    "tp": (controllers.export_fanuc, controllers.FanucSettings, "abb-irb2600", WIDE),
}


@pytest.fixture(scope="module", params=list(CASES))
def exported(request, ur_path, abb_path, ur_doc, abb_doc):
    lang = request.param
    export, settings, model, limits = CASES[lang]
    wp, doc = (ur_path, ur_doc) if model == "ur5" else (abb_path, abb_doc)
    s = settings(robot_model=model, safety=limits, tcp_xyz=TCP)
    result = export(doc, s)
    return lang, wp, s, result, read(lang, result.text)


def test_program_parses_and_has_the_planned_structure(exported):
    lang, wp, s, result, moves = exported
    assert result.plan.checked_with == get_model(s.robot_model).name
    assert len(moves) == len(result.plan.motions)
    i = 0
    for seam in result.plan.seams:
        n = len(seam.reduction.poses)
        block = moves[i : i + n + 2]
        assert block[0].kind == "joint"  # every seam is approached by a joint move
        assert all(m.kind == "linear" for m in block[1:])
        assert [m.events for m in block] == [[], ["arc_on"], *[[]] * (n - 2), ["arc_off"], []]
        first, last = block[1].pose, block[n].pose
        # approach and retract: s.retract back along the torch axis, no arc
        np.testing.assert_allclose(block[0].pose[:3, 3], first[:3, 3] - s.retract * first[:3, 2], atol=2e-6)
        np.testing.assert_allclose(block[-1].pose[:3, 3], last[:3, 3] - s.retract * last[:3, 2], atol=2e-6)
        i += n + 2


def test_blends_never_overlap_and_stop_at_the_arc_ends(exported):
    lang, wp, s, result, moves = exported
    positions = np.array([m.pose[:3, 3] for m in moves])
    seg = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    for k, m in enumerate(moves):
        if "arc_on" in m.events or "arc_off" in m.events or m.kind == "joint" or k == len(moves) - 1:
            assert m.blend == 0.0, f"move {k} must stop: {m.events}"
        if lang == "tp":  # CNT is a smoothing level, not a distance: FINE where the others stop
            continue
        shorter = min(seg[k - 1] if k > 0 else np.inf, seg[k] if k < len(seg) else np.inf)
        assert m.blend <= 0.45 * shorter + 1e-6, f"move {k}: blend {m.blend} over 45 % of {shorter}"
    assert any(m.blend > 0 for m in moves)


def test_round_trip_follows_the_planned_path(exported):
    lang, wp, s, result, moves = exported
    i = 0
    for seam, planned in zip(result.plan.seams, wp.seams, strict=True):
        n = len(seam.reduction.poses)
        welded = np.stack([m.pose for m in moves[i + 1 : i + n + 1]])
        loop = np.concatenate([planned.poses, planned.poses[:1]]) if planned.closed else planned.poses
        d, a = path_gap(loop, welded, step=5e-5)  # a closed seam is welded all the way round
        assert d <= s.tolerance + 5e-5 and a <= s.angle_tolerance + 2e-3
        nominal = getattr(s, "weld_speed", None) or s.tool_speed
        speed = planned.extra.get("weld_speed", nominal)  # a seam's own speed wins
        assert [m.speed for m in moves[i + 2 : i + n + 1]] == pytest.approx([speed] * (n - 1))
        i += n + 2


def test_replay_through_the_robot_model_and_the_gate(exported):
    """The motions read back from the text (not the exporter's plan) pass the gate with the robot model."""
    lang, wp, s, result, moves = exported
    for m, planned in zip(moves, result.plan.motions, strict=True):  # the text holds the checked plan
        np.testing.assert_allclose(m.pose[:3, 3], planned.pose[:3, 3], atol=1e-6)
        assert np.linalg.norm(m.pose[:3, :3] - planned.pose[:3, :3]) < 5e-5  # TP: 0.001 deg
    if lang in ("krl", "tp"):
        return  # equal motions, same verdict: the gate replay below is done for URScript and RAPID
    gate = SafetyGate(SafetyLimits(**(WIDE if s.robot_model != "ur5" else {})), get_model(s.robot_model))
    T_ft = T_from_rpy((0, 0, 0), TCP)
    q, prev = None, None
    for k, m in enumerate(moves):
        if prev is None or m.kind == "joint":
            q = gate.check_pose(m.pose, m.pose @ invert(T_ft), q, f"move {k}")
        else:
            q = gate.check_linear(prev, m.pose, T_ft, m.speed or 0.1, s.accel, q, f"move {k}")
        prev = m.pose
    assert q is not None


@pytest.mark.parametrize("lang", list(CASES))
def test_a_program_the_gate_would_refuse_is_not_exported(lang):
    export, settings, model, limits = CASES[lang]
    far = weld_path(0.9 if model == "ur5" else 1.9, 0.1)  # beyond the robot's reach
    with pytest.raises(SafetyError, match="the program would be refused") as e:
        export(far.to_json(), settings(robot_model=model, safety=limits))
    assert "nothing was exported" in e.value.fix


@pytest.mark.parametrize("lang", list(CASES))
def test_without_a_robot_model_the_program_says_it_was_not_checked(lang, ur_doc):
    export, settings, _, _ = CASES[lang]
    text = export(ur_doc, settings()).text
    prose = text
    if lang == "tp":  # TP comments are short lines
        prose = " ".join(x.split("!", 1)[1].strip(" ;") for x in text.splitlines() if "!" in x)
    assert "NOT checked against a robot model" in prose and "no torch TCP given" in prose
    assert "set_tcp" not in text and "$TOOL = {" not in text  # the calibrated tool, not a zero one
    read(lang, text)


def test_rapid_declares_everything_it_uses(abb_doc):
    s = programs.RapidSettings(wobj="wobjTable", tcp_xyz=(0.01, 0.0, 0.35), tool_mass=2.5)
    moves, decls = g.read_rapid(programs.to_rapid(abb_doc, s))  # undeclared names would fail
    assert decls["tWeldGun"][0] == "tooldata"
    assert decls["tWeldGun"][1][1][0] == [10.0, 0.0, 350.0] and decls["tWeldGun"][1][2][0] == 2.5
    assert decls["wobjTable"][0] == "wobjdata" and decls["smWeld"][0] == "seamdata"
    assert decls["vWeld"][1][0] == 10.0 and decls["vApproach"][1][0] == 100.0
    assert decls["wdWeld_0"][1][0] == 8.0  # the seam's own weld speed, mm/s
    assert sum(t == "robtarget" for t, _ in decls.values()) == len(moves)


def test_urscript_process_calls_and_tcp(ur_doc):
    s = programs.URScriptSettings(arc_on_call="weld_start()", arc_off_call="weld_end()", tcp_xyz=TCP)
    text = programs.to_urscript(ur_doc, s)
    moves, tcp = g.read_urscript(text, {"weld_start": "arc_on", "weld_end": "arc_off"})
    assert "set_standard_digital_out" not in text
    assert sum("arc_on" in m.events for m in moves) == 2 == sum("arc_off" in m.events for m in moves)
    np.testing.assert_allclose(tcp[:3, 3], TCP, atol=1e-9)
    with pytest.raises(AssertionError, match="undefined function"):
        g.read_urscript(text)  # the reader refuses calls it does not know: the check can fail


def test_krl_registers_its_src_dat_pair(weldcell_pm, ur_doc):
    import weldcell.plugins.exporters as exporters_plugin

    weldcell_pm.register(exporters_plugin, "exporters")
    spec = weldcell_pm.registry.get("exporter", "export.kuka-krl")
    assert spec.suffix == ".src" and spec.files is controllers.krl_files
    assert weldcell_pm.registry.get("exporter", "export.urscript").files is None


def test_krl_src_and_dat_pair_matches_the_inline_program(ur_doc):
    s = controllers.KrlSettings(tool_number=3, base_number=2)
    files = controllers.krl_files(ur_doc, s)
    assert set(files) == {"weldcell_path.src", "weldcell_path.dat"}
    paired, _ = g.read_krl(files["weldcell_path.src"], files["weldcell_path.dat"])
    inline, tool = g.read_krl(controllers.to_krl(ur_doc, s))
    assert tool is None and "$TOOL = TOOL_DATA[3]" in files["weldcell_path.src"]
    assert "$BASE = BASE_DATA[2]" in files["weldcell_path.src"]
    assert len(paired) == len(inline)
    for a, b in zip(paired, inline, strict=True):
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-9)
        assert (a.kind, a.speed, a.blend, a.events) == (b.kind, b.speed, b.blend, b.events)


def test_fanuc_frames_and_digital_output(ur_doc):
    s = controllers.FanucSettings(uframe=2, utool=4, arc="digital_out", arc_output=7)
    text = controllers.to_fanuc(ur_doc, s)
    moves, frames = g.read_tp(text)
    assert frames == {"UFRAME_NUM": 2, "UTOOL_NUM": 4}
    assert "DO[7]=ON" in text and "Arc Start" not in text
    assert text.count("UF : 2, UT : 4") == len(moves)


def test_a_seam_too_short_to_weld_is_skipped_and_noted(ur_doc):
    doc = copy.deepcopy(ur_doc)
    doc["seams"][0]["poses"] = doc["seams"][0]["poses"][:1]
    result = programs.export_rapid(doc)
    assert [s.id for s in result.plan.seams] == ["s1"]
    assert "skipped: seam s0: 1 pose(s)" in result.text
    g.read_rapid(result.text)


@pytest.mark.parametrize("lang", list(CASES))
def test_seam_ids_become_unique_routine_names(lang, ur_doc):
    """Ids that are not identifiers, or that clash once made identifiers, still give one routine each."""
    export, settings, _, _ = CASES[lang]
    doc = copy.deepcopy(ur_doc)
    doc["seams"][0]["id"], doc["seams"][1]["id"] = "weld-1", "weld 1"
    result = export(doc, settings())
    assert [s.routine for s in result.plan.seams] == ["seam_weld_1", "seam_weld_1_1"]
    moves = read(lang, result.text)  # both routines defined and called
    assert sum("arc_on" in m.events for m in moves) == 2
