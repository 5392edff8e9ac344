"""RAPID data values as RWS reads and writes them (text), and ABB pose conventions.

ABB poses are millimetres with quaternions [q1, q2, q3, q4] = [w, x, y, z]; joint targets are degrees.
weldcell is SI with quaternions [x, y, z, w]: everything is converted here, at the edge.
No vendor import: the peers in the tests use the same helpers to read what the adapter wrote.
"""

from __future__ import annotations

import json
import re

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import make_T

EXT_UNUSED = 9e9
"""RAPID's value for an unused external axis."""

_BOOL = re.compile(r"\b(TRUE|FALSE)\b")


def parse_value(text: str):
    """A RAPID aggregate value (``[[1,2,3],[1,0,0,0],...]``, numbers, TRUE/FALSE) as nested Python lists."""
    try:
        return json.loads(_BOOL.sub(lambda m: m.group(1).lower(), text.strip()))
    except (json.JSONDecodeError, TypeError) as e:
        raise DataError(f"cannot parse RAPID value {text[:80]!r}: {e}", "check the RAPID data type") from e


def quat_wxyz_from_R(R: np.ndarray) -> np.ndarray:
    """ABB quaternion [w, x, y, z] of a rotation matrix, with w >= 0."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    q = np.array([w, x, y, z])
    return -q if q[0] < 0 else q


def T_from_abb(pos_mm, quat_wxyz) -> np.ndarray:
    """A 4x4 pose (m) from ABB's position [mm] and quaternion [w, x, y, z]."""
    q = np.asarray(quat_wxyz, dtype=float)
    n = float(np.linalg.norm(q))
    if not np.isfinite(n) or n < 1e-6:
        raise DataError(f"invalid ABB quaternion {q.tolist()}", "the controller sent a zero quaternion")
    R = Rotation.from_quat(q[[1, 2, 3, 0]] / n).as_matrix()
    return make_T(R, np.asarray(pos_mm, dtype=float) / 1000.0)


def T_to_abb(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ABB position [mm] and quaternion [w, x, y, z] of a 4x4 pose (m)."""
    T = np.asarray(T, dtype=float)
    return T[:3, 3] * 1000.0, quat_wxyz_from_R(T[:3, :3])


def _nums(v, fmt: str) -> str:
    return ",".join(format(float(x), fmt) for x in v)


def robtarget(T: np.ndarray, conf=(0, 0, 0, 0)) -> str:
    """RAPID ``robtarget`` text of a flange pose (base frame; configuration unused: ConfL\\Off)."""
    p, q = T_to_abb(T)
    ext = ",".join(["9E+09"] * 6)
    return f"[[{_nums(p, '.4f')}],[{_nums(q, '.8f')}],[{','.join(str(int(c)) for c in conf)}],[{ext}]]"


def robtarget_to_T(value) -> np.ndarray:
    """Flange pose (m) of a parsed or textual RAPID ``robtarget``."""
    v = parse_value(value) if isinstance(value, str) else value
    return T_from_abb(v[0], v[1])


def jointtarget(q_rad) -> str:
    """RAPID ``jointtarget`` text of joint angles (rad -> deg)."""
    q = np.degrees(np.asarray(q_rad, dtype=float))
    if q.shape != (6,):
        raise DataError(f"an IRB joint target has 6 axes, got {q.shape}", "pass 6 joint angles")
    return f"[[{_nums(q, '.5f')}],[{','.join(['9E+09'] * 6)}]]"


def speeddata(v_tcp: float, v_ori: float, v_leax: float = 5000.0, v_reax: float = 1000.0) -> str:
    """RAPID ``speeddata`` from TCP speed [m/s] and reorientation speed [rad/s]."""
    return f"[{v_tcp * 1000.0:.3f},{np.degrees(v_ori):.3f},{v_leax:.1f},{v_reax:.1f}]"


def zonedata(blend: float) -> str:
    """RAPID ``zonedata`` for a blend radius [m]: ``fine`` (stop point) at 0, else a fly-by zone."""
    if blend <= 0:
        return "[TRUE,0,0,0,0,0,0]"
    pz = blend * 1000.0
    return f"[FALSE,{pz:.3f},{1.5 * pz:.3f},{1.5 * pz:.3f},{0.15 * pz:.3f},{1.5 * pz:.3f},{0.15 * pz:.3f}]"


def array(items: list[str], size: int) -> str:
    """A RAPID array value of exactly ``size`` items (padded with the last item)."""
    if not items or len(items) > size:
        raise DataError(f"{len(items)} items do not fit a RAPID array of {size}", "split the data")
    return "[" + ",".join(items + [items[-1]] * (size - len(items))) + "]"
