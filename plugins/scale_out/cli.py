"""``weldcell batch`` and ``weldcell study``: thin click layers over :mod:`weldcell.sdk.scale`."""

from __future__ import annotations

import shlex
from pathlib import Path

import click
from weldcell.sdk.errors import JobError, UsageError


def _cluster_options(f):
    f = click.option(
        "--scheduler",
        metavar="ADDRESS",
        help="An existing Dask scheduler, e.g. tcp://host:8786 (default: $DASK_SCHEDULER_ADDRESS, "
        "else a local cluster).",
    )(f)
    f = click.option(
        "--workers",
        type=click.IntRange(min=0),
        help="Local worker processes (default: one per core; 0: run in this process, for debugging).",
    )(f)
    f = click.option(
        "--retries",
        type=click.IntRange(min=0),
        default=2,
        show_default=True,
        help="Re-runs of a task whose worker died or that ran past --time-limit.",
    )(f)
    f = click.option(
        "--time-limit",
        type=click.FloatRange(min=0, min_open=True),
        help="Seconds one task may run; its worker is then stopped and the task retried or failed.",
    )(f)
    f = click.option("-q", "--quiet", is_flag=True, help="No progress bar; only the summary.")(f)
    return f


def _options(scheduler, workers, retries, time_limit):
    from weldcell.sdk.scale.cluster import ClusterOptions

    return ClusterOptions(scheduler=scheduler, workers=workers, retries=retries, time_limit=time_limit)


def split_command(items: tuple[str, ...], names: list[str]) -> tuple[str, list[str]]:
    """``("calibrate", "hand-eye", "a", "b")`` → ``("calibrate hand-eye", ["a", "b"])``: the longest
    batchable command name the first words form."""
    for n in (2, 1):
        name = " ".join(items[:n])
        if len(items) >= n and name in names:
            return name, list(items[n:])
    raise UsageError(
        f"'{items[0] if items else ''}' is not a batchable command",
        f"batchable commands: {', '.join(sorted(names)) or '(none)'}",
    )


@click.command("batch", context_settings={"ignore_unknown_options": False})
@click.argument("items", nargs=-1, required=True, metavar="COMMAND INPUTS...")
@click.option(
    "-o", "--output", "out_dir", required=True, type=click.Path(path_type=Path), help="Output folder."
)
@click.option(
    "--args",
    "command_args",
    default="",
    help="Arguments given to the command for every input, e.g. --args 'part.dxf --seeds 7' for localize "
    "(its TEMPLATE), or --args '--t 3' for seam.",
)
@click.option(
    "--reports", is_flag=True, help="Also write the command's report for each input (if it has one)."
)
@_cluster_options
def batch_command(items, out_dir, command_args, reports, scheduler, workers, retries, time_limit, quiet):
    """Run an offline COMMAND (seam, reconstruct, calibrate hand-eye, localize, or any batchable plugin
    command) on every input (files, folders, glob patterns), one Dask task each.

    OUT_DIR gets results/<input>/ (the command's output, its log and checksums), failed/<input>/,
    batch.json, summary.csv and index.html. Running the same batch again skips the inputs whose result
    is complete and valid. Exit code 1 when an input failed (the others still ran).
    """
    from weldcell.sdk.plugins import get_plugin_manager
    from weldcell.sdk.scale.batch import batchable_commands, run_batch
    from weldcell.sdk.scale.progress import TaskProgress

    names = list(batchable_commands(get_plugin_manager().registry))
    command, inputs = split_command(items, names)
    if not inputs:
        raise UsageError(f"no input given to batch {command}", "give files, folders or glob patterns")
    summary = run_batch(
        command,
        inputs,
        out_dir,
        _options(scheduler, workers, retries, time_limit),
        args=tuple(shlex.split(command_args)),
        progress=TaskProgress(quiet),
        reports=reports,
    )
    c = summary.counts
    click.echo(
        f"batch {command}: {c.get('ok', 0)} ok ({c.get('resumed', 0)} from an earlier run), "
        f"{c.get('failed', 0)} failed, of {c.get('inputs', 0)} inputs -> {summary.out_dir}/index.html"
    )
    if summary.failed:
        raise JobError(
            f"{summary.failed} of {c.get('inputs', 0)} inputs failed",
            f"see {summary.out_dir}/index.html and failed/<input>/log.txt; fix them and run the same command "
            "again (finished inputs are skipped)",
        )


@click.command("study")
@click.argument("profile", type=click.Path(path_type=Path), required=False)
@click.option(
    "--function",
    metavar="MODULE:FUNCTION",
    help="Run this trial function instead of a profile's job: fn(values, seed=, trial=) -> figures "
    "(docs/scale-out.md), e.g. weldcell.plugins.relocalize.table4:trial.",
)
@click.option("--by", metavar="KEY", help="A varied key whose values group the statistics (a table's rows).")
@click.option("--trials", type=click.IntRange(min=1), required=True, help="Number of trials.")
@click.option(
    "--vary",
    multiple=True,
    metavar="KEY=DISTRIBUTION",
    help="A profile key and its distribution: uniform(a,b), normal(mu,sigma), choice(v1,v2,...); "
    "cycle(v1,v2,...) (trial i takes value i mod k); arguments may carry units, e.g. "
    "job.settings.worker.placement_offset='uniform(5 mm, 25 mm)'. Repeatable.",
)
@click.option(
    "-o", "--output", "out_dir", required=True, type=click.Path(path_type=Path), help="Output folder."
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the whole study.")
@click.option("--keep-runs", is_flag=True, help="Keep every trial's whole run folder (captures included).")
@click.option("--reports", is_flag=True, help="Let every trial write its job report and pictures.")
@_cluster_options
# one parameter per click option (click passes them by name); the body hands them to run_study
def study_command(
    profile,
    function,
    by,
    trials,
    vary,
    out_dir,
    seed,
    keep_runs,
    reports,
    scheduler,
    workers,
    retries,
    time_limit,
    quiet,
):
    """Run PROFILE's simulated job TRIALS times with settings drawn from --vary distributions, seeded and
    reproducible; report the metrics' distribution (mean, sigma, percentiles, failure rate) with plots.

    Each trial is trials/<n>/profile.toml (extends PROFILE; run it alone with `weldcell run`). Running
    the same study again skips finished trials. With --function MODULE:FUNCTION (and no PROFILE) each
    trial calls that function with the drawn values instead (a protocol that is not a whole job).
    """
    from weldcell.sdk.scale.progress import TaskProgress
    from weldcell.sdk.scale.study import run_study

    if profile is not None and not profile.is_file():
        raise UsageError(
            f"profile not found: {profile}", "give a simulation profile, e.g. profiles/*-sim.toml"
        )
    study = run_study(
        profile,
        trials,
        list(vary),
        out_dir,
        _options(scheduler, workers, retries, time_limit),
        seed=seed,
        keep_runs=keep_runs,
        reports=reports,
        progress=TaskProgress(quiet),
        function=function,
        by=by,
    )
    c = study["counts"]
    _echo_study(study, profile.name if profile else function, by, out_dir)
    if c["lost"] or c["pending"]:
        raise JobError(
            f"{c['lost'] + c['pending']} trials did not finish",
            "run the same command again: finished trials are skipped",
        )


def _echo_study(study: dict, name: str, by: str | None, out_dir: Path) -> None:
    """The study's counts, the first statistics (overall and per ``--by`` group) and where its report is."""
    c = study["counts"]
    click.echo(
        f"study {name}: {c['ok']} ok, {c['failed']} failed (failure rate "
        f"{study['failure_rate'] * 100:.1f} %), {c['lost']} lost, of {c['trials']} trials"
    )
    for k, st in list(study["statistics"].items())[:12]:
        if st.get("n"):
            click.echo(
                f"  {k:<36} mean {st['mean']:.6g}  sigma {st['std']:.6g}  p5 {st['p5']:.6g}  "
                f"p50 {st['p50']:.6g}  p95 {st['p95']:.6g}  (n={st['n']})"
            )
    for value, g in (study.get("groups") or {}).items():
        click.echo(f"  {by} = {value}: {g['counts']['ok']} ok, {g['counts']['failed']} failed")
        for k, st in list(g["statistics"].items())[:12]:
            if st.get("n"):
                click.echo(f"    {k:<34} mean {st['mean']:.6g}  sigma {st['std']:.6g}  p50 {st['p50']:.6g}")
    click.echo(f"report: {Path(out_dir).resolve()}/index.html")
