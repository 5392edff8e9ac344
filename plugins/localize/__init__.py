"""Cell 3, localize-and-weld (paper 002): CAD templates, laser-scan edge extraction and template localization.

Registers the stages ``edges.step-kernel`` and ``localize.template-fit`` and the offline commands
``weldcell template`` and ``weldcell localize``.
"""

from __future__ import annotations

from weldcell.sdk.descriptors import BatchSpec, CommandSpec, DeviceRole, JobSpec, StageRole, StageSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell.plugins.localize import edges, fit, stages

    register(
        StageSpec(
            name="edges.step-kernel",
            kind="edges",
            summary="edge points of laser scan lines: step kernels, CAD heights, 0.6 mm slots (§III-D)",
            settings=edges.EdgeSettings,
            factory=stages.EdgeExtractor,
        )
    )
    register(
        StageSpec(
            name="localize.template-fit",
            kind="localize",
            summary="template fit (eq. 3): global search + robust Gauss-Newton, or Powell from 7 seeds (§IV)",
            settings=fit.LocalizeSettings,
            factory=stages.Localizer,
        )
    )


@hookimpl
def weldcell_register_commands(register) -> None:
    from weldcell.plugins.localize import cli

    register(
        CommandSpec(
            name="template",
            command=cli.template_command,
            summary="CAD (DXF / mesh) -> weldcell/template@1 for localization",
        )
    )
    register(
        CommandSpec(
            name="localize",
            command=cli.localize_command,
            summary="localize a workpiece from a laser scan against its CAD template",
            # TEMPLATE is the same for every scan: weldcell batch localize SCANS... --args TEMPLATE
            batch=(
                BatchSpec(output="result.json", inputs="any", patterns=("*.csv",), markers=("state.json",)),
            ),
        )
    )


@hookimpl
def weldcell_register_jobs(register) -> None:
    from weldcell.plugins.localize import job

    register(
        JobSpec(
            name="localize-and-weld",
            kind="job",
            summary="guided placement, laser inspection, template localization, re-planned weld (paper 002)",
            settings=job.LocalizeAndWeldSettings,
            run=job.run,
            devices=(
                DeviceRole(
                    "robot", "robot", "the arm carrying the torch, the laser sensor and the projector"
                ),
                DeviceRole("laser", "displacement_sensor", "the laser displacement sensor on the flange"),
                DeviceRole("projector", "laser_projector", "the projector guiding the worker", optional=True),
            ),
            stages=(
                StageRole("edges", "edges", "edges.step-kernel", "edge points from the laser scan lines"),
                StageRole("localize", "localize", "localize.template-fit", "fit the template to the edges"),
                StageRole("path", "path", "path.torch-frames", "torch poses along the re-planned welds"),
            ),
        )
    )
