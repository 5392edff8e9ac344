"""The ``check-devices`` job: open every device of a profile, take one reading each, report health."""

from __future__ import annotations

from weldcell.sdk.descriptors import JobSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_jobs(register) -> None:
    from weldcell.plugins.device_check.job import CheckSettings, run

    register(
        JobSpec(
            name="check-devices",
            kind="job",
            settings=CheckSettings,
            run=run,
            any_devices=True,
            summary="open every device of the cell, take one reading from each, report its health",
        )
    )
