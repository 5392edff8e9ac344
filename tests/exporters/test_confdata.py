"""Configuration data from the robot model's IK: each exported target's confdata (RAPID), Status/Turn (KRL)
or CONFIG (FANUC TP) selects the IK branch the path was planned on, read back from the program text.

KUKA and FANUC arms are not among weldcell's robot models yet: their round trips use an arm with the
IRB 2600's geometry registered under a ``kuka-``/``fanuc-`` name (the convention comes from the name).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from weldcell.hal import kinematics
from weldcell.hal.robot_models import ABB_IRB2600
from weldcell.hal.safety import SafetyGate
from weldcell.plugins.exporters import confdata, controllers, programs
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy, invert
from weldcell.sdk.weldpath import SeamPath, WeldPath

from . import grammars as g
from .conftest import WIDE, torch_poses, weld_path

TCP = (0.0, 0.0, 0.2)
T_FT = T_from_rpy((0, 0, 0), TCP)
ABB = kinematics.get_model("abb-irb2600")
D = np.radians


def _rotated(wp: WeldPath, deg: float) -> WeldPath:
    R = np.eye(4)
    R[:3, :3] = T_from_rpy((0, 0, math.radians(deg)), (0, 0, 0))[:3, :3]
    return WeldPath(
        [
            SeamPath(s.id, s.joint, (R[:3, :3] @ s.points.T).T, R @ s.poses, s.closed, s.extra)
            for s in wp.seams
        ],
        frame=wp.frame,
    )


def _wall_seam() -> WeldPath:
    """A seam on a wall facing the robot, the torch pointing forward and down: the IK branch nearest the
    home joints has axis 5 negative (a flipped wrist)."""
    p = np.column_stack([np.full(300, 1.0), np.linspace(-0.15, 0.15, 300), np.full(300, 0.4)])
    return WeldPath([SeamPath("wall", "fillet", p, torch_poses(p, [1.0, 0.0, -0.35]))], frame="base")


PATHS = {
    "front": lambda: weld_path(1.0, 0.4),  # a line and a closed saddle (axis 6 turns through every quadrant)
    "left-behind": lambda: _rotated(weld_path(1.0, 0.4), 125.0),  # axis 1 past +90 deg
    "right-behind": lambda: _rotated(weld_path(1.0, 0.4), -125.0),  # axis 1 past -90 deg
    "flipped-wrist": _wall_seam,
}


def _vendor_model(vendor: str) -> kinematics.RobotModel:
    limits = list(ABB_IRB2600["joint_limits_deg"])
    if vendor == "kuka":  # KUKA wrists turn +-350 deg: the Turn bits tell every turn apart
        limits[3] = limits[5] = (-350.0, 350.0)
    table = dict(ABB_IRB2600, name=f"{vendor}-irb2600-geometry", aliases=(), joint_limits_deg=limits)
    return kinematics.build_model(table)


CASES = {  # language: export, settings, reader, vendor
    "rapid": (programs.export_rapid, programs.RapidSettings, lambda t: g.read_rapid(t)[0], "abb"),
    "krl": (controllers.export_krl, controllers.KrlSettings, lambda t: g.read_krl(t)[0], "kuka"),
    "tp": (controllers.export_fanuc, controllers.FanucSettings, lambda t: g.read_tp(t)[0], "fanuc"),
}


@pytest.fixture
def vendor_models(monkeypatch):
    for v in ("kuka", "fanuc"):
        m = _vendor_model(v)
        monkeypatch.setitem(kinematics.MODELS, m.name, m)


def _replay(moves, model) -> list[np.ndarray]:
    """The joints at every motion of the program text, tracked through the safety gate from the model's
    home joints (nearest solution at each joint move, followed along each linear move)."""
    gate = SafetyGate(SafetyLimits(**WIDE), model)
    q, prev, out = None, None, []
    for k, m in enumerate(moves):
        if prev is None or m.kind == "joint":
            q = gate.check_pose(m.pose, m.pose @ invert(T_FT), q, f"move {k}")
        else:
            q = gate.check_linear(prev, m.pose, T_FT, m.speed or 0.1, 0.5, q, f"move {k}")
        out.append(q)
        prev = m.pose
    return out


ROUND_TRIPS = [("rapid", p) for p in PATHS] + [  # every path in RAPID, two each in KRL and TP (test time)
    ("krl", "front"),
    ("krl", "right-behind"),
    ("tp", "left-behind"),
    ("tp", "flipped-wrist"),
]


@pytest.mark.parametrize("lang, path", ROUND_TRIPS)
def test_the_written_configuration_selects_the_planned_branch(lang, path, vendor_models):
    export, settings, reader, vendor = CASES[lang]
    model = ABB if vendor == "abb" else kinematics.get_model(f"{vendor}-irb2600-geometry")
    result = export(PATHS[path]().to_json(), settings(robot_model=model.name, safety=WIDE, tcp_xyz=TCP))
    moves = reader(result.text)
    assert all(m.config is not None for m in moves)
    planned = _replay(moves, model)  # from the text alone, not from the exporter's plan
    seen = set()
    for k, (m, q) in enumerate(zip(moves, planned, strict=True)):
        chosen = confdata.select(model, m.pose @ invert(T_FT), vendor, m.config)
        assert len(chosen) == 1, f"move {k}: {m.config} matches {len(chosen)} solutions"
        np.testing.assert_allclose(chosen[0], q, atol=1e-4, err_msg=f"move {k}: {m.config}")
        seen.add(m.config)
    # the paths exercise what they are for
    cfgs = [confdata.CONFIG_OF[vendor](model, q) for q in planned]
    if path == "left-behind":
        assert all(q[0] > D(90) for q in planned)
    if path == "right-behind":
        assert all(q[0] < D(-90) for q in planned)
    if path == "flipped-wrist":
        assert all(q[4] < 0 for q in planned)
    if path == "front" and vendor == "abb":
        assert len({c[2] for c in cfgs}) >= 3  # the saddle turns axis 6 through several quadrants
    if path == "front":
        assert len(seen) >= 2


def test_rapid_with_confdata_monitors_the_configuration(abb_doc):
    text = programs.to_rapid(abb_doc, programs.RapidSettings(robot_model="abb-irb2600", safety=WIDE))
    assert "ConfL\\On;" in text and "ConfJ\\On;" in text and "ConfL\\Off" not in text
    assert "confdata computed from the IK of abb-irb2600" in text
    first = g.read_rapid(text)[0][0]  # the first target: the solution nearest the home joints (zero tool)
    assert first.config == confdata.abb_confdata(ABB, ABB.ik(first.pose, ABB.home))


def _prose(lang: str, text: str) -> str:
    """The program's comments as one line (TP comments are cut into 30-character lines)."""
    if lang == "tp":
        return "".join(x.split("!", 1)[1].strip(" ;") for x in text.splitlines() if "!" in x)
    return " ".join(text.split())


@pytest.mark.parametrize("lang", list(CASES))
def test_unknown_robot_or_convention_keeps_configuration_off_with_a_note(lang, ur_doc):
    export, settings, reader, vendor = CASES[lang]
    unknown = export(ur_doc, settings()).text  # no robot model
    foreign = export(ur_doc, settings(robot_model="ur5")).text  # a UR5 follows no ABB/KUKA/FANUC convention
    for text, why in ((unknown, "robot unknown"), (foreign, "does not follow")):
        moves = reader(text)
        if lang == "rapid":
            assert "ConfL\\Off;" in text and "ConfJ\\Off;" in text and all(m.config is None for m in moves)
        elif lang == "krl":
            assert all(m.config is None for m in moves) and "no S and T given" in text
        else:
            assert all(m.config == "N U T, 0, 0, 0" for m in moves)
        assert why.replace(" ", "") in _prose(lang, text).replace(" ", "")


def test_kuka_turn_bits_need_axes_within_one_turn(abb_doc, monkeypatch):
    wide = kinematics.build_model(dict(ABB_IRB2600, name="kuka-wide", aliases=()))  # axes 4, 6: +-400 deg
    monkeypatch.setitem(kinematics.MODELS, wide.name, wide)
    s = controllers.KrlSettings(robot_model=wide.name, safety=WIDE)
    text = controllers.to_krl(abb_doc, s)
    assert "Turn bits cannot tell apart" in text
    assert all(m.config is None for m in g.read_krl(text)[0])


# -- the definitions, on joint vectors chosen by hand -------------------------------------------------
@pytest.mark.parametrize(
    "q_deg, cf",
    [
        ([0, 10, 30, 0, 50, 0], (0, 0, 0, 0)),  # home: everything in front, axis 5 positive
        ([100, 10, 30, 0, 50, 0], (1, 0, 0, 0)),  # axis 1 in its second quadrant
        ([-100, 10, 30, 0, 50, 0], (-2, 0, 0, 0)),
        ([0, 10, 30, 95, -50, -200], (0, 1, -3, 1)),  # axis 5 negative: cfx odd; quadrants of 4 and 6
        ([0, 10, 30, -5, 50, 370], (0, -1, 4, 0)),
    ],
)
def test_abb_quadrants_and_wrist_bit(q_deg, cf):
    assert confdata.abb_confdata(ABB, D(q_deg)) == cf


def _wrist(q) -> np.ndarray:
    """The IRB 2600's wrist centre: 85 mm behind tool0 along its z (the product specification)."""
    F = ABB.fk(q)
    return F[:3, 3] - 0.085 * F[:3, 2]


def test_wrist_in_front_of_axis_1_matches_the_geometry():
    rng = np.random.default_rng(3)
    lo, hi = ABB.joint_limits.T
    for q in lo + (hi - lo) * rng.random((200, 6)):
        x_a1 = np.array([math.cos(q[0]), math.sin(q[0]), 0.0])  # ABB axis 1 turns about +z
        front = float(_wrist(q) @ x_a1) > 0
        assert confdata.posture(ABB, q).front_of_axis1 == front
        assert (confdata.abb_confdata(ABB, q)[3] >= 4) == (not front)


def test_elbow_bit_flips_where_the_arm_is_stretched():
    """Sweeping axis 3, the wrist centre is farthest from axis 2 at the stretched arm: the elbow bit
    flips there and nowhere else, with the home pose's side called 'in front'."""
    rng = np.random.default_rng(4)
    for _ in range(4):
        q = ABB.home + rng.normal(0, 0.3, 6)
        q3 = np.linspace(*ABB.joint_limits[2], 512)
        Q = np.tile(q, (len(q3), 1))
        Q[:, 2] = q3
        shoulder = np.array([0.15 * math.cos(q[0]), 0.15 * math.sin(q[0]), 0.445])  # axis 2 (spec)
        reach = [np.linalg.norm(_wrist(x) - shoulder) for x in Q]
        stretched = q3[int(np.argmax(reach))]
        bits = np.array([confdata.posture(ABB, x).front_of_lower_arm for x in Q])
        flips = q3[1:][bits[1:] != bits[:-1]]
        assert len(flips) == 1 and abs(flips[0] - stretched) < 2 * (q3[1] - q3[0])
        assert bits[np.argmin(np.abs(q3 - ABB.home[2]))]


def test_fanuc_turn_numbers_and_kuka_bits():
    turns = [confdata.fanuc_turn(D(a)) for a in (-539, -181, -179, 0, 180, 181, 539)]
    assert turns == [-1, -1, 0, 0, 0, 1, 1]
    s, t = confdata.kuka_status_turn(ABB, D([-20, 10, 30, -5, -50, 30]))
    assert t == 0b011001 and s & 4  # A1, A4, A5 negative; A5 negative sets Status bit 2
    assert confdata.fanuc_config(ABB, D([0, 10, 30, 0, -50, 200])) == "N U T, 0, 0, 1"


def test_the_configuration_follows_the_robots_start_joints(abb_doc):
    """From a start with the wrist flipped (axis 4 + 180 deg, axis 5 negated, axis 6 + 180 deg: the same
    flange pose) the planner keeps the flipped wrist, and the confdata says so."""
    home = ABB.home
    flipped = home + D([0, 0, 0, 180, 0, 180])
    flipped[4] = -home[4]
    np.testing.assert_allclose(ABB.fk(flipped), ABB.fk(home), atol=1e-9)
    base = programs.RapidSettings(robot_model="abb-irb2600", safety=WIDE)
    moves0 = g.read_rapid(programs.to_rapid(abb_doc, base))[0]
    start = programs.RapidSettings(robot_model="abb-irb2600", safety=WIDE, start_joints=tuple(flipped))
    moves1 = g.read_rapid(programs.to_rapid(abb_doc, start))[0]
    assert moves0[0].config[3] % 2 == 0 and moves1[0].config[3] % 2 == 1  # axis 5 positive / negative
    with pytest.raises(DataError, match="start_joints"):
        programs.to_rapid(abb_doc, programs.RapidSettings(robot_model="abb-irb2600", start_joints=(0.0, 0.0)))
