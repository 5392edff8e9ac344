"""Cell 1, scan-and-plan (paper 000): gesture-guided scanning, linear ICP reconstruction, bilateral
denoising, edge-intensity seam extraction and 6-DOF torch paths."""

from __future__ import annotations

from weldcell.sdk.descriptors import BatchSpec, CommandSpec, DeviceRole, JobSpec, StageRole, StageSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell.plugins.scan_plan import stages as st

    register(
        StageSpec(
            name="reconstruct.linear-icp",
            kind="reconstruct",
            summary="multi-view merge (eq. 1) + "
            "linear point-to-plane ICP (eqs. 2-8) against the growing model",
            settings=st.ReconstructSettings,
            factory=st.Reconstructor,
        )
    )
    register(
        StageSpec(
            name="denoise.bilateral",
            kind="denoise",
            summary="point-cloud bilateral filter (eqs. 9-10) + voxel down-sampling",
            settings=st.BilateralSettings,
            factory=st.BilateralDenoiser,
        )
    )
    register(
        StageSpec(
            name="seam.edge-intensity",
            kind="seam",
            summary="edge intensity + structure tensor (eqs. 11-17), joint classification and chaining",
            settings=st.EdgeSeamSettings,
            factory=st.EdgeSeamExtractor,
        )
    )
    register(
        StageSpec(
            name="path.torch-frames",
            kind="path",
            summary="torch frames with averaged travel direction, linear + slerp interpolation (eqs. 18-19)",
            settings=st.TorchPathSettings,
            factory=st.TorchPathPlanner,
        )
    )


@hookimpl
def weldcell_register_jobs(register) -> None:
    from weldcell.plugins.scan_plan import job

    register(
        JobSpec(
            name="scan-and-plan",
            kind="job",
            summary="scan a part by hand gestures, reconstruct it, find its seams and plan 6-DOF weld paths",
            settings=job.ScanAndPlanSettings,
            run=job.run,
            devices=(
                DeviceRole("robot", "robot", "the arm carrying the camera"),
                DeviceRole("camera", "depth_camera", "the depth camera on the flange"),
                DeviceRole("gesture", "gesture_sensor", "the hand tracker"),
            ),
            stages=(
                StageRole(
                    "reconstruct", "reconstruct", "reconstruct.linear-icp", "merge and refine the views"
                ),
                StageRole("denoise", "denoise", "denoise.bilateral", "denoise the model"),
                StageRole("seam", "seam", "seam.edge-intensity", "find the seams"),
                StageRole("path", "path", "path.torch-frames", "plan the torch path"),
            ),
        )
    )


@hookimpl
def weldcell_register_commands(register) -> None:
    from weldcell.plugins.scan_plan import cli

    register(
        CommandSpec(
            name="seam",
            command=cli.seam_command,
            summary="denoise -> seams -> 6-DOF torch paths on a cloud in the base frame",
            batch=(BatchSpec(output="path.json", patterns=("*.ply", "*.pcd"), report_option="--report"),),
        )
    )
    register(
        CommandSpec(
            name="reconstruct",
            command=cli.reconstruct_command,
            summary="merge posed scans + hand-eye into a model refined by linear ICP",
            batch=(BatchSpec(output="model.ply", inputs="dir", markers=("scans.json", "state.json")),),
        )
    )
