"""The laser inspection of ``localize-and-weld``: the plan at the sensor's height, every motion through the
safety gate before anything moves, and the checkpointed scan of the lines (resumable).
"""

from __future__ import annotations

import numpy as np
from weldcell.hal.sim import world_of
from weldcell.plugins.localize import acquisition as acq
from weldcell.plugins.localize.job_settings import LocalizeAndWeldSettings
from weldcell.plugins.localize.plans import check_constraints, make_plan, plan_duration
from weldcell.plugins.localize.projector_calibration import move_to
from weldcell.plugins.localize.template import Template
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.geometry import invert


def plan_inspection(ctx, template: Template, s: LocalizeAndWeldSettings, T_fs: np.ndarray):
    """The plan, refused before anything moves when it cannot constrain the pose or fails the gate."""
    robot = ctx.device("robot")
    z_sensor = sensor_height(ctx, template, s)
    plan = make_plan(template, s.plan, z_sensor, start_xy=None)
    plan.constraints = check_constraints(plan, template, s.plan)
    plan.duration = plan_duration(plan, robot.gate.model, T_fs, robot.T_flange_tcp)
    return plan


def check_transit(robot, T_tcp: np.ndarray, what: str) -> np.ndarray | None:
    """The gate's check of a transit (:func:`move_to`) from the robot's pose now; returns the joints."""
    gate, T_ft = robot.gate, robot.T_flange_tcp
    st = robot.state()
    if gate.model is None:
        return gate.check_linear(
            st.T_base_tcp, T_tcp, T_ft, robot.motion.speed, robot.motion.accel, st.q, what
        )
    q = gate.solve(T_tcp @ invert(T_ft), st.q, what)
    gate.check_joint_speed(robot.motion.joint_speed, robot.motion.joint_accel)
    for a in np.linspace(0.0, 1.0, 25):  # as Robot.move_joint checks it
        gate.check_point((gate.model.fk((1 - a) * st.q + a * q) @ T_ft)[:3, 3], f"{what} at {100 * a:.0f}%")
    return q


def check_plan_motions(robot, plan, T_fs: np.ndarray, lines: list[int], start: np.ndarray) -> None:
    """Every linear segment of the lines still to scan, through the gate, from the robot's pose now via
    ``start`` (the TCP pose at the first line's start)."""
    gate, T_ft = robot.gate, robot.T_flange_tcp
    q = check_transit(robot, start, "approach to the inspection")
    T_prev = start
    for k in lines:
        for T in plan.line_tcp_poses(k, T_fs, T_ft):
            q = gate.check_linear(T_prev, T, T_ft, plan.line_speed(k), plan.accel, q, f"inspection line {k}")
            T_prev = T


def inspect(ctx, plan, s: LocalizeAndWeldSettings, T_fs: np.ndarray) -> acq.Recording:
    """Scan every line not yet captured (checkpointed: each line saved and recorded at once)."""
    robot, laser = ctx.device("robot"), ctx.device("laser")
    done = {}
    for i, rec in enumerate(ctx.state.captures):
        if rec.get("kind") == "inspection-line" and ctx.state.check_capture(i) is None:
            done[int(rec["line"])] = rec["file"]
    todo = [k for k in range(len(plan.lines)) if k not in done]
    lines = [acq.LineRecord.load(ctx.run_dir / done[k]) for k in sorted(done)]
    world = world_of(ctx)
    if lines and world is not None:  # a resumed simulation: its clock continues after what was recorded
        world.clock.advance(max(ln.t_end for ln in lines) + 1.0 - world.clock.t)
    if todo:
        with ctx.step("check inspection motions (safety gate)"):
            first = plan.tcp_poses(plan.lines[todo[0]][:1], T_fs, robot.T_flange_tcp, plan.yaw(todo[0]))[0]
            check_plan_motions(robot, plan, T_fs, todo, start=first)
        with ctx.step("inspect", total=len(plan.lines), kind="checkpointed") as advance:
            poses = acq.pose_stream_for(robot, s.acquisition.pose_rate)
            move_to(robot, first)  # a joint move (the sensor may turn), through the gate
            poses.start()
            laser.start_stream(capacity=1 << 20)
            t_prev = None
            try:
                for k in todo:
                    spec = acq.LineSpec(
                        k,
                        plan.kinds[k],
                        plan.line_tcp_poses(k, T_fs, robot.T_flange_tcp),
                        s.plan.blend,
                        t_prev,
                        plan.line_speed(k),
                    )
                    line = acq.scan_line(robot, laser, poses, spec, plan, s.acquisition, 0.0)
                    t_prev = line.t_end
                    line.save(ctx.path(acq.line_file(k)))
                    ctx.state.add_capture(
                        {
                            "kind": "inspection-line",
                            "line": k,
                            "file": acq.line_file(k),
                            "readings": len(line.laser_t),
                        }
                    )
                    lines.append(line)
                    advance(len(lines))
            except DeviceError as e:  # keep what the failed line captured (it is scanned again on resume)
                part = getattr(e, "partial_line", None)
                if part is not None:
                    rest = laser.stop_stream()
                    part.laser_t = np.r_[part.laser_t, [r.stamp for r in rest]]
                    part.laser_d = np.r_[
                        part.laser_d, [np.nan if r.distance is None else r.distance for r in rest]
                    ]
                    name = f"inspection/partial_line_{part.index:04d}.npz"
                    part.save(ctx.path(name))
                    ctx.state.data["notes"].setdefault("partial_lines", []).append(name)
                    ctx.state.save()
                raise
            finally:
                rest = laser.stop_stream()
                poses.stop()
            if rest and lines:  # readings that arrived after the last line was saved: keep them
                last = lines[-1]
                last.laser_t = np.r_[last.laser_t, [r.stamp for r in rest]]
                last.laser_d = np.r_[
                    last.laser_d, [np.nan if r.distance is None else r.distance for r in rest]
                ]
                last.save(ctx.path(acq.line_file(last.index)))
    lines.sort(key=lambda ln: ln.index)
    rec = acq.Recording(lines, T_fs, None, {"plan": plan.kind, "levels": None})
    return rec


def sensor_height(ctx, template: Template, s: LocalizeAndWeldSettings) -> float:
    """Height of the laser during inspection: the highest top plus the stand-off (default mid-range)."""
    spec = getattr(ctx.device("laser"), "spec", None)
    mid = 0.5 * (spec.min_range + spec.max_range) if spec is not None else 0.15
    return max(m.top for m in template.members) + (s.plan.standoff if s.plan.standoff is not None else mid)


def inspection_tcp_height(ctx, template: Template, s: LocalizeAndWeldSettings, T_fs: np.ndarray) -> float:
    """TCP height above the table while inspecting (the envelope is computed there)."""
    from weldcell.plugins.localize.plans import R_DOWN

    T = np.eye(4)
    T[:3, :3] = R_DOWN
    T[2, 3] = sensor_height(ctx, template, s)
    return float((T @ invert(T_fs) @ ctx.device("robot").T_flange_tcp)[2, 3] - template.table_z)
