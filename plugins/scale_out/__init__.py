"""Scale out on Dask (issue 14): the ``weldcell batch`` and ``weldcell study`` commands.

Registration only; the core is :mod:`weldcell.sdk.scale` and Dask is imported when a command runs.
"""

from __future__ import annotations

from weldcell.sdk.descriptors import CommandSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_commands(register) -> None:
    from weldcell.plugins.scale_out import cli

    register(
        CommandSpec(
            name="batch",
            command=cli.batch_command,
            summary="run an offline command (seam, reconstruct, calibrate hand-eye, localize, ...) on many "
            "inputs on Dask, locally or on a cluster",
        )
    )
    register(
        CommandSpec(
            name="study",
            command=cli.study_command,
            summary="Monte-Carlo trials of a simulated job with drawn settings, on Dask: metric statistics",
        )
    )
