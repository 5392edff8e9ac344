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


class _RedactingConsole(Console):
    """A console that never prints a secret: registered ``${env:NAME}`` values show as their reference,
    credentials in URLs are masked (weldcell.sdk.secrets)."""

    def print(self, *objects, **kwargs) -> None:  # type: ignore[override]
        from weldcell.sdk.secrets import redact

        if not self.is_terminal:  # a file or a pipe: one line per message, never wrapped mid-phrase
            kwargs.setdefault("soft_wrap", True)
        super().print(*(redact(o) if isinstance(o, str) else o for o in objects), **kwargs)


console = _RedactingConsole(stderr=True, highlight=False)
out = _RedactingConsole(highlight=False)


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
            disable=quiet or not console.is_terminal,  # no bar (nor its blank lines) in a file or pipe
        )
        self._tasks: dict[str, int] = {}
        self._labels: dict[str, str] = {}

    def step_label(self, name: str, label: str) -> None:
        """Show step ``name`` as ``label`` when it finishes (e.g. with the plugin that ran in it)."""
        self._labels[name] = label

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
        label = self._labels.pop(name, name)
        if not self.quiet:
            console.print(f"  [green]✓[/green] {escape(label)} [dim]{seconds:.2f} s[/dim]")

    def info(self, message: str) -> None:
        if not self.quiet:
            console.print(f"  {message}", markup=True)


def _traceback_helps(e: WeldcellError) -> bool:
    """Whether ``--debug``'s traceback tells more than the message: only when the error wraps an
    unexpected exception (a bug, a vendor library's failure), not for bad input, a refused motion or
    a profile problem, whose message and fix say everything; and not when the fix already says so."""
    if "--debug" in (e.fix or ""):
        return False
    cause = e.__cause__
    while isinstance(cause, WeldcellError):
        cause = cause.__cause__
    return isinstance(cause, Exception)


class WeldcellGroup(click.Group):
    """Adds plugin commands and turns WeldcellErrors into one-line messages with exit codes."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(super().list_commands(ctx)) | set(self._plugin_commands()))

    def get_command(self, ctx: click.Context, name: str):
        cmd = super().get_command(ctx, name)
        return cmd if cmd is not None else self._plugin_commands().get(name)

    def _plugin_commands(self) -> dict[str, click.Command]:
        """Plugin commands by name; a name with a space (``"map relocalize"``) is a sub-command of a
        group (``weldcell map``) that the plugins share: the group is made here from its members."""
        try:
            reg = get_plugin_manager().registry
        except WeldcellError:
            return {}
        builtin = set(self.commands)
        out: dict[str, click.Command] = {}
        groups: dict[str, dict[str, tuple[str, click.Command]]] = {}
        for n, r in reg.entries["command"].items():
            group, _, sub = n.partition(" ")
            if group in builtin:
                continue
            if sub:
                groups.setdefault(group, {})[sub] = (r.descriptor.summary, r.descriptor.command)
            else:
                out[n] = r.descriptor.command
        for group, members in groups.items():
            g = out.get(group)
            if g is None:
                helptext = f"{group} commands: " + ", ".join(sorted(members)) + "."
                g = out[group] = click.Group(group, help=helptext)
            if not isinstance(g, click.Group):  # a plain command took the group's name: it stays alone
                continue
            for sub, (_summary, cmd) in sorted(members.items()):
                if sub not in g.commands:
                    g.add_command(cmd, sub)
        return out

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except WeldcellError as e:
            debug = ctx.meta.get("weldcell.debug", False)
            if debug:  # the traceback too is redacted: no secret value on the terminal
                from weldcell.sdk.secrets import redact

                sys.stderr.write(redact(traceback.format_exc()))
            if getattr(e, "warning", False):  # a JobWarning: the job finished, its result needs a person
                console.print(f"[bold yellow]warning:[/bold yellow] {escape(e.message)}")
            else:
                console.print(f"[bold red]error:[/bold red] {escape(e.message)}")
            for line in getattr(e, "problems", []) or []:
                console.print(f"  - {escape(line)}")
            if e.fix:
                console.print(f"  [bold]fix:[/bold] {escape(e.fix)}")
            if not debug and _traceback_helps(e):
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
@click.option(
    "--redo",
    "redo",
    multiple=True,
    metavar="STEP",
    help="With --resume: run STEP again although it moved the robot or welded before (repeatable).",
)
@click.option("--dry-run", is_flag=True, help="Log motion commands instead of sending them.")
@click.option("-q", "--quiet", is_flag=True, help="Print only the summary.")
def run(
    profile: Path,
    resume: Path | None,
    runs_dir: Path | None,
    redo: tuple[str, ...],
    dry_run: bool,
    quiet: bool,
) -> None:
    """Run the job of PROFILE (simulated or on hardware) and write a run folder.

    An interrupted run continues with --resume RUN_DIR: captures are verified and kept, computation is
    redone, and a step that moved the robot or welded is never repeated unless named with --redo.
    """
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
        profile, pm, run_dir=resume, runs_dir=runs_dir, reporter=reporter, overrides=overrides, redo=redo
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
            message = e.message.removeprefix(f"{Path(f).resolve()}: ").removeprefix(f"{f}: ")
            console.print(f"[red]✗[/red] {escape(str(f))}: {escape(message)}")
            for line in e.problems:
                console.print(f"    - {escape(line)}")
            if e.fix:
                console.print(f"  [bold]fix:[/bold] {escape(e.fix)}")
            continue
        devices = ", ".join(f"{r}={s.name}" for r, (s, _) in resolved.devices.items())
        out.print(f"[green]✓[/green] {f}  job={loaded.profile.job.name}  devices: {devices or '-'}")
    if failed:
        console.print(f"{failed} of {len(files)} profile(s) invalid")
        sys.exit(3)


@profiles.command("list")
@click.argument("folder", default="profiles", type=click.Path(path_type=Path))
def profiles_list(folder: Path) -> None:
    """List the profiles in FOLDER with their job and description.

    A file that cannot be read is listed with its error and the others still are (exit 3 at the end).
    """
    from weldcell.sdk.errors import ProfileError, UsageError
    from weldcell.sdk.profile import read_profile_file

    if not folder.is_dir():
        raise UsageError(
            f"profile folder not found: {folder}", "give the folder that holds the .toml profiles"
        )
    broken = 0
    for f in sorted(folder.glob("*.toml")):
        try:
            data = read_profile_file(f)
        except ProfileError as e:
            broken += 1
            console.print(f"[red]✗[/red] {escape(str(f))}  [red]error:[/red] {escape(e.message)}")
            continue
        job = data.get("job")
        name = job.get("name", "(inherited)") if isinstance(job, dict) else "(inherited)"
        out.print(
            f"{escape(str(f))}  [bold]{escape(str(name))}[/bold]  {escape(str(data.get('description', '')))}"
        )
    if broken:
        console.print(
            f"{broken} profile(s) could not be read  [bold]fix:[/bold] `weldcell profiles validate FILE`"
        )
        sys.exit(3)


@main.command()
@click.argument("profile", required=False, type=click.Path(path_type=Path))
def devices(profile: Path | None) -> None:
    """What each device plugin needs and, with PROFILE, whether each device of it is reachable."""
    from weldcell.sdk.plugin_listing import device_report

    sys.exit(device_report(get_plugin_manager(), out, profile))


if __name__ == "__main__":  # pragma: no cover
    main()
