"""The tactile jobs' planned path: from a weld-path file, or from one scan of the fixed depth camera.

The vision step maps the scan to the robot base with the given hand-eye (eye-on-base), crops it to the
part's region, runs the profile's denoise and seam stages and keeps the seam with a side wall standing
beside it, ordered so that the wall is on the servo's side (:func:`scan_for_seam`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.hal.sim import world_of
from weldcell.sdk.cloud import PointCloud, write_cloud
from weldcell.sdk.errors import DataError, JobError
from weldcell.sdk.geometry import invert, transform_points
from weldcell.sdk.stages import denoised_scan
from weldcell.sdk.weldpath import WeldPath

from .paths import Polyline, left_normal
from .track_settings import ScanSettings
from .tracking import goto


@dataclass
class Plan:
    """A planned seam line (K, 3) in the base frame, ordered so that the wall is on the servo's side."""

    points: np.ndarray
    source: str
    info: dict[str, Any] = field(default_factory=dict)


def wall_evidence(cloud_pts: np.ndarray, seam_pts: np.ndarray, band: float, rise: float) -> tuple[int, int]:
    """Points of a wall standing beside the seam: (count on the left of travel, count on the right)."""
    line = Polyline(seam_pts, "seam")
    P = np.asarray(cloud_pts, dtype=float)
    near = line.distances(P) < band
    left = right = 0
    for p in P[near][:: max(1, int(near.sum()) // 4000)]:
        pr = line.project(p)
        if pr.before_start or pr.past_end or p[2] < pr.point[2] + rise:
            continue
        side = float((p[:2] - pr.point[:2]) @ left_normal(pr.tangent))
        left += side > 0
        right += side < 0
    return left, right


def orient_plan(points: np.ndarray, wall_side: str, wall_left: bool) -> np.ndarray:
    """Reverse the seam if needed so that its wall is on ``wall_side`` of travel."""
    return points if (wall_left == (wall_side == "left")) else points[::-1].copy()


def plan_from_file(path: Path, seam_id: str | None) -> np.ndarray:
    wp = WeldPath.from_json(path)
    if wp.frame not in ("base", "robot.base"):
        raise DataError(
            f"{path}: the plan is in frame '{wp.frame}'", "give a weld path in the robot base frame"
        )
    seams = [s for s in wp.seams if seam_id is None or s.id == seam_id]
    if not seams:
        raise DataError(
            f"{path}: no seam {seam_id!r} (seams: {[s.id for s in wp.seams]})",
            "set [job.settings] seam_id to one of them",
        )
    return np.asarray(seams[0].points, dtype=float)


def scan_for_seam(
    ctx,
    camera,
    T_base_camera: np.ndarray,
    s: ScanSettings,
    wall_side: str,
    truth_seams: list[np.ndarray] | None = None,
    prefix: str = "",
) -> Plan:
    """One scan → base frame (with the GIVEN hand-eye) → ROI → denoise → seams → the seam with a wall."""
    robot = ctx.device("robot")
    P = _recorded_scan(ctx, prefix)
    if P is None and s.park_xyz is not None:
        from weldcell.sdk.geometry import T_from_rpy

        with ctx.step(f"{prefix}park the robot out of the camera's view", kind="checkpointed"):
            goto(robot, T_from_rpy(s.park_rpy, s.park_xyz) @ robot.T_flange_tcp)
    if P is None:
        with ctx.step(f"{prefix}scan the part", kind="checkpointed"):
            frame = camera.capture()
            cam_pts = frame.to_cloud().points
            P = transform_points(T_base_camera, cam_pts)
            keep = np.all((P >= np.asarray(s.roi_min)) & (P <= np.asarray(s.roi_max)), axis=1)
            P = P[keep]
            write_cloud(ctx.path("scan_base.ply"), PointCloud(P, frame="base"))
            if len(P) < s.min_points:
                raise JobError(
                    f"the scan has only {len(P)} points inside the part's ROI (need {s.min_points})",
                    "check [job.settings.scan] roi_min/roi_max (robot base frame) and that the part is "
                    "in the camera's view",
                )
            # a checkpoint: a resumed run reuses this scan instead of parking and scanning again
            rec = {"kind": "scan", "prefix": prefix, "file": "scan_base.ply", "points": len(P)}
            ctx.state.add_capture(rec)
    with ctx.step(f"{prefix}seams (denoise + edge intensity)"):
        view = transform_points(T_base_camera, np.zeros((1, 3)))
        scan = PointCloud(P, frame="base", viewpoints=view)
        clean = denoised_scan(scan, ctx.stage("denoise")(scan))
        extraction = ctx.stage("seam")(clean)
    candidates = []
    for seam in extraction.seams:
        left, right = wall_evidence(clean.points, seam.points, s.wall_band, s.wall_rise)
        candidates.append((max(left, right), left > right, seam))
    info = {
        "seams_found": len(candidates),
        "candidates": [
            {
                "id": int(c[2].id),
                "joint": c[2].joint_class,
                "length_mm": 1e3 * c[2].length,
                "wall_points": c[0],
            }
            for c in candidates
        ],
    }
    good = [c for c in candidates if c[0] >= s.min_wall_points]
    if not good:
        raise JobError(
            f"no seam with a side wall found in the scan ({len(candidates)} seam(s), wall points "
            f"{[c[0] for c in candidates]})",
            "check the ROI and the seam stage's settings; the SRM tool tracks fillet and lap joints",
        )
    n_wall, wall_left, seam = max(good, key=lambda c: (c[0], c[2].length))
    pts = orient_plan(np.asarray(seam.points, dtype=float), ctx.stage_settings("servo").wall_side, wall_left)
    info.update(chosen=int(seam.id), joint=seam.joint_class, length_mm=1e3 * seam.length, wall_points=n_wall)
    if truth_seams:
        info.update(plan_error_vs_truth(pts, truth_seams))
    return Plan(pts, "vision", info)


def plan_error_vs_truth(plan: np.ndarray, truth_seams: list[np.ndarray]) -> dict[str, float]:
    """RMS / max distance (mm) of a planned seam to the nearest true seam, in the plane and in 3-D."""
    best = None
    for true in truth_seams:
        line = Polyline(true, "true seam")
        inside = np.array([not (p.before_start or p.past_end) for p in map(line.project, plan)])
        if not inside.any():
            continue
        Q = plan[inside]
        d_xy = line.distances(Q)
        dense = line.resample(0.0002)
        from scipy.spatial import cKDTree

        d3 = cKDTree(dense).query(Q)[0]
        row = {
            "vision_plan_rms_mm": 1e3 * float(np.sqrt(np.mean(d_xy**2))),
            "vision_plan_max_mm": 1e3 * float(d_xy.max()),
            "vision_plan_rms_3d_mm": 1e3 * float(np.sqrt(np.mean(d3**2))),
        }
        if best is None or row["vision_plan_rms_mm"] < best["vision_plan_rms_mm"]:
            best = row
    return best or {}


def _recorded_scan(ctx, prefix: str) -> np.ndarray | None:
    """The part scan of an earlier attempt of this run (verified against its size and SHA-256), or None
    when there is none or it is damaged (then the robot parks and scans again: no contact, no weld)."""
    from weldcell.sdk.cloud import read_cloud

    for i, rec in enumerate(ctx.state.captures):
        if rec.get("kind") == "scan" and rec.get("prefix", "") == prefix:
            problem = ctx.state.check_capture(i)
            if problem:
                ctx.reporter.info(f"[yellow]{problem}: the part is scanned again[/yellow]")
                return None
            ctx.reporter.info(f"[dim]{prefix}scan of the part: taken in an earlier attempt, reused[/dim]")
            return read_cloud(ctx.run_dir / rec["file"], units="m", frame="base", check_scale=False).points
    return None


def read_T_base_camera(path: Path) -> np.ndarray:
    """``T_base_camera`` from a ``weldcell/hand-eye@1`` file (eye-on-base)."""
    from weldcell.sdk.handeye_files import read_result

    res = read_result(path)
    if res.name != "T_base_camera":
        raise DataError(
            f"{path}: the hand-eye is {res.name}, not T_base_camera (a camera fixed in the cell)",
            "calibrate the fixed camera with the 'calibrate' job (eye-on-base)",
        )
    return np.asarray(res.T, dtype=float)


def true_seams(ctx) -> list[np.ndarray] | None:
    """Ground-truth seams in the robot base frame (simulated cell), else None."""
    world = world_of(ctx)
    if world is None:
        return None
    T_base_world = invert(world.T_world("robot.base"))
    return [transform_points(T_base_world, s.points) for _, s in world.seams_in_world()]
