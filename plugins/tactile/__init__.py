"""Soft tactile seam tracking (paper 003 §2.2): the SRM servo stage, the simulated SRM tool's camera,
the ``tactile-track`` and ``calibrate-and-track`` jobs. Registration only: modules load lazily."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceRole, DeviceSpec, JobSpec, StageRole, StageSpec
from weldcell.sdk.hookspecs import hookimpl

_PLAN_STAGES = (
    StageRole("denoise", "denoise", "denoise.bilateral", "denoise the scan (vision step)"),
    StageRole("seam", "seam", "seam.edge-intensity", "find the seams in the scan (vision step)"),
    StageRole("servo", "tactile-servo", "tactile.srm-servo", "the deformation servo (Algorithm 2)"),
)


def _servo_factory(settings):
    from weldcell.plugins.tactile.job import SRMServoStage

    return SRMServoStage(settings)


def _sim_factory(settings, ctx):
    from weldcell.plugins.tactile.sim_device import factory

    return factory(settings, ctx)


def _sim_probe(settings) -> str:
    return "simulated (always reachable)"


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell.plugins.tactile.servo import ServoSettings

    register(
        StageSpec(
            name="tactile.srm-servo",
            kind="tactile-servo",
            summary="SRM deformation servo + online trajectory refinement (eqs. 14-18, Algorithm 2)",
            settings=ServoSettings,
            factory=_servo_factory,
            requires={"cv2": "vision"},
        )
    )


@hookimpl
def weldcell_register_devices(register) -> None:
    from weldcell.plugins.tactile.sim_device import SimTactileSettings

    register(
        DeviceSpec(
            name="tactile.sim",
            kind="tactile_camera",
            summary="in-finger ArUco camera of a simulated SRM tool on a robot flange (contact "
            "model + rendered tag images)",
            settings=SimTactileSettings,
            factory=_sim_factory,
            simulated=True,
            probe=_sim_probe,
            requires={"cv2": "vision"},
        )
    )


@hookimpl
def weldcell_register_jobs(register) -> None:
    from weldcell.plugins.tactile import cell2_job, job

    robot = DeviceRole("robot", "robot", "the arm carrying the SRM tool (TCP = the SRM tip)")
    tactile = DeviceRole(
        "tactile", "tactile_camera", "the SRM finger's in-finger camera, on the robot flange"
    )
    register(
        JobSpec(
            name="tactile-track",
            kind="job",
            summary="track a seam wall with the soft SRM tool (Algorithm 2), planned from a file or a scan",
            settings=job.TactileTrackSettings,
            run=job.run,
            devices=(
                robot,
                tactile,
                DeviceRole("camera", "depth_camera", "fixed depth camera for the vision step", optional=True),
            ),
            stages=_PLAN_STAGES,
        )
    )
    register(
        JobSpec(
            name="calibrate-and-track",
            kind="job",
            summary="cell 2 from scratch: flange hand-eye calibration, vision plan, tactile seam tracking",
            settings=cell2_job.CalibrateAndTrackSettings,
            run=cell2_job.run,
            devices=(
                robot,
                DeviceRole("camera", "depth_camera", "the depth camera fixed in the cell (eye-on-base)"),
                tactile,
            ),
            stages=(
                StageRole(
                    "handeye", "handeye", "handeye.flange", "measure the flange and solve the hand-eye"
                ),
                *_PLAN_STAGES,
            ),
        )
    )
