"""Hand-eye calibration (paper 003): flange-based and classical stages, the ``calibrate`` job and the
``weldcell calibrate hand-eye`` command. Registration only: every module is imported lazily."""

from __future__ import annotations

from weldcell.sdk.descriptors import BatchSpec, CommandSpec, DeviceRole, JobSpec, StageRole, StageSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell.plugins.handeye import stages as st

    register(
        StageSpec(
            name="handeye.flange",
            kind="handeye",
            summary="flange segmentation + RANSAC circle, "
            "scaled SVD fit (eqs. 9-12), robust fit, Algorithm 1 with the ICP metric (eq. 13, 21)",
            settings=st.FlangeSettings,
            factory=st.FlangeHandEye,
        )
    )
    register(
        StageSpec(
            name="handeye.opencv",
            kind="handeye",
            summary="classical AX=XB / AX=YB solvers (Tsai, "
            "Park, Horaud, Andreff, Daniilidis, Shah, Li) on board or flange poses",
            settings=st.ClassicalSettings,
            factory=st.ClassicalHandEye,
        )
    )


@hookimpl
def weldcell_register_jobs(register) -> None:
    from weldcell.plugins.handeye import job
    from weldcell.sdk.calibration import CALIBRATE_JOB, CalibrateSettings

    register(
        JobSpec(
            name=CALIBRATE_JOB,
            kind="job",
            summary="hand-eye calibration of a depth camera fixed in the cell (scans of the robot's flange) "
            "or on the flange (scans of a fixed ISO 9409-1 plate), online",
            settings=CalibrateSettings,
            run=job.run,
            devices=(
                DeviceRole("robot", "robot", "the arm whose flange is scanned (or that carries the camera)"),
                DeviceRole("camera", "depth_camera", "the depth camera, on 'world' or on 'robot.flange'"),
            ),
            stages=(
                StageRole(
                    "handeye", "handeye", "handeye.flange", "measure the flange and solve the hand-eye"
                ),
            ),
        )
    )


@hookimpl
def weldcell_register_commands(register) -> None:
    from weldcell.plugins.handeye.cli import calibrate_group

    register(
        CommandSpec(
            name="calibrate",
            command=calibrate_group,
            summary="calibrate a cell from recorded data",
            batch=(
                BatchSpec(
                    output="handeye.json", subcommand="hand-eye", inputs="dir", report_option="--report"
                ),
            ),
        )
    )
