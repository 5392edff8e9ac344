"""Cell 4, relocalization (paper 004 §II-E): NDT (Magnusson), FPFH + RANSAC global registration and the
verified relocalization of a current map against a prior map.

Registers the command ``weldcell map relocalize``.
"""

from __future__ import annotations

from weldcell.sdk.descriptors import CommandSpec, StageSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell.plugins.relocalize import stage

    register(
        StageSpec(
            name="relocalize.ndt",
            kind="relocalizer",
            summary="relocalization against a prior map: priors + NDT hypotheses, GICP fine, FPFH fallback, "
            "verified",
            settings=stage.RelocalizeSettings,
            factory=stage.Relocalizer,
        )
    )


@hookimpl
def weldcell_register_commands(register) -> None:
    from weldcell.plugins.relocalize import cli

    register(
        CommandSpec(
            name="map relocalize",
            command=cli.relocalize_command,
            summary="relocalize a current map/cloud against a prior map (weldcell/relocalization@1)",
        )
    )
