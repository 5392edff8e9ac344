"""The ``weldcell`` command line.

Exit codes (scripts may rely on them): 0 success; 1 job failed; 2 bad usage or bad input data;
3 invalid profile; 4 plugin problem (broken, conflicting, unknown, missing extra); 5 device
unreachable or faulted; 6 a motion was refused by the safety gate; 130 interrupted.
Errors print as one line plus the fix; ``--debug`` adds the traceback.
"""

from __future__ import annotations

import sys
import time
import traceback
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape
from weldcell.sdk.errors import WeldcellError
from weldcell.sdk.plugins import get_plugin_manager

console = Console(stderr=True, highlight=False)
out = Console(highlight=False)


class RichReporter:
    """Progress of a run on the terminal: one line per step with its time, and a bar for long steps."""

    def __init__(self, quiet: bool = False) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.quiet = quiet
        self._progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[msg]}"),
            TimeElapsedColumn(),
            console=console,
            transient=True,
            disable=quiet,
        )
        self._tasks: dict[str, int] = {}

    def step_started(self, name: str, total: int | None = None) -> None:
        if total:
            if not self._progress.live.is_started:
                self._progress.start()
            self._tasks[name] = self._progress.add_task(name, total=total, msg="")

    def advance(self, name: str, done: int, total: int | None = None, message: str = "") -> None:
        if name in self._tasks:
            self._progress.update(self._tasks[name], completed=done, total=total, msg=message)

    def step_finished(self, name: str, seconds: float) -> None:
        if name in self._tasks:
            self._progress.remove_task(self._tasks.pop(name))
            if not self._tasks:
                self._progress.stop()
        if not self.quiet:
            console.print(f"  [green]✓[/green] {name} [dim]{seconds:.2f} s[/dim]")

    def info(self, message: str) -> None:
        if not self.quiet:
            console.print(f"  {message}", markup=True)


class WeldcellGroup(click.Group):
    """Adds plugin commands and turns WeldcellErrors into one-line messages with exit codes."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(self._plugin_commands()))

    def get_command(self, ctx: click.Context, name: str):
        cmd = super().get_command(ctx, name)
        return cmd if cmd is not None else self._plugin_commands().get(name)

    def _plugin_commands(self) -> dict[str, click.Command]:
        try:
            reg = get_plugin_manager().registry
        except WeldcellError:
            return {}
        builtin = set(self.commands)
        return {n: r.descriptor.command for n, r in reg.entries["command"].items() if n not in builtin}

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except WeldcellError as e:
            debug = ctx.meta.get("weldcell.debug", False)
            if debug:
                traceback.print_exc()
            console.print(f"[bold red]error:[/bold red] {escape(e.message)}")
            for line in getattr(e, "problems", []) or []:
                console.print(f"  - {escape(line)}")
            if e.fix:
                console.print(f"  [bold]fix:[/bold] {escape(e.fix)}")
            if not debug:
                console.print("  [dim](--debug shows the traceback)[/dim]")
            ctx.exit(e.exit_code)
        except KeyboardInterrupt:
            console.print("[yellow]interrupted[/yellow]")
            ctx.exit(130)


@click.group(cls=WeldcellGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--debug", is_flag=True, help="Show tracebacks on errors.")
@click.option("--strict-plugins", is_flag=True, help="Treat any plugin that fails to load as an error.")
@click.version_option(package_name="weldcell")
@click.pass_context
def main(ctx: click.Context, debug: bool, strict_plugins: bool) -> None:
    """weldcell: vision-guided robotic welding cells, simulated or real.

    Start with `weldcell run profiles/cell1-scan-and-plan-sim.toml`.
    """
    ctx.meta["weldcell.debug"] = debug
    if debug:
        import logging

        logging.basicConfig(level=logging.INFO)
    if strict_plugins:
        import os

        os.environ["WELDCELL_STRICT_PLUGINS"] = "1"
        from weldcell.sdk.plugins import PluginManager, set_plugin_manager

        set_plugin_manager(PluginManager(discover=True, strict=True))


@main.command()
@click.argument("profile", type=click.Path(path_type=Path))
@click.option(
    "--resume", "resume", type=click.Path(path_type=Path), help="Continue an interrupted run folder."
)
@click.option("--runs-dir", type=click.Path(path_type=Path), help="Where to create the run folder.")
@click.option("--dry-run", is_flag=True, help="Log motion commands instead of sending them.")
@click.option("-q", "--quiet", is_flag=True, help="Print only the summary.")
def run(profile: Path, resume: Path | None, runs_dir: Path | None, dry_run: bool, quiet: bool) -> None:
    """Run the job of PROFILE (simulated or on hardware) and write a run folder."""
    from weldcell.sdk.jobs import run_job

    pm = get_plugin_manager()
    reporter = RichReporter(quiet)

    def overrides(loaded):
        if dry_run:
            loaded.profile.cell.dry_run = True

    if not quiet:
        console.print(f"[bold]weldcell run[/bold] {profile}")
    t0 = time.perf_counter()
    run_dir, result = run_job(
        profile, pm, run_dir=resume, runs_dir=runs_dir, reporter=reporter, overrides=overrides
    )
    summary = run_dir / "summary.txt"
    if summary.is_file():
        out.print(summary.read_text().rstrip())
    out.print(f"\nrun folder: {run_dir}  ({time.perf_counter() - t0:.1f} s)")


@main.command()
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def plugins(as_json: bool) -> None:
    """List installed plugins, what each registers, and what failed to load."""
    from weldcell.sdk.plugin_listing import plugin_table

    pm = get_plugin_manager()
    plugin_table(pm, out, as_json=as_json)
    if pm.registry.failures or pm.registry.conflicts:
        sys.exit(4)


@main.group()
def profiles() -> None:
    """Check and list cell profiles."""


@profiles.command("validate")
@click.argument("files", nargs=-1, required=True, type=click.Path(path_type=Path))
def profiles_validate(files: tuple[Path, ...]) -> None:
    """Validate profiles against the installed plugins (nothing is opened or moved)."""
    from weldcell.sdk.errors import ProfileError
    from weldcell.sdk.jobs import prepare

    pm = get_plugin_manager()
    failed = 0
    for f in files:
        try:
            loaded, resolved = prepare(f, pm)
        except ProfileError as e:
            failed += 1
            console.print(f"[red]✗[/red] {escape(str(f))}: {escape(e.message)}")
            for line in e.problems:
                console.print(f"    - {escape(line)}")
            continue
        devices = ", ".join(f"{r}={s.name}" for r, (s, _) in resolved["devices"].items())
        out.print(f"[green]✓[/green] {f}  job={loaded.profile.job.name}  devices: {devices or '-'}")
    if failed:
        console.print(f"{failed} of {len(files)} profile(s) invalid")
        sys.exit(3)


@profiles.command("list")
@click.argument("folder", default="profiles", type=click.Path(path_type=Path))
def profiles_list(folder: Path) -> None:
    """List the profiles in FOLDER with their job and description."""
    import tomllib

    for f in sorted(folder.glob("*.toml")):
        data = tomllib.loads(f.read_text())
        job = data.get("job", {}).get("name", "(inherited)")
        out.print(f"{f}  [bold]{job}[/bold]  {data.get('description', '')}")


@main.command()
@click.argument("profile", required=False, type=click.Path(path_type=Path))
def devices(profile: Path | None) -> None:
    """What each device plugin needs and, with PROFILE, whether each device of it is reachable."""
    from weldcell.sdk.plugin_listing import device_report

    sys.exit(device_report(get_plugin_manager(), out, profile))


if __name__ == "__main__":  # pragma: no cover
    main()
