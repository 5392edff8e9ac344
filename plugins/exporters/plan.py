"""What every robot-program exporter emits, independent of the language: the motion plan of a weld path.

Per seam (in the planned order): an approach pose ``retract`` metres back along the torch's -z, a move
to the first weld pose (stop, arc on), the weld poses reduced by :func:`~.reduce.reduce_poses` with blend
radii that never overlap (:func:`weldcell.hal.safety.path_blends`, zero at arc start and arc end), arc
off at the last weld pose, and a retract. The first approach of the program is a joint move (the robot
starts wherever it stands); every other move is linear. :func:`check_plan` replays the plan through the
cell's safety gate with the robot model, so no exported program holds a motion the gate would refuse.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
from pydantic import Field
from weldcell.hal.safety import SafetyGate, path_blends
from weldcell.sdk.cell import SafetyLimits
from weldcell.sdk.errors import DataError, SafetyError
from weldcell.sdk.geometry import T_from_rpy, invert
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Acceleration, Angle, Length
from weldcell.sdk.weldpath import WeldPath

from .reduce import Reduction, reduce_poses


class ProgramSettings(Settings):
    """Settings every robot-program exporter shares (reduction, tool, approach, safety check)."""

    retract: Length = Field(0.05, ge=0, description="approach/retract distance along -z of the torch [m]")
    accel: Acceleration = Field(0.5, gt=0, description="TCP acceleration [m/s^2]")
    reduce: bool = Field(True, description="drop poses the interpolated path does not need (see tolerance)")
    tolerance: Length = Field(1e-4, gt=0, description="largest TCP deviation of the reduced path [m]")
    angle_tolerance: Angle = Field(
        math.radians(0.5), gt=0, description="largest torch orientation deviation of the reduced path [rad]"
    )
    tcp_xyz: tuple[Length, Length, Length] | None = Field(
        None,
        description="torch TCP offset from the flange (the cell's torch calibration) [m]; "
        "unset: a zero tool is declared and the program says so",
    )
    tcp_rpy: tuple[Angle, Angle, Angle] = Field(
        (0.0, 0.0, 0.0), description="TCP rotation from the flange [rad]"
    )
    robot_model: str | None = Field(
        None,
        description="robot model (weldcell.hal.kinematics, e.g. 'ur5', 'abb-irb2600'): every "
        "motion is checked through the safety gate with it before the program is written",
    )
    safety: SafetyLimits = Field(default_factory=SafetyLimits, description="the cell's motion limits")
    start_joints: tuple[float, ...] | None = Field(
        None,
        description="joints the robot starts the program from [rad] (default: the model's home): the first "
        "approach is checked from them and the configurations written follow the IK solutions nearest them",
    )


@dataclass(frozen=True)
class Motion:
    """One programmed move to a TCP pose (path frame)."""

    kind: str  # "joint" | "linear"
    pose: np.ndarray
    speed: float  # m/s (joint moves: the TCP speed the language's joint move is given)
    blend: float  # m, 0 = stop at the pose
    process: str = "move"  # "move" | "arc_start" (arc on after reaching the pose) | "weld" | "arc_end"


@dataclass
class SeamPlan:
    id: str
    joint: str
    length: float
    weld_speed: float
    motions: list[Motion]
    reduction: Reduction
    routine: str = ""  # the routine's name: an identifier every language accepts, unique in the program


@dataclass
class ProgramPlan:
    """The motions of a whole program, the achieved reduction deviation and what was left out."""

    seams: list[SeamPlan]
    frame: str
    T_flange_tcp: np.ndarray
    tcp_given: bool
    skipped: list[str] = field(default_factory=list)
    checked_with: str | None = None
    model: object | None = None  # the RobotModel the plan was checked with
    joints: list[np.ndarray] = field(default_factory=list)  # per motion: the joints the gate tracked

    @property
    def max_position_error(self) -> float:
        return max((s.reduction.max_position_error for s in self.seams), default=0.0)

    @property
    def max_angle_error(self) -> float:
        return max((s.reduction.max_angle_error for s in self.seams), default=0.0)

    @property
    def motions(self) -> list[Motion]:
        return [m for s in self.seams for m in s.motions]

    def header(self, configuration: str, without_tcp: str = "a zero tool is declared") -> list[str]:
        """Comment lines every program starts with (without the comment marker); ``configuration`` says how
        the language's robot configuration is handled (computed from the robot model's IK, or why not),
        ``without_tcp`` what the program does when no TCP was given."""
        n_planned = sum(s.reduction.n_planned for s in self.seams)
        n_kept = sum(len(s.reduction.poses) for s in self.seams)
        out = [
            f"generated by weldcell: {len(self.seams)} seam(s), frame '{self.frame}'",
            f"path reduction: {n_kept} of {n_planned} planned poses kept; max deviation "
            f"{self.max_position_error * 1000:.3f} mm, {math.degrees(self.max_angle_error):.3f} deg",
            f"configuration: {configuration}",
        ]
        if not self.tcp_given:
            out.append(f"WARNING: no torch TCP given (tcp_xyz): {without_tcp}; the check assumed a zero tool")
        out.append(
            f"checked through the safety gate with robot model {self.checked_with}"
            if self.checked_with
            else "NOT checked against a robot model (set robot_model to check reach, limits and speeds)"
        )
        out += [f"skipped: {s}" for s in self.skipped]
        return out


def retracted(T: np.ndarray, d: float) -> np.ndarray:
    out = np.array(T, dtype=float)
    out[:3, 3] = out[:3, 3] - d * out[:3, 2]
    return out


def routine_name(seam_id: str, taken: set[str]) -> str:
    """``seam_<id>`` as an identifier of at most 24 characters (KRL's limit), unique among ``taken``."""
    base = ("seam_" + re.sub(r"\W", "_", str(seam_id)))[:24]
    name, k = base, 1
    while name in taken:
        name, k = f"{base[: 24 - len(str(k)) - 1]}_{k}", k + 1
    return name


def welded_poses(seam) -> np.ndarray:
    """The poses the torch welds through: a closed seam's poses and its first pose again (the planner
    stops one segment short of the start), so the weld closes the loop."""
    P = np.array(seam.poses, dtype=float)
    if seam.closed and len(P) > 2 and np.linalg.norm(P[-1, :3, 3] - P[0, :3, 3]) > 1e-9:
        P = np.concatenate([P, P[:1]])
    return P


def build_plan(data: dict, s: ProgramSettings, weld_speed: float, travel_speed: float, blend: float):
    """The program's motions for the weld-path document ``data`` (validated here)."""
    path = WeldPath.from_json(data)
    T_ft = T_from_rpy(s.tcp_rpy, s.tcp_xyz if s.tcp_xyz is not None else (0.0, 0.0, 0.0))
    plan = ProgramPlan([], path.frame, T_ft, s.tcp_xyz is not None)
    for seam in path.seams:
        if len(seam.poses) < 2:
            plan.skipped.append(f"seam {seam.id}: {len(seam.poses)} pose(s), a weld needs at least 2")
            continue
        planned = welded_poses(seam)
        if s.reduce:
            red = reduce_poses(planned, s.tolerance, s.angle_tolerance)
        else:
            red = Reduction(planned, np.arange(len(planned)), 0.0, 0.0, len(planned))
        v = float(seam.extra.get("weld_speed", weld_speed))
        if not (math.isfinite(v) and v > 0):
            raise DataError(f"seam {seam.id}: weld_speed {v!r} is not a positive speed", "fix the weld path")
        P = red.poses
        radii = path_blends(P[:, :3, 3], blend)
        radii[0] = 0.0  # arc start: stop
        # every seam is approached by a joint move (as the jobs execute it): a linear transit between two
        # seams' torch orientations can turn the wrist faster than the joints may
        motions = [
            Motion("joint", retracted(P[0], s.retract), travel_speed, 0.0),
            Motion("linear", P[0], travel_speed, 0.0, "arc_start"),
        ]
        motions += [
            Motion("linear", T, v, float(r), "weld") for T, r in zip(P[1:-1], radii[1:-1], strict=True)
        ]
        motions.append(Motion("linear", P[-1], v, 0.0, "arc_end"))
        motions.append(Motion("linear", retracted(P[-1], s.retract), travel_speed, 0.0))
        name = routine_name(seam.id, {x.routine for x in plan.seams})
        plan.seams.append(SeamPlan(seam.id, seam.joint, seam.length, v, motions, red, name))
    return plan


def check_plan(plan: ProgramPlan, s: ProgramSettings) -> None:
    """Replay every motion through the safety gate with ``s.robot_model``; refuse the export (SafetyError
    naming the seam and move) when the gate refuses one. No-op without a robot model."""
    if not s.robot_model:
        return
    from weldcell.hal.kinematics import get_model

    model = get_model(s.robot_model)
    joints: list[np.ndarray] = []
    gate = SafetyGate(s.safety, model)
    start = None
    if s.start_joints is not None:
        start = np.asarray(s.start_joints, dtype=float)
        if start.shape != (model.dof,) or not model.within_limits(start):
            raise DataError(
                f"start_joints {list(s.start_joints)}: not a joint vector of {model.name} inside its limits",
                f"give {model.dof} joint angles in radians inside the limits, or leave start_joints unset",
            )
    check_motions(plan.motions, gate, plan.T_flange_tcp, s.accel, _labels(plan), joints, start)
    plan.checked_with, plan.model, plan.joints = model.name, model, joints


def _labels(plan: ProgramPlan) -> list[str]:
    out = []
    for seam in plan.seams:
        out += [f"seam {seam.id} move {i + 1} ({m.process})" for i, m in enumerate(seam.motions)]
    return out


def check_motions(
    motions, gate: SafetyGate, T_ft: np.ndarray, accel: float, labels=None, joints=None, start=None
):
    """The gate on a motion list: the first joint move at its target (from ``start`` joints when given,
    along the whole joint-space line; else the start is unknown: the IK solution nearest the model's home),
    later joint moves along the whole joint-space line to the solution nearest the previous joints, every
    linear move along its line from the previous pose (joints tracked). Returns the final joints;
    ``joints`` (a list) receives the joints at every motion's target."""
    inv_ft = invert(T_ft)
    q, T_prev = start, None
    for i, m in enumerate(motions):
        what = labels[i] if labels else f"move {i + 1}"
        try:
            if m.kind == "joint" or T_prev is None:
                q_new = gate.check_pose(m.pose, m.pose @ inv_ft, q, f"export: {what}")
                if q is not None and q_new is not None:  # from a known pose: the whole joint move
                    lim = gate.limits
                    gate.check_joint_move(
                        q, q_new, T_ft, lim.max_joint_speed, lim.max_joint_accel, f"export: {what}"
                    )
                q = q_new
            else:
                q = gate.check_linear(T_prev, m.pose, T_ft, m.speed, accel, q, f"export: {what}")
        except SafetyError as e:
            raise SafetyError(
                f"the program would be refused: {e.message}",
                f"{e.fix}; nothing was exported (move the part, change the robot or the limits)",
            ) from None
        if joints is not None and q is not None:
            joints.append(np.array(q, dtype=float))
        T_prev = m.pose
    return q
