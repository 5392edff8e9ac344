"""Calibration poses the robot can take: every planned pose is checked the way the job's move checks it
(the TCP inside the cell's workspace box and reach, an IK solution inside the joint limits) before the
robot is asked, and a pose that fails is replaced by one drawn between it and the box centre.

The plan itself (:func:`weldcell.plugins.handeye.job.plan_poses`: a grid over the pose box, the flange
facing the camera, bounded random tilts) spans the whole box; where the box reaches past the robot's
reach or the cell's workspace (cell 2's box with the tactile finger's 0.3 m TCP, cell 1's far corner for
a UR5), those nodes used to be refused one by one during the run. Replacing them up front keeps the
number of poses and the spread of the plan: the replacement keeps the node's direction from the box
centre, as far out as the robot allows, with the same tilt bounds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from weldcell.sdk.errors import JobError, SafetyError


@dataclass(frozen=True)
class PoseCheck:
    """A robot's gate, tool and joint speed: :meth:`reach` says whether the move the job makes to a flange
    pose would pass (TCP in the workspace box and reach; with a model, the IK solution nearest the
    previous joints inside the limits and the TCP inside the box all along the joint move)."""

    gate: object
    T_flange_tcp: np.ndarray
    joint_speed: float = 0.5
    joint_accel: float = 1.0

    def reach(self, T_base_flange: np.ndarray, q_prev=None) -> tuple[str | None, np.ndarray | None]:
        """``(None, joints)`` when the move from ``q_prev`` (None: the pose alone) to the pose passes,
        else ``(the gate's reason, None)``."""
        T_tcp = np.asarray(T_base_flange, dtype=float) @ self.T_flange_tcp
        try:
            self.gate.check_point(T_tcp[:3, 3], "calibration pose")
            if getattr(self.gate, "model", None) is None:
                return None, None  # the job moves linearly: both ends in the (convex) box
            q = self.gate.solve(T_base_flange, q_prev, "calibration pose")
            if q_prev is not None:
                self.gate.check_joint_move(
                    q_prev, q, self.T_flange_tcp, self.joint_speed, self.joint_accel, "joint move"
                )
        except SafetyError as e:
            return e.message, None
        return None, q

    def why_not(self, T_base_flange: np.ndarray) -> str | None:
        """The gate's reason to refuse the pose itself (None: it would accept it)."""
        return self.reach(T_base_flange)[0]


@dataclass
class Replacement:
    """One planned pose that the robot could not take and what replaced it."""

    index: int
    reason: str
    moved: float  # how far the replacement's position moved toward the box centre [m]


def replace_unreachable(
    poses: np.ndarray,
    centre: np.ndarray,
    draw: Callable[[np.ndarray, int], np.ndarray],
    check: PoseCheck,
    seed: int,
    *,
    to_flange: np.ndarray | None = None,
    start=None,
    attempts: int = 40,
) -> tuple[np.ndarray, list[Replacement]]:
    """``poses`` (n, 4, 4) as planned (flange poses; eye-in-hand: camera poses, ``to_flange`` the
    camera-to-flange transform ``inv(T_flange_camera)``), visited in order from the joints ``start``,
    with each one whose move ``check`` refuses replaced by ``draw(position, seed)`` (a new planned pose at
    ``position``, as the planner makes them) at positions stepped from the refused pose's toward
    ``centre``: the first one whose move passes. Deterministic for a seed and start. Raises
    :class:`JobError` when a pose has no reachable replacement even at the centre (the box does not fit
    the robot or the workspace)."""
    post = np.eye(4) if to_flange is None else np.asarray(to_flange, dtype=float)
    out = np.array(poses, dtype=float)
    done: list[Replacement] = []
    q = None if start is None else np.asarray(start, dtype=float)
    for i, T in enumerate(out):
        why, q_new = check.reach(T @ post, q)
        if why is not None:
            p0 = T[:3, 3]
            for k in range(1, attempts + 1):
                s = 1.0 - k / attempts  # from next to the node to the centre itself
                cand = draw(centre + s * (p0 - centre), seed * 1009 + i * 97 + k)
                bad, q_new = check.reach(cand @ post, q)
                if bad is None:
                    out[i] = cand
                    done.append(Replacement(i, why, float((1.0 - s) * np.linalg.norm(p0 - centre))))
                    break
            else:
                raise JobError(
                    f"calibration pose {i} cannot be reached, nor any pose between it and the centre of "
                    f"the pose box: {why}",
                    "move [job.settings] box_min/box_max inside the robot's reach and the cell's workspace "
                    "box (with the tool mounted), or lower max_tilt",
                )
        q = q_new if q_new is not None else q
    return out, done


__all__ = ["PoseCheck", "Replacement", "replace_unreachable"]
