"""The robot configuration of a joint vector in each controller's own terms (docs/exporters.md).

A Cartesian target reaches up to 8 joint solutions of a 6-axis arm (times the extra turns of axes with
more than 360 degrees of travel); the controller picks one from the configuration written beside the
pose. The exporters write the configuration of the joints the safety gate tracked along the planned path
(:func:`.plan.check_plan`: the first approach from the robot's home joints, every later pose the IK
solution nearest the previous joints), so the controller runs the branch the plan was checked on.

Two geometric facts of a spherical-wrist arm (axes 4, 5, 6 meeting at the wrist centre) decide the
shoulder and elbow branches; they are computed from the robot model alone (joint axes from its
Jacobian), whatever the model's joint signs:

* *wrist centre in front of axis 1*: positive x of the axis-1 coordinate system (the base frame at
  axis 1 = 0, turning with axis 1);
* *wrist centre in front of the lower arm*: on the front side of the line through axes 2 and 3 (the
  side the arm faces with the lower arm upright; elbow up).

The wrist branch and the turns are read from joint values, so they need the vendor's joint signs: a
model follows vendor V's convention when its name starts with ``V-`` (``abb-irb2600``; the tables of
:mod:`weldcell.hal.robot_models` store the joint values the controller reports).

* **ABB** confdata ``[cf1, cf4, cf6, cfx]``: cf1/cf4/cf6 = quadrant of axes 1/4/6, ``floor(q / 90 deg)``
  (0 for 0..90, -1 for -90..0, 1 for 90..180, ...); cfx = 4 x (wrist centre behind axis 1)
  + 2 x (behind the lower arm) + (axis 5 negative) (RAPID reference, data type confdata).
* **KUKA** E6POS ``S`` (Status) bits: 0 = overhead area (wrist centre at negative x of the A1 system),
  1 = A3 at or past the stretched position (wrist centre in front of the line A2-A3), 2 = A5 in
  [-180, 0) deg (mod 360); ``T`` (Turn) bit i = axis i+1 negative (KSS 8 expert programming manual).
* **FANUC** ``CONFIG : 'F|N U|D T|B, t1, t4, t6'``: F(lip) when J5 > 0 (N with the common wrist-down
  pose J5 = -90), U(p) when the elbow is up (wrist centre in front of the lower arm), T(op/front) when
  the wrist centre is in front of J1, B(ack) otherwise; turn numbers of J1, J4, J6 = 0 for
  -180 < J <= 180, 1 for 180 < J <= 540, -1 for -540 < J <= -180.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

VENDORS = ("abb", "kuka", "fanuc")
_Q = math.pi / 2


@dataclass(frozen=True)
class Posture:
    """The branch-deciding geometry of one joint vector (see the module docstring)."""

    front_of_axis1: bool
    front_of_lower_arm: bool


def vendor_of(model) -> str | None:
    """The controller vendor whose joint convention ``model`` follows, or None (unknown convention, or an
    arm without a spherical wrist, for which the three vendors' configuration bits are not defined)."""
    if model is None or getattr(model, "dof", 0) != 6 or getattr(model, "ik_method", "") != "spherical-wrist":
        return None
    head = str(model.name).split("-", 1)[0].lower()
    return head if head in VENDORS else None


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (..., 3) arrays (numpy's is slow on small arrays)."""
    return np.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def _axes(model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit joint axes (6, 3) and a point on each (6, 3), base frame, at joints ``q``."""
    F, J = model.fk_jacobian(q) if hasattr(model, "fk_jacobian") else (model.fk(q), model.jacobian(q))
    h = J[3:].T
    return h, F[:3, 3] - _cross(J[:3].T, h)  # v = h x (pe - p)  =>  (pe - p) off the axis = v x h


def _meet(p1, h1, p2, h2) -> np.ndarray:
    """Midpoint of the closest points of two non-parallel lines."""
    w = p1 - p2
    b = float(h1 @ h2)
    den = max(1.0 - b * b, 1e-12)
    s = (b * float(h2 @ w) - float(h1 @ w)) / den
    t = (float(h2 @ w) - b * float(h1 @ w)) / den
    return 0.5 * (p1 + s * h1 + p2 + t * h2)


def _turned(v: np.ndarray, k: np.ndarray, angle: float) -> np.ndarray:
    """``v`` turned by ``angle`` about the unit axis ``k`` (Rodrigues)."""
    c, s = math.cos(angle), math.sin(angle)
    return v * c + _cross(k, v) * s + k * float(k @ v) * (1.0 - c)


def posture(model, q) -> Posture:
    """Where the wrist centre of ``model`` at joints ``q`` (rad) lies: in front of axis 1, in front of the
    lower arm. The same for ``q`` and ``q`` plus whole turns of any joint."""
    q = np.asarray(q, dtype=float)
    h, p = _axes(model, q)
    wrist = _meet(p[3], h[3], p[4], h[4])
    h1 = h[0] if h[0][2] >= 0 else -h[0]  # axis 1, pointing up
    x_a1 = _turned(np.array([1.0, 0.0, 0.0]), h[0], q[0])  # base x at axis 1 = 0, turning with axis 1
    x_a1 = x_a1 - (x_a1 @ h1) * h1
    front1 = float((wrist - p[0]) @ x_a1) > 0.0
    h2 = h[1] if _cross(h[1], h1) @ x_a1 >= 0 else -h[1]  # oriented so that h2 x up = forward
    u = p[2] - p[1]
    u = u - (u @ h2) * h2
    n = _cross(h2, u / max(float(np.linalg.norm(u)), 1e-12))  # the lower arm's front normal (arm plane)
    front2 = float((wrist - p[1]) @ n) > 0.0
    return Posture(front1, front2)


def _abb(q: np.ndarray, pos: Posture) -> tuple[int, int, int, int]:
    cfx = 4 * (not pos.front_of_axis1) + 2 * (not pos.front_of_lower_arm) + int(q[4] < 0.0)
    return math.floor(q[0] / _Q), math.floor(q[3] / _Q), math.floor(q[5] / _Q), cfx


def _kuka(q: np.ndarray, pos: Posture) -> tuple[int, int]:
    a5 = math.degrees(q[4]) % 360.0
    status = int(not pos.front_of_axis1) + 2 * int(pos.front_of_lower_arm) + 4 * int(a5 >= 180.0)
    return status, sum(1 << i for i in range(6) if q[i] < 0.0)


def fanuc_turn(angle: float) -> int:
    """FANUC turn number of a joint angle (rad): 0 for (-180, 180] deg, 1 for (180, 540], -1 for
    (-540, -180]."""
    return math.ceil((angle - math.pi) / (2 * math.pi) - 1e-12)


def _fanuc(q: np.ndarray, pos: Posture) -> str:
    flip = "F" if q[4] > 0.0 else "N"
    up = "U" if pos.front_of_lower_arm else "D"
    top = "T" if pos.front_of_axis1 else "B"
    return f"{flip} {up} {top}, {fanuc_turn(q[0])}, {fanuc_turn(q[3])}, {fanuc_turn(q[5])}"


_FROM_POSTURE = {"abb": _abb, "kuka": _kuka, "fanuc": _fanuc}


def abb_confdata(model, q) -> tuple[int, int, int, int]:
    """ABB RAPID confdata ``(cf1, cf4, cf6, cfx)`` of joints ``q`` (rad, ABB joint signs)."""
    q = np.asarray(q, dtype=float)
    return _abb(q, posture(model, q))


def kuka_status_turn(model, q) -> tuple[int, int]:
    """KUKA E6POS ``(S, T)`` of joints ``q`` (rad, KUKA joint signs)."""
    q = np.asarray(q, dtype=float)
    return _kuka(q, posture(model, q))


def fanuc_config(model, q) -> str:
    """FANUC CONFIG string ``'N U T, 0, 0, 0'`` of joints ``q`` (rad, FANUC joint signs)."""
    q = np.asarray(q, dtype=float)
    return _fanuc(q, posture(model, q))


CONFIG_OF = {"abb": abb_confdata, "kuka": kuka_status_turn, "fanuc": fanuc_config}


def plan_configs(plan, vendor: str) -> tuple[list | None, str]:
    """The configuration of every motion of a checked plan in ``vendor``'s terms and a note saying where
    it comes from; ``(None, why not)`` when the plan was not checked with a robot model that follows the
    vendor's joint convention."""
    model = getattr(plan, "model", None)
    if model is None:
        return None, "robot unknown (set robot_model)"
    if vendor_of(model) != vendor:
        return None, f"robot model {model.name} does not follow {vendor.upper()}'s joint convention"
    if vendor == "kuka" and np.any(np.abs(model.joint_limits) > 2 * math.pi + 1e-9):
        return None, f"{model.name} has axes past +-360 deg, which KUKA's Turn bits cannot tell apart"
    if len(plan.joints) != len(plan.motions):
        return None, "the plan holds no joints for some motions"
    f = CONFIG_OF[vendor]
    return [f(model, q) for q in plan.joints], f"computed from the IK of {model.name} along the checked path"


def _turns(model, q: np.ndarray) -> list[np.ndarray]:
    """``q`` with every combination of whole turns that keeps each joint inside its limits."""
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    options = []
    for j in range(model.dof):
        base = q[j] - 2 * math.pi * math.floor((q[j] - lo[j] + 1e-9) / (2 * math.pi))
        options.append([v for v in np.arange(base, hi[j] + 1e-9, 2 * math.pi) if v >= lo[j] - 1e-9])
    return [np.array(c) for c in itertools.product(*options)]


def solutions(model, T_base_flange) -> np.ndarray:
    """Every joint solution (k, 6) of the flange pose inside the joint limits, with every extra turn of
    the axes that travel more than 360 degrees (what a configuration has to choose among)."""
    out = [v for q in model.ik_all(T_base_flange, within_limits_only=False) for v in _turns(model, q)]
    return np.array(out).reshape(-1, model.dof)


def select(model, T_base_flange, vendor: str, config) -> np.ndarray:
    """The joint solutions (k, 6) of the flange pose whose ``vendor`` configuration is ``config``: what
    the controller chooses from (k = 1 when the configuration is unambiguous)."""
    f = _FROM_POSTURE[vendor]
    out = []
    for q in model.ik_all(T_base_flange, within_limits_only=False):
        pos = posture(model, q)  # whole turns do not change the posture
        out += [v for v in _turns(model, q) if f(v, pos) == config]
    return np.array(out).reshape(-1, model.dof)


__all__ = [
    "CONFIG_OF",
    "Posture",
    "VENDORS",
    "abb_confdata",
    "fanuc_config",
    "fanuc_turn",
    "kuka_status_turn",
    "plan_configs",
    "posture",
    "select",
    "solutions",
    "vendor_of",
]
