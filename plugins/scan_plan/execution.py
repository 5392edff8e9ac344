"""Executing a weld path on the robot: every motion checked through the safety gate before anything is
sent (:func:`plan_execution`), then welded seam by seam as a resumable ``motion`` step (:func:`execute`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from weldcell.sdk.artifacts import sha256_file
from weldcell.sdk.errors import SafetyError
from weldcell.sdk.geometry import invert

EXECUTE = "execute weld path"
CHECK = "check weld path motions"


@dataclass
class SeamMotion:
    """The motions that weld one seam: a joint move (``q_high``; a linear move to ``high`` when the robot
    has no kinematic model) to a pose above the seam start, a linear move down to ``above``, then the
    torch poses and back out through ``above`` and ``high`` at weld speed."""

    seam_id: str
    q_high: np.ndarray | None
    high: np.ndarray
    above: np.ndarray
    path: np.ndarray


def plan_execution(robot, path, speed: float, approach: float) -> list[SeamMotion]:
    """Check every motion of executing ``path`` through the robot's safety gate, from the robot's current
    state, before anything is sent: one unreachable pose anywhere refuses the whole execution.

    Raises SafetyError naming the seam and the motion; the robot has not moved.
    """
    gate, T_ft = robot.gate, robot.T_flange_tcp
    st = robot.state()
    T_prev, q = st.T_base_tcp, st.q
    lin_speed, lin_accel = robot.motion.speed, robot.motion.accel
    plans = []
    for seam in path.seams:
        try:
            above = seam.poses[0].copy()
            above[:3, 3] -= approach * above[:3, 2]
            high = above.copy()  # the approach pose at the current height: joint moves stay clear of the part
            high[2, 3] = max(above[2, 3], min(T_prev[2, 3], above[2, 3] + 0.15))
            q_high = None
            if gate.model is not None:
                q_high = gate.solve(high @ invert(T_ft), q, f"approach of {seam.id}")
                gate.check_joint_move(  # exactly what Robot.move_joint checks
                    q,
                    q_high,
                    T_ft,
                    robot.motion.joint_speed,
                    robot.motion.joint_accel,
                    f"joint move to the approach of {seam.id}",
                )
                q = q_high
            else:
                q = gate.check_linear(T_prev, high, T_ft, lin_speed, lin_accel, q, f"approach of {seam.id}")
            q = gate.check_linear(high, above, T_ft, lin_speed, lin_accel, q, f"descent to {seam.id}")
            poses = np.concatenate([seam.poses, above[None], high[None]])
            T_seg = above
            for i, T in enumerate(poses):
                q = gate.check_linear(T_seg, T, T_ft, speed, robot.motion.accel, q, f"path segment {i}")
                T_seg = T
        except SafetyError as e:
            raise SafetyError(
                f"seam {seam.id} cannot be welded: {e.message}; nothing was sent to the robot", e.fix
            ) from None
        plans.append(SeamMotion(seam.id, q_high, high, above, poses))
        T_prev = high
    return plans


def execute(ctx, path, speed: float, approach: float) -> None:
    """Check the whole execution first (:func:`plan_execution`), then per seam: joint move above its
    start, down, and follow its torch poses (each command again through the safety gate).

    A ``motion`` step: done in an earlier attempt it is not repeated (nor checked again); interrupted part
    way it stops the resume (the part may be welded in part) until the operator asks ``--redo execute``.
    """
    robot = ctx.device("robot")
    if ctx.skip(EXECUTE):
        before = ctx.state.steps[EXECUTE].get("weld_path_sha256")
        if before and before != sha256_file(ctx.run_dir / "weld_path.json"):
            ctx.reporter.info(
                "[yellow]the weld path computed now differs from the one executed earlier; the earlier "
                "execution stands (--redo execute to weld this one)[/yellow]"
            )
        return
    with ctx.step(CHECK):
        plans = plan_execution(robot, path, speed, approach)
    with ctx.step(EXECUTE, total=len(plans), kind="motion") as advance:
        ctx.state.set_step(
            EXECUTE,
            weld_path_sha256=sha256_file(ctx.run_dir / "weld_path.json"),
            progress=f"0 of {len(plans)} seams welded",
        )
        for i, m in enumerate(plans):
            ctx.state.set_step(EXECUTE, progress=f"{i} of {len(plans)} seams welded, {m.seam_id} started")
            if m.q_high is not None:
                robot.move_joint(m.q_high)
            else:
                robot.move_linear(m.high)
            robot.move_linear(m.above)
            robot.follow_path(m.path, speed=speed)
            ctx.state.set_step(EXECUTE, progress=f"{i + 1} of {len(plans)} seams welded")
            advance(i + 1)
