"""Scripted hands for the simulated gesture sensor (Leap-like: metres, y up, sensor frame).

A script is a list of steps, each held for ``seconds``::

    {"left": "right", "seconds": 1.2}          # left palm in the interaction box's right region
    {"left": "home", "rpy": [0, 20, 0], "seconds": 0.6}   # home region, hand tilted (deg): rotation mode
    {"ok": true, "seconds": 0.3}                # right hand makes the "ok" sign (capture)
    {"fist": true, "seconds": 0.6}              # right hand closed: end of scan
    {"none": true, "seconds": 0.5}              # no hands in view

Regions are 'home', 'left', 'right', 'up', 'down', 'inward', 'outward'. A little tremor (1.5 mm,
0.8 deg) is added so the scan code's dead-band and filtering are exercised.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.hal.readings import Hand, HandsFrame, InteractionBox
from weldcell.sdk.errors import DataError

BOX_CENTER = np.array([0.0, 0.20, 0.0])
BOX_SIZE = np.array([0.10, 0.10, 0.10])
REGION_OFFSET = {
    "home": np.zeros(3),
    "left": np.array([-0.04, 0.0, 0.0]),
    "right": np.array([0.04, 0.0, 0.0]),
    "up": np.array([0.0, 0.04, 0.0]),
    "down": np.array([0.0, -0.04, 0.0]),
    "inward": np.array([0.0, 0.0, -0.04]),
    "outward": np.array([0.0, 0.0, 0.04]),
}
FINGERS = ("thumb", "index", "middle", "ring", "pinky")

BUILTIN_SCRIPTS: dict[str, list[dict]] = {
    # Survey a part from above and from four tilted views, capturing six clouds, then stop.
    "survey": [
        {"none": True, "seconds": 0.3},
        {"left": "home", "rpy": [0, 0, 0], "seconds": 0.4},
        {"ok": True, "seconds": 0.3},
        {"left": "left", "seconds": 0.9},
        {"left": "home", "rpy": [0, 0, 14], "seconds": 0.6},
        {"ok": True, "seconds": 0.3},
        {"left": "right", "seconds": 1.8},
        {"left": "home", "rpy": [0, 0, -14], "seconds": 0.6},
        {"ok": True, "seconds": 0.3},
        {"left": "left", "seconds": 0.9},
        {"left": "outward", "seconds": 0.7},
        {"left": "home", "rpy": [14, 0, 0], "seconds": 0.6},
        {"ok": True, "seconds": 0.3},
        {"left": "inward", "seconds": 1.4},
        {"left": "home", "rpy": [-14, 0, 0], "seconds": 0.6},
        {"ok": True, "seconds": 0.3},
        {"left": "outward", "seconds": 0.7},
        {"left": "up", "seconds": 0.5},
        {"left": "home", "rpy": [0, 0, 0], "seconds": 0.6},
        {"ok": True, "seconds": 0.3},
        {"fist": True, "seconds": 0.6},
    ],
    # A fillet T-joint (a web standing on a plate, its seams along base x): a top view, then one view
    # from each side of the web, lowered, moved 0.3 m sideways and tilted 35 deg toward the web, so the
    # camera sees the web face and the plate at each seam (the foot of the web) at 35-55 deg instead of
    # grazing. The hand keeps its tilt while it makes the "ok" sign (else the camera levels during the hold).
    "survey-sides": [
        {"none": True, "seconds": 0.3},
        {"left": "home", "rpy": [0, 0, 0], "seconds": 2.3},
        {"ok": True, "left": "home", "rpy": [0, 0, 0], "seconds": 0.3},
        {"left": "down", "seconds": 1.9},
        {"left": "outward", "seconds": 3.7},
        {"left": "home", "rpy": [35, 0, 0], "seconds": 1.1},
        {"ok": True, "left": "home", "rpy": [35, 0, 0], "seconds": 0.3},
        {"left": "inward", "seconds": 7.4},
        {"left": "home", "rpy": [-35, 0, 0], "seconds": 1.9},
        {"ok": True, "left": "home", "rpy": [-35, 0, 0], "seconds": 0.3},
        {"fist": True, "seconds": 0.6},
    ],
    # One capture from where the robot starts.
    "single": [
        {"left": "home", "rpy": [0, 0, 0], "seconds": 0.3},
        {"ok": True, "seconds": 0.3},
        {"fist": True, "seconds": 0.6},
    ],
}


@dataclass
class _Pose:
    left_region: str | None
    left_rpy_deg: np.ndarray
    ok: bool
    fist: bool


def load_script(spec: str | list[dict]) -> list[dict]:
    """A built-in script by name, a JSON file path, or an explicit list; validated."""
    if isinstance(spec, list):
        steps = spec
    elif spec in BUILTIN_SCRIPTS:
        steps = BUILTIN_SCRIPTS[spec]
    elif Path(spec).suffix == ".json" and Path(spec).is_file():
        steps = json.loads(Path(spec).read_text())
    else:
        raise DataError(
            f"unknown hand script {spec!r}",
            f"use one of {', '.join(BUILTIN_SCRIPTS)} or a .json file of steps",
        )
    for i, st in enumerate(steps):
        if not isinstance(st, dict) or float(st.get("seconds", 0)) <= 0:
            raise DataError(
                f"hand script step {i} needs a positive 'seconds'", 'e.g. {"ok": true, "seconds": 0.3}'
            )
        if "left" in st and st["left"] not in REGION_OFFSET:
            raise DataError(
                f"hand script step {i}: unknown region {st['left']!r}",
                f"use one of {', '.join(REGION_OFFSET)}",
            )
    return steps


class HandScript:
    """Plays a script as :class:`HandsFrame` s at ``rate`` Hz of simulated time."""

    def __init__(self, steps: list[dict], rate: float = 60.0, tremor: float = 0.0015, seed: int = 0) -> None:
        self.steps = steps
        self.rate = rate
        self.tremor = tremor
        self.rng = np.random.default_rng(seed)
        self.ends = np.cumsum([float(s["seconds"]) for s in steps])
        self.index = 0

    @property
    def duration(self) -> float:
        return float(self.ends[-1]) if len(self.ends) else 0.0

    @property
    def finished(self) -> bool:
        return self.index / self.rate >= self.duration

    def _pose_at(self, t: float) -> _Pose:
        k = int(np.searchsorted(self.ends, t, side="right"))
        st = self.steps[min(k, len(self.steps) - 1)]
        if st.get("none"):
            return _Pose(None, np.zeros(3), False, False)
        region = st.get("left", "home")
        return _Pose(
            region,
            np.asarray(st.get("rpy", [0, 0, 0]), dtype=float),
            bool(st.get("ok")),
            bool(st.get("fist")),
        )

    def next_frame(self, stamp: float) -> HandsFrame:
        t = self.index / self.rate
        self.index += 1
        pose = self._pose_at(t)
        box = InteractionBox(BOX_CENTER.copy(), BOX_SIZE.copy())
        if pose.left_region is None:
            return HandsFrame(stamp=stamp, hands=(), frame_id=self.index, interaction_box=box)
        jitter = self.rng.normal(0.0, self.tremor, 3)
        rot = Rotation.from_euler("xyz", pose.left_rpy_deg + self.rng.normal(0.0, 0.8, 3), degrees=True)
        left = _hand("left", BOX_CENTER + REGION_OFFSET[pose.left_region] + jitter, rot, ok=False, fist=False)
        right_pos = BOX_CENTER + np.array([0.12, 0.0, 0.0]) + self.rng.normal(0.0, self.tremor, 3)
        right = _hand("right", right_pos, Rotation.identity(), ok=pose.ok, fist=pose.fist)
        return HandsFrame(stamp=stamp, hands=(left, right), frame_id=self.index, interaction_box=box)


def _hand(side: str, palm: np.ndarray, rot: Rotation, ok: bool, fist: bool) -> Hand:
    """A hand with palm down (normal -y), fingers toward -z (the screen), rotated by ``rot``."""
    normal = rot.apply([0.0, -1.0, 0.0])
    direction = rot.apply([0.0, 0.0, -1.0])
    sign = -1.0 if side == "left" else 1.0
    offsets = {
        "thumb": [sign * -0.045, 0.0, -0.03],
        "index": [sign * -0.02, 0.0, -0.085],
        "middle": [0.0, 0.0, -0.09],
        "ring": [sign * 0.02, 0.0, -0.085],
        "pinky": [sign * 0.038, 0.0, -0.07],
    }
    extended = dict.fromkeys(FINGERS, True)
    if ok:  # thumb and index tips touch, the other three fingers stay extended
        offsets["thumb"] = offsets["index"] = [sign * -0.03, -0.01, -0.05]
        extended["index"] = False
    if fist:
        offsets = {f: [o[0] * 0.5, -0.02, -0.03] for f, o in offsets.items()}
        extended = dict.fromkeys(FINGERS, False)
    tips = {f: palm + rot.apply(o) for f, o in offsets.items()}
    return Hand(
        side=side,
        palm_position=palm,
        palm_normal=normal,
        direction=direction,
        grab_strength=1.0 if fist else 0.0,
        pinch_strength=1.0 if ok else 0.0,
        fingertips=tips,
        extended=extended,
    )
