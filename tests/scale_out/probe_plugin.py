"""A tiny plugin for the scale-out tests: a batchable ``probe`` command and a ``probe-job`` job.

``probe INPUT -o OUT`` reads a text file: ``ok N`` writes ``{"metrics": {"value": N, "square": N*N}}``;
``bad`` fails with a DataError; ``kill-once`` kills its own worker process the first time it runs;
``kill-always`` every time; ``sleep`` sleeps for a minute. Every run appends a line to ``INPUT.runs``, so a
test can count how often each input ran. The workers import this module by name (``plugin_modules``).
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import click
from pydantic import Field
from weldcell.sdk.descriptors import BatchSpec, CommandSpec, JobSpec
from weldcell.sdk.errors import DataError, JobError
from weldcell.sdk.hookspecs import hookimpl
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length

MODULE = "scale_out.probe_plugin"


@click.command("probe")
@click.argument("source", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path))
@click.option("--scale", type=float, default=1.0)
def probe_command(source: Path, output: Path, scale: float) -> None:
    """Read SOURCE, write a result."""
    with open(f"{source}.runs", "a") as f:
        f.write(f"{os.getpid()}\n")
    text = source.read_text().strip()
    if text == "bad":
        raise DataError(f"{source}: not a probe file", "write 'ok N'")
    if text == "kill-once":
        marker = Path(f"{source}.killed")
        if not marker.exists():
            marker.write_text("1")
            os.kill(os.getpid(), signal.SIGKILL)
        text = "ok 7"
    if text == "kill-always":
        os.kill(os.getpid(), signal.SIGKILL)
    if text == "sleep":
        time.sleep(60)
    n = float(text.split()[1]) * scale
    click.echo(f"value {n}")
    output.write_text(json.dumps({"metrics": {"value": n, "square": n * n}}))


class ProbeJobSettings(Settings):
    offset: Length = Field(0.0, description="an offset [m]")
    gain: float = Field(1.0, description="noise gain")
    mode: str = Field("ok", description="'ok' or 'fail'")


def run_probe_job(ctx) -> dict:
    s = ctx.settings
    if s.mode == "fail":
        raise JobError("probe job asked to fail", "use mode 'ok'")
    noise = float(ctx.rng.normal())
    return {
        "error_mm": abs(s.offset) * 1000 + s.gain * noise,
        "offset_mm": s.offset * 1000,
        "seed": ctx.profile.cell.seed,
    }


@hookimpl
def weldcell_register_commands(register) -> None:
    register(
        CommandSpec(
            name="probe",
            command=probe_command,
            summary="test command",
            batch=(BatchSpec(output="probe.json", patterns=("*.txt",)),),
        )
    )


@hookimpl
def weldcell_register_jobs(register) -> None:
    register(
        JobSpec(
            name="probe-job", kind="job", summary="test job", settings=ProbeJobSettings, run=run_probe_job
        )
    )


def probe_trial(values: dict, seed: int, trial: int) -> dict:
    """A study trial function (``weldcell study --function scale_out.probe_plugin:probe_trial``)."""
    if values.get("row") == "bad":
        raise DataError("row 'bad' asked to fail", "use another row")
    return {"value": float(values.get("x", 0.0)) * 1000, "trial": trial}
