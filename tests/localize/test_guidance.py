"""Guided placement (§III-B): the reachable envelope, fixture positions, the projector as an inverse camera
and its calibration from a projected dot pattern (cv2.calibrateCamera), every move through the gate."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.hal.kinematics import get_model
from weldcell.hal.readings import Intrinsics
from weldcell.hal.robot import RobotMotionSettings
from weldcell.hal.safety import SafetyGate
from weldcell.hal.sim.devices import SimProjector, SimRobot
from weldcell.hal.sim.world import SimWorld
from weldcell.plugins.localize import projector_calibration as pc
from weldcell.plugins.localize.guidance import (
    GuidanceSettings,
    centre_template,
    fixture_positions,
    guide_placement,
    reachable_envelope,
)
from weldcell.plugins.localize.template import Member, Template
from weldcell.plugins.localize.workpieces import make_workpiece
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import DataError, SafetyError
from weldcell.sdk.geometry import T_from_rpy

INTR = Intrinsics(848, 480, 1010.0, 1005.0, 430.0, 236.0)
T_FP_NOMINAL = T_from_rpy([0, 0, 0], [-0.08, 0.0, 0.05])
T_FP_TRUE = T_FP_NOMINAL @ T_from_rpy([0.01, -0.008, 0.02], [0.002, -0.003, 0.001])  # the bracket is off


def make_cell(box_max=(1.8, 1.0, 1.5), start_z: float = 0.95):
    model = get_model("abb-irb2600")
    world = SimWorld([])
    gate = SafetyGate(SafetyLimits(workspace_min=[0.2, -1, -0.05], workspace_max=list(box_max)), model=model)
    robot = SimRobot(
        model,
        world,
        name="robot",
        gate=gate,
        motion=RobotMotionSettings(tcp_xyz=(0, 0, 0.35), speed=0.25, accel=1.0),
        q_start=model.ik(T_from_rpy([np.pi, 0, 0], [1.0, 0.0, start_z]), model.home),
    )
    proj = SimProjector(world, T_FP_TRUE, parent="robot.flange", intrinsics=INTR)
    return robot, proj


def test_reachable_envelope_from_the_joint_limits_and_a_centred_part():
    robot, _ = make_cell()
    with robot:
        env = reachable_envelope(robot, 0.0, GuidanceSettings(envelope_step=0.1), height=0.16)
    ok = env.xy[env.reachable]
    r = np.linalg.norm(ok, axis=1)
    assert r.max() < 1.65 and r.min() > 0.3  # within the IRB 2600's reach, not at its foot
    assert env.contains(np.array([[1.0, 0.0]]))[0] and not env.contains(np.array([[0.25, 0.0]]))[0]
    tpl = make_workpiece("truss", center=(0.0, 0.0))
    placed, clear = centre_template(tpl, env, margin=0.04)
    assert clear >= 0.04
    pts = np.vstack([m.outline for m in placed.members])
    assert env.contains(pts).all()
    # the same part twice as large does not fit with the margin: refused, not planned out of reach
    big = Template([Member(m.id, m.top, m.outline * 3.0) for m in tpl.members])
    with pytest.raises(DataError, match="reachable envelope"):
        centre_template(big, env, margin=0.04)


def test_fixture_magnets_sit_on_each_members_outer_boundary():
    tpl = make_workpiece("ladder", center=(1.0, 0.0))
    for i, m in enumerate(tpl.members[:2]):  # the rails: magnets on their outer long side
        mags = fixture_positions(tpl, i, 0.03, 2)
        y_out = m.outline[:, 1].max() if m.outline[:, 1].mean() > tpl.centroid[1] else m.outline[:, 1].min()
        assert np.allclose(np.abs(mags[:, 1] - y_out), 0.015)
        assert np.all(np.abs(mags[:, 1] - tpl.centroid[1]) > np.abs(y_out - tpl.centroid[1]))
        assert np.ptp(mags[:, 0]) == pytest.approx(0.5, abs=1e-6)  # at 1/4 and 3/4 of the 1 m rail


def test_projector_calibration_from_a_dot_pattern_finds_the_mount():
    robot, proj = make_cell()
    with robot, proj:
        poses = pc.calibration_poses(np.array([1.0, 0.0]), 0.0, 0.6)
        views = pc.collect_views_sim(
            robot, proj, poses, T_FP_NOMINAL, pc.dot_pattern(848, 480), 0.3e-3, np.random.default_rng(0)
        )
    cal = pc.calibrate(views, (848, 480), 0.0, fix_distortion=True)
    assert cal.views == 8 and cal.rms_px < 1.5
    assert cal.K[0, 0] == pytest.approx(1010.0, rel=0.02) and cal.K[1, 2] == pytest.approx(236.0, abs=5)
    assert cal.landing_error_mean < 1e-3  # dots land within 1 mm of where the calibration predicts
    # the nominal mount was 3.8 mm and 1.4 deg off; the calibration is within 1 mm / 0.2 deg of the truth
    dR = cal.T_flange_projector[:3, :3].T @ T_FP_TRUE[:3, :3]
    assert np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))) < 0.2
    # the optical centre's position along the optical axis trades against the focal length: compare across
    lat = (cal.T_flange_projector[:3, 3] - T_FP_TRUE[:3, 3])[:2]
    assert np.linalg.norm(lat) < 1e-3
    with pytest.raises(DataError, match="views"):
        pc.calibrate(views[:2], (848, 480), 0.0)


def guide(robot, proj, calibration):
    tpl = make_workpiece("truss", center=(1.0, 0.0))
    proj.calibration = calibration
    said = []
    recs = guide_placement(
        robot, proj, tpl, calibration[1], calibration[0], (848, 480), GuidanceSettings(), said.append
    )
    return tpl, recs, said


def test_guidance_lands_the_outline_where_the_cad_says_once_calibrated():
    robot, proj = make_cell()
    with robot, proj:
        views = pc.collect_views_sim(
            robot,
            proj,
            pc.calibration_poses(np.array([1.0, 0.0]), 0.0, 0.6),
            T_FP_NOMINAL,
            pc.dot_pattern(848, 480),
            0.3e-3,
            np.random.default_rng(0),
        )
        cal = pc.calibrate(views, (848, 480), 0.0, fix_distortion=True)
        tpl, recs, said = guide(robot, proj, (cal.K, cal.T_flange_projector))
        _, uncal, _ = guide(robot, proj, (INTR.K, T_FP_NOMINAL))
    assert [r.id for r in recs] == [m.id for m in tpl.members]
    assert len(said) == 2 * len(tpl.members)  # the worker confirms the fixtures, then the outline
    assert "magnets" in said[0] and "outline" in said[1]
    assert all(r.confirmed == ["fixtures", "outline"] for r in recs)
    assert max(r.lit_error_mean for r in recs) < 1.0e-3
    assert min(r.lit_error_mean for r in uncal) > 2.0e-3  # the nominal mount puts the light mm off


def test_every_guidance_move_goes_through_the_safety_gate():
    robot, proj = make_cell(box_max=(1.8, 1.0, 0.25), start_z=0.5)  # the tool must stay below 250 mm
    with robot, proj:
        before = len(robot.trajectory)
        with pytest.raises(SafetyError, match="workspace box"):
            guide(robot, proj, (INTR.K, T_FP_NOMINAL))
        assert len(robot.trajectory) == before and proj.drawn == []
