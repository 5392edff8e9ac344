"""The weld of ``localize-and-weld``: the re-planned CAD welds as seams, their path, its error against the
true seams (simulated cell), every weld motion through the safety gate before any is sent, and the programs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from weldcell.plugins.localize.job_settings import LocalizeAndWeldSettings
from weldcell.plugins.localize.sim_worker import TruePlacement
from weldcell.plugins.localize.template import Template
from weldcell.sdk.errors import JobError, SafetyError
from weldcell.sdk.geometry import invert


@dataclass
class CadSeam:
    """A re-planned CAD weld as a seam polyline for the path stage (approach straight down)."""

    id: str
    joint_class: str
    points: np.ndarray
    normals: np.ndarray
    closed: bool = False

    @property
    def length(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


def seams_from_welds(welds: list[dict], spacing: float) -> list[CadSeam]:
    out = []
    for w in welds:
        P = np.asarray(w["points"], float)
        L = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]
        if len(P) < 2 or L[-1] <= 0:
            continue
        t = np.linspace(0, L[-1], max(3, int(np.ceil(L[-1] / spacing)) + 1))
        pts = np.column_stack([np.interp(t, L, P[:, i]) for i in range(3)])
        out.append(CadSeam(str(w["id"]), "fillet", pts, np.tile([0.0, 0.0, -1.0], (len(pts), 1))))
    return out


def weld_path(ctx, welds: list[dict], s: LocalizeAndWeldSettings):
    seams = seams_from_welds(welds, s.seam_spacing)
    if not seams:
        raise JobError(
            "the template has no weld seam to re-plan", "add welds to the template (or derive them)"
        )
    path = ctx.stage("path")(seams, frame="base")
    for seam, cad in zip(path.seams, seams, strict=True):
        seam.id = cad.id
    return path


def measure_path(path, truth: TruePlacement | None, template: Template) -> dict:
    """Distance of each re-planned seam (its seam line) from the true seam (simulated cell)."""
    if truth is None:
        return {}
    per = []
    for seam, true in zip(path.seams, truth.welds, strict=False):
        a, b = true[0], true[-1]
        ab = b - a
        t = np.clip((seam.points - a) @ ab / max(ab @ ab, 1e-18), 0, 1)
        d = np.linalg.norm(seam.points - (a + t[:, None] * ab), axis=1)
        per.append({"seam": seam.id, "mean_mm": float(d.mean() * 1e3), "max_mm": float(d.max() * 1e3)})
    allmax = max((p["max_mm"] for p in per), default=float("nan"))
    return {"per_seam": per, "max_mm": allmax, "mean_mm": float(np.mean([p["mean_mm"] for p in per]))}


def plan_weld_motions(robot, path, speed: float, approach: float) -> list[tuple[str, str, object]]:
    """Every motion of the weld, checked through the gate from the robot's pose now before anything moves:
    per seam a joint move above its start (the torch turns there, away from the part), a linear move down,
    the torch poses at weld speed, and back up. Returns (seam id, kind, target) in order."""
    gate, T_ft = robot.gate, robot.T_flange_tcp
    st = robot.state()
    T_prev, q = st.T_base_tcp, st.q
    out: list[tuple[str, str, object]] = []
    for seam in path.seams:
        above = seam.poses[0].copy()
        above[:3, 3] -= approach * above[:3, 2]
        high = above.copy()
        high[2, 3] = max(above[2, 3], T_prev[2, 3])
        end = seam.poses[-1].copy()
        end[:3, 3] -= approach * end[:3, 2]
        try:
            if gate.model is not None:
                q_high = gate.solve(high @ invert(T_ft), q, f"seam {seam.id} approach")
                gate.check_joint_speed(robot.motion.joint_speed, robot.motion.joint_accel)
                for a in np.linspace(0.0, 1.0, 25):  # as Robot.move_joint checks it
                    gate.check_point(
                        (gate.model.fk((1 - a) * q + a * q_high) @ T_ft)[:3, 3], f"seam {seam.id} approach"
                    )
                q, first = q_high, ("joint", q_high)
            else:
                q = gate.check_linear(
                    T_prev, high, T_ft, robot.motion.speed, robot.motion.accel, q, "approach"
                )
                first = ("move", high)
            T_prev = high
            steps = [first, ("move", above), ("weld", seam.poses), ("move", end)]
            for kind, target in steps[1:]:
                v = speed if kind == "weld" else robot.motion.speed
                for T in np.reshape(target, (-1, 4, 4)):
                    q = gate.check_linear(T_prev, T, T_ft, v, robot.motion.accel, q, f"seam {seam.id} {kind}")
                    T_prev = T
        except SafetyError as e:
            raise SafetyError(
                f"seam {seam.id} cannot be welded: {e.message}; nothing was sent to the robot", e.fix
            ) from None
        out += [(seam.id, kind, target) for kind, target in steps]
    return out


def execute_weld(ctx, path, s: LocalizeAndWeldSettings) -> dict:
    robot = ctx.device("robot")
    with ctx.step("check weld motions (safety gate)"):
        motions = plan_weld_motions(robot, path, s.weld_speed, s.approach_distance)
    with ctx.step("weld", total=len(path.seams), kind="motion") as advance:
        done = 0
        for _seam, kind, target in motions:
            if kind == "joint":
                robot.move_joint(target)
            elif kind == "weld":
                robot.follow_path(target, speed=s.weld_speed)
                done += 1
                advance(done)
            else:
                robot.move_linear(target)
    return {"status": "done", "seams": len(path.seams), "dry_run": bool(ctx.profile.cell.dry_run)}


def export_programs(ctx, path) -> list[str]:
    """The robot programs of the re-planned welds, gate-checked for the cell's robot and tool."""
    return ctx.write_programs(path.to_json(), ctx.device("robot").program_settings())
