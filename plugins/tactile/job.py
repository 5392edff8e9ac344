"""The ``tactile-track`` job (paper 003 §2.2, Algorithm 2): track a seam's side wall with the SRM tool.

At camera rate: capture the in-finger image →
:class:`~weldcell.plugins.tactile.marker.MarkerDisplacementEstimator` (tag displacement → tip deflection δ
through the SRM's tag gains) → :meth:`TactileSeamServo.step` → the twist
``[vx, vy, vz, 0, 0, ω]`` of the TCP (the SRM tip's undeformed centre) → ``robot.speed_linear`` through the
HAL safety gate. A command the gate refuses (e.g. the seam runs out of the ``[cell.safety]`` box), a lost
marker or an overload is a **safe stop**: the robot stops, everything recorded so far is written, and the
run fails with a message that says why and where.

The planned path comes from a ``weldcell/weld-path@1`` file (``plan_file``) or from the run's own vision
step: one scan of the fixed depth camera, mapped to the robot base with the hand-eye (``[calibration]
hand_eye``, an eye-on-base ``T_base_camera``), denoised and searched for seams by the profile's stages.

Writes ``tactile_track.json`` (``weldcell/tactile-track@1``), ``refined_path.json``
(``weldcell/weld-path@1``: the seam found by touch, with torch poses), ``fig13_paths.png``,
``deformation_over_time.png``, ``error_along_seam.png`` (simulated cell), ``summary.txt`` and
``report/report.html`` (plugins/tactile/report.py).

The steps are modules: :mod:`~weldcell.plugins.tactile.vision_plan` (the planned path),
:mod:`~weldcell.plugins.tactile.tracking` (Algorithm 2 on the robot),
:mod:`~weldcell.plugins.tactile.track_results` (figures and files), with the settings in
:mod:`~weldcell.plugins.tactile.track_settings`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from weldcell.sdk.errors import JobError

from .servo import ServoSettings, TactileSeamServo
from .track_settings import TactileTrackSettings
from .tracking import track
from .vision_plan import Plan, plan_from_file, read_T_base_camera, scan_for_seam, true_seams

__all__ = ["SRMServoStage", "TactileTrackSettings", "run"]


class SRMServoStage:
    """The ``tactile.srm-servo`` stage: builds Algorithm 2's controller for a planned path."""

    def __init__(self, settings: ServoSettings) -> None:
        self.settings = settings

    def __call__(self, planned_points: np.ndarray, gate=None) -> TactileSeamServo:
        return TactileSeamServo(planned_points, self.settings, gate)


def run(ctx) -> dict[str, Any]:
    """The ``tactile-track`` job."""
    s: TactileTrackSettings = ctx.settings
    S: ServoSettings = ctx.stage_settings("servo")
    if s.plan_file is not None:
        path = (ctx.loaded.source_of(("job", "settings", "plan_file")).parent / s.plan_file).resolve()
        plan = Plan(plan_from_file(path, s.seam_id), f"file {path}")
        pts = plan.points
        # the file's travel direction is kept; only the servo's wall side must match it
    else:
        camera = ctx.devices.get("camera")
        hand_eye = ctx.calibration_file("hand_eye")
        if camera is None or hand_eye is None:
            raise JobError(
                "tactile-track has no planned path: no plan_file, and no camera + hand-eye for the "
                "vision step",
                "set [job.settings] plan_file, or add [devices.camera] and "
                "[calibration] hand_eye = 'handeye.json'",
            )
        truth = true_seams(ctx)
        plan = scan_for_seam(ctx, camera, read_T_base_camera(hand_eye), s.scan, S.wall_side, truth)
        pts = plan.points
    figures = {"plan": {"source": plan.source, **plan.info}}
    ctx.figures.update(figures)
    figures["tactile"] = track(ctx, pts, s)
    return figures
