"""Algorithm 1 (gesture "joystick"): regions, dead-band, rate limits, capture and stop signs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from weldcell.hal.readings import HandsFrame, InteractionBox
from weldcell.hal.sim.hands import BOX_CENTER, REGION_OFFSET, HandScript, _hand, load_script
from weldcell.plugins.scan_plan.gesture import GestureScanController, GestureScanSettings, hand_rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "leap-motion-recordings"
CAM_DOWN = T_from_rpy([np.pi, 0, 0], [0.4, 0.0, 0.5])


def frame(stamp, left_region=None, rpy=(0, 0, 0), ok=False, fist=False, jitter=None):
    box = InteractionBox(BOX_CENTER.copy(), np.array([0.1, 0.1, 0.1]))
    hands = []
    if left_region is not None:
        pos = BOX_CENTER + REGION_OFFSET[left_region] + (np.zeros(3) if jitter is None else jitter)
        hands.append(_hand("left", pos, Rotation.from_euler("xyz", rpy, degrees=True), ok=False, fist=False))
    hands.append(_hand("right", BOX_CENTER + [0.12, 0, 0], Rotation.identity(), ok=ok, fist=fist))
    return HandsFrame(stamp=stamp, hands=tuple(hands), interaction_box=box)


def run(ctl, frames, T=CAM_DOWN):
    T = T.copy()
    cmds = []
    for f in frames:
        c = ctl.update(f, T)
        cmds.append(c)
        if c.target is not None:
            T = c.target
    return T, cmds


@pytest.mark.parametrize(
    "region,axis",
    [
        ("left", [-1, 0, 0]),
        ("right", [1, 0, 0]),
        ("up", [0, 0, 1]),
        ("down", [0, 0, -1]),
        ("inward", [0, 1, 0]),
        ("outward", [0, -1, 0]),
    ],
)
def test_each_region_moves_the_camera_along_its_direction_at_the_set_speed(region, axis):
    ctl = GestureScanController(GestureScanSettings(speed=0.06))
    T, cmds = run(ctl, [frame(i / 60, region) for i in range(120)])
    moved = T[:3, 3] - CAM_DOWN[:3, 3]
    active = sum(c.mode == "translate" for c in cmds)
    assert np.allclose(moved / np.linalg.norm(moved), axis, atol=1e-9)
    assert np.linalg.norm(moved) == pytest.approx(0.06 * active / 60, rel=1e-6)
    assert np.allclose(T[:3, :3], CAM_DOWN[:3, :3]), "translation must not rotate the camera"


def test_home_keeps_position_and_a_shaky_hand_does_not_move_the_robot():
    rng = np.random.default_rng(1)
    ctl = GestureScanController()
    T, cmds = run(ctl, [frame(i / 60, "home", jitter=rng.normal(0, 0.004, 3)) for i in range(240)])
    assert np.allclose(T[:3, 3], CAM_DOWN[:3, 3]), "a hand in home never translates the camera"
    assert {c.mode for c in cmds} <= {"idle", "rotate"}
    # once the camera has taken the hand's orientation, the tremor (inside the dead-band) commands nothing
    assert all(c.target is None for c in cmds[-100:])


def test_rotation_mode_aligns_the_camera_axis_with_the_palm_normal_rate_limited():
    s = GestureScanSettings(max_angular_speed=0.5)
    ctl = GestureScanController(s)
    T, cmds = run(ctl, [frame(i / 60, "home", rpy=(0, 0, 20)) for i in range(180)])
    hand = frame(0, "home", rpy=(0, 0, 20)).hand("left")
    z_expected = ctl.R_base_sensor @ hand_rotation(hand)[:, 2]
    assert np.allclose(T[:3, 3], CAM_DOWN[:3, 3]), "rotation mode keeps the camera position (Alg. 1 line 14)"
    assert np.degrees(np.arccos(np.clip(T[:3, 2] @ z_expected, -1, 1))) < 3.0
    steps = [c for c in cmds if c.target is not None]
    R_prev = CAM_DOWN[:3, :3]
    for c in steps:
        ang = np.linalg.norm(Rotation.from_matrix(R_prev.T @ c.target[:3, :3]).as_rotvec())
        assert ang <= 0.5 / 60 + 1e-9
        R_prev = c.target[:3, :3]


def test_ok_sign_captures_once_per_sign_and_fist_stops():
    ctl = GestureScanController(GestureScanSettings(ok_hold=0.1, stop_hold=0.3))
    frames = [frame(i / 60, "home", ok=True) for i in range(30)]  # held 0.5 s
    frames += [frame((30 + i) / 60, "home") for i in range(10)]
    frames += [frame((40 + i) / 60, "home", ok=True) for i in range(10)]
    _, cmds = run(ctl, frames)
    assert sum(c.capture for c in cmds) == 2
    first = next(i for i, c in enumerate(cmds) if c.capture)
    assert first >= 6, "ok must be held ok_hold seconds (debounce)"
    _, cmds = run(
        GestureScanController(GestureScanSettings(stop_hold=0.3)),
        [frame(i / 60, "home", fist=True) for i in range(30)],
    )
    stops = [i for i, c in enumerate(cmds) if c.stop]
    assert stops and stops[0] >= 18


def test_a_new_hand_must_be_tracked_a_few_frames_before_it_acts():
    ctl = GestureScanController(GestureScanSettings(min_visible_frames=5))
    _, cmds = run(ctl, [frame(i / 60, "right") for i in range(4)])
    assert all(c.target is None for c in cmds)


def test_survey_script_plays_and_bad_scripts_are_refused():
    steps = load_script("survey")
    player = HandScript(steps, rate=60)
    n = 0
    while not player.finished:
        player.next_frame(0.0)
        n += 1
    assert n == pytest.approx(player.duration * 60, abs=1)
    with pytest.raises(DataError, match="unknown hand script"):
        load_script("no-such-script")
    with pytest.raises(DataError, match="unknown region"):
        load_script([{"left": "sideways", "seconds": 1}])


@pytest.mark.data
def test_real_leap_recording_gives_bounded_smooth_targets():
    if not DATA.is_dir():
        pytest.skip(f"recorded data not found at {DATA}")
    leap = pytest.importorskip("weldcell.plugins.leap.playback")
    proto = pytest.importorskip("weldcell.plugins.leap.protocol")
    frames = [
        proto.frame_from_json(m, stamp=i / 115.0)
        for i, m in enumerate(leap.load_recording(DATA / "recordings" / "brian.json"))
    ]
    ctl = GestureScanController(GestureScanSettings(speed=0.05, max_angular_speed=0.8))
    T, cmds = run(ctl, frames)
    targets = [c.target for c in cmds if c.target is not None]
    assert any(f.hands for f in frames)
    prev = CAM_DOWN
    for tgt in targets:
        assert np.linalg.norm(tgt[:3, 3] - prev[:3, 3]) <= 0.05 * 0.1 + 1e-9  # speed x max dt
        prev = tgt
