"""Leap Motion WebSocket frames (protocol v6, "v6.json") -> weldcell readings.

A frame is JSON with ``hands[]`` (``id``, ``type`` 'left'/'right', ``palmPosition``, ``palmNormal``,
``direction``, ``grabStrength``, ``pinchStrength``, ``confidence``, ``timeVisible``), ``pointables[]``
(``handId``, ``type`` 0..4 = thumb..pinky, ``tipPosition``, ``extended``) and ``interactionBox``
(``center``, ``size``). Units are millimetres in the Leap frame (origin at the sensor, y up, z toward
the user); weldcell readings are metres in the same axes.
"""

from __future__ import annotations

import numpy as np
from weldcell.hal.readings import Hand, HandsFrame, InteractionBox
from weldcell.sdk.errors import DataError

FINGERS = ("thumb", "index", "middle", "ring", "pinky")
MM = 1e-3


def _vec(v, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise DataError(f"Leap frame has a bad {what}: {v!r}", "check that the service speaks protocol v6")
    return a


def _unit(v, what: str) -> np.ndarray:
    a = _vec(v, what)
    n = np.linalg.norm(a)
    return a / n if n > 0 else a


def finger_type(p: dict) -> int | None:
    """Finger index 0..4 of a pointable: its ``type``, else the v2 id rule ``id = handId * 10 + type``."""
    t = p.get("type")
    if isinstance(t, int) and 0 <= t <= 4:
        return t
    pid, hid = p.get("id"), p.get("handId")
    if isinstance(pid, int) and isinstance(hid, int) and 0 <= pid - 10 * hid <= 4:
        return pid - 10 * hid
    return None


def hand_from_json(h: dict, pointables: list[dict]) -> Hand:
    """One hand, with its fingertips from the pointables whose ``handId`` is the hand's id."""
    side = h.get("type")
    if side not in ("left", "right"):
        raise DataError(
            f"Leap hand has type {side!r}, expected 'left' or 'right'", "check the protocol version"
        )
    tips: dict[str, np.ndarray] = {}
    ext: dict[str, bool] = {}
    for p in pointables:
        if p.get("handId") != h.get("id") or p.get("tool"):
            continue
        k = finger_type(p)
        if k is None or "tipPosition" not in p:
            continue
        tips[FINGERS[k]] = _vec(p["tipPosition"], "tipPosition") * MM
        if "extended" in p:
            ext[FINGERS[k]] = bool(p["extended"])
    return Hand(
        side=side,
        palm_position=_vec(h["palmPosition"], "palmPosition") * MM,
        palm_normal=_unit(h["palmNormal"], "palmNormal"),
        direction=_unit(h["direction"], "direction"),
        grab_strength=float(h.get("grabStrength", 0.0)),
        pinch_strength=float(h.get("pinchStrength", 0.0)),
        fingertips=tips,
        extended=ext,
        confidence=float(h.get("confidence", 1.0)),
        time_visible=float(h.get("timeVisible", 0.0)),
    )


def is_frame(msg: dict) -> bool:
    """A tracking frame (the first message of a connection is the service's version instead)."""
    return isinstance(msg, dict) and "hands" in msg and "id" in msg


def frame_from_json(msg: dict, stamp: float, frame: str = "gesture") -> HandsFrame:
    """A :class:`HandsFrame` (metres) from one v6 JSON frame received at host time ``stamp``."""
    if not is_frame(msg):
        raise DataError("message is not a Leap tracking frame (no 'hands'/'id')", "check the service URL")
    pointables = msg.get("pointables") or []
    hands = tuple(hand_from_json(h, pointables) for h in msg["hands"])
    box = None
    ib = msg.get("interactionBox")
    if ib:
        box = InteractionBox(
            center=_vec(ib["center"], "interactionBox.center") * MM,
            size=_vec(ib["size"], "interactionBox.size") * MM,
        )
    return HandsFrame(stamp=stamp, hands=hands, frame_id=int(msg["id"]), interaction_box=box, frame=frame)
