"""The job runner: validates a profile, opens its devices, runs the job's steps, writes the run folder.

A run folder (``runs/<profile>-<time>/``) holds ``state.json`` (every step with its kind and status,
every capture with its size and SHA-256), every artifact (written atomically and durably),
``result.json`` (figures + provenance) and ``report.md``. An interrupted run keeps everything captured
so far; ``weldcell run PROFILE --resume RUN_DIR`` continues it where it stopped:

- ``compute`` steps (pure computation) are simply computed again from the captures;
- ``motion`` steps (a robot moved, a torch welded: side effects on the cell) that are done are never
  repeated, and one that was interrupted after it started stops the resume with an error, unless the
  operator asks for it with ``--redo STEP``;
- ``checkpointed`` steps (a scan) continue from their own records: captures already taken are verified
  against their size and checksum and kept, the step goes on from the last good one.

Nothing a run writes (files, messages, provenance) contains a ``${env:NAME}`` secret's value
(:mod:`weldcell.sdk.secrets`). See docs/runs.md. The run's ``state.json`` record is
:class:`~weldcell.sdk.run_state.RunState` (:mod:`weldcell.sdk.run_state`).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata as md
import platform
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk import artifacts, secrets
from weldcell.sdk.errors import DeviceError, JobError, SafetyError, UsageError, WeldcellError
from weldcell.sdk.geometry import T_from_rpy
from weldcell.sdk.plugins import PluginManager
from weldcell.sdk.profile import LoadedProfile, Mount, ResolvedProfile, load_profile, validate_profile
from weldcell.sdk.run_state import (  # noqa: F401 - STATE_SCHEMA, STARTED, RunState re-exported (old home)
    STARTED,
    STATE_SCHEMA,
    RunState,
    step_key,
    step_label,
    utc_now,
)
from weldcell.sdk.settings import with_defaults

RESULT_SCHEMA = "weldcell/run-result@1"
STEP_KINDS = ("setup", "compute", "checkpointed", "motion")


class Reporter:
    """Progress output of a run. The default prints nothing; the CLI passes a rich-backed one."""

    def step_started(self, name: str, total: int | None = None) -> None:
        """A step began (``total`` units of work when known)."""

    def advance(self, name: str, done: int, total: int | None = None, message: str = "") -> None:
        """Progress inside a step."""

    def step_label(self, name: str, label: str) -> None:
        """Show step ``name`` as ``label`` when it finishes (it names the stage plugins that ran in it;
        called just before :meth:`step_finished`, only when the two differ)."""

    def step_finished(self, name: str, seconds: float) -> None:
        """A step ended."""

    def info(self, message: str) -> None:
        """A line for the operator."""


@dataclass
class DeviceContext:
    """What a device factory gets besides its settings."""

    role: str
    mount: Mount
    profile: LoadedProfile
    shared: dict[str, Any]
    devices: dict[str, Any]
    dry_run: bool
    safety: Any
    seed: int

    @property
    def T_parent_device(self) -> np.ndarray:
        """The mount offset as a 4x4 transform (parent frame <- device frame)."""
        return T_from_rpy(self.mount.rpy, self.mount.xyz)

    def device(self, role: str) -> Any:
        """Another device of this run, opened earlier (devices open in profile order, parents first)."""
        if role not in self.devices:
            raise DeviceError(
                f"device '{self.role}' needs device '{role}', which is not open",
                f"add [devices.{role}] to the profile, before [devices.{self.role}]",
            )
        return self.devices[role]


class RunContext:
    """Everything a job's ``run(ctx)`` uses: settings, devices, stages, the run folder, progress."""

    def __init__(
        self,
        loaded: LoadedProfile,
        resolved: ResolvedProfile,
        pm: PluginManager,
        run_dir: Path,
        reporter: Reporter,
        redo: tuple[str, ...] = (),
    ) -> None:
        self.loaded = loaded
        self.profile = loaded.profile
        self.resolved = resolved
        self.pm = pm
        self.run_dir = run_dir
        self.reporter = reporter
        self.settings = resolved.job
        self.devices: dict[str, Any] = {}
        self.shared: dict[str, Any] = {}
        self.timings: dict[str, float] = {}
        self.resumed = (run_dir / "state.json").is_file()
        self.state = RunState.load_or_new(run_dir / "state.json")
        # --redo STEP: steps the operator asked to run again although they were done or interrupted
        self.redo: set[str] = {self.state.match_step(k) for k in redo}
        self.figures: dict[str, Any] = {}
        self._stages: dict[str, Any] = {}
        self._open_steps: list[list[str]] = []  # stage roles used inside each step being run
        self.rng = np.random.default_rng(self.profile.cell.seed)

    # -- methods ---------------------------------------------------------------------------------
    def stage(self, role: str) -> Any:
        """The stage object filling ``role`` (built once from its plugin and settings). Used inside a
        step, the step is labelled with the plugin's name (:func:`step_label`)."""
        if self._open_steps and role not in self._open_steps[-1]:
            self._open_steps[-1].append(role)
        if role not in self._stages:
            spec, settings = self.resolved.stages[role]
            self._stages[role] = spec.factory(settings)
        return self._stages[role]

    def stage_settings(self, role: str) -> Any:
        return self.resolved.stages[role][1]

    def device(self, role: str) -> Any:
        """An open device by role; a clear error when the profile has none."""
        if role not in self.devices:
            raise DeviceError(
                f"this run has no device '{role}'", f"add [devices.{role}] to {self.loaded.path}"
            )
        return self.devices[role]

    def calibration_file(self, name: str) -> Path | None:
        """The calibration file named ``name`` in the profile, or None."""
        rel = self.profile.calibration.get(name)
        if rel is None:
            return None
        return (self.loaded.source_of(("calibration", name)).parent / rel).resolve()

    # -- run folder ------------------------------------------------------------------------------
    def path(self, name: str) -> Path:
        """A path inside the run folder."""
        p = self.run_dir / name
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def write_json(self, name: str, data: Any) -> Path:
        """Write JSON into the run folder (atomically, durably, secrets as references)."""
        return artifacts.write_json(self.path(name), secrets.redact_obj(data))

    def write_text(self, name: str, text: str) -> Path:
        """Write text into the run folder (atomically, durably, secrets as references)."""
        return artifacts.write_text(self.path(name), secrets.redact(text))

    def save_figure(self, fig: Any, name: str, **kwargs: Any) -> Path:
        """A matplotlib figure into the run folder (atomically, durably)."""
        return artifacts.save_figure(fig, self.path(name), **kwargs)

    def write_programs(
        self, weld_path: dict, cell: dict[str, Any] | None = None, stem: str = "weld_path"
    ) -> list[str]:
        """Run every exporter of ``[output] exporters`` on a weld-path document; write its file(s) under
        ``programs/``. ``cell`` fills exporter settings the profile does not set (a robot's
        ``program_settings()``: its model, tool and the cell's limits, so programs are gate-checked for
        that robot). A program the safety gate refuses is not written: the refusal is kept in
        ``figures["programs_refused"]`` and told to the operator. Returns the files written."""
        written = []
        for spec in self.resolved.exporters:
            given = self.resolved.exporter_settings.get(spec.name)
            settings = with_defaults(spec.settings, given, cell or {}) if spec.settings else given
            try:
                if spec.files is not None:
                    files = spec.files(weld_path, settings)
                else:
                    files = {f"{stem}{spec.suffix}": spec.export(weld_path, settings)}
            except SafetyError as e:
                self.figures.setdefault("programs_refused", {})[spec.name] = e.message
                self.reporter.info(f"[yellow]{spec.name}: no program written: {e.message}[/yellow]")
                continue
            for file_name, text in files.items():
                self.write_text(f"programs/{file_name}", text)
                written.append(f"programs/{file_name}")
        return written

    @property
    def resume_command(self) -> str:
        """The command that continues this run."""
        return f"weldcell run {self.loaded.path} --resume {self.run_dir}"

    def redoing(self, name: str) -> bool:
        """The operator asked to run step ``name`` again (``--redo``)."""
        return name in self.redo

    def skip(self, name: str) -> bool:
        """A ``motion`` or ``checkpointed`` step that is done and must not run again (no ``--redo``).

        Jobs call it before such a step: ``if not ctx.skip(NAME): with ctx.step(NAME, kind="motion"): ...``
        """
        if self.state.step_done(name) and name not in self.redo:
            self.reporter.info(f"[dim]{name}: done in an earlier attempt, not repeated[/dim]")
            return True
        return False

    def _guard_motion(self, name: str) -> None:
        rec = self.state.steps.get(name, {})
        status = rec.get("status")
        if name in self.redo or status is None:
            return
        if status == "done":
            raise JobError(
                f"step '{name}' moved the robot in an earlier attempt of this run; it is not repeated "
                "automatically",
                f"check the robot and the part; to run it again on purpose: `{self.resume_command} "
                f"--redo '{step_key(name)}'`, or start a new run",
            )
        progress = f" ({rec['progress']})" if rec.get("progress") else ""
        raise JobError(
            f"step '{name}' was interrupted after it started{progress}: the robot may have moved or "
            "welded part of it, so it is not repeated automatically",
            f"check the robot and the part; then run it again from its start with `{self.resume_command} "
            f"--redo '{step_key(name)}'`, or start a new run",
        )

    @contextlib.contextmanager
    def step(
        self, name: str, total: int | None = None, kind: str = "compute"
    ) -> Iterator[Callable[..., None]]:
        """Time a step, show its progress and record it (kind, status) in ``state.json``.

        ``kind`` is ``compute`` (pure computation: recomputed on resume), ``motion`` (moves the robot or
        welds: never repeated on resume without ``--redo``; see :meth:`skip`), ``checkpointed`` (moves
        the robot but records its progress and continues from it) or ``setup`` (opening devices).
        Yields ``advance(done, total=None, message="")`` for progress inside the step.
        """
        if kind not in STEP_KINDS:
            raise ValueError(f"unknown step kind {kind!r}; use one of {STEP_KINDS}")
        if kind == "motion":
            self._guard_motion(name)
        self.reporter.step_started(name, total)
        prev = self.state.steps.get(name, {})
        self.state.steps[name] = {
            "kind": kind,
            "status": "running",
            "started": utc_now(),
            "attempts": int(prev.get("attempts", 0)) + 1,
            **({"redone": True} if name in self.redo else {}),
        }
        self.state.save()
        t0 = time.perf_counter()

        def advance(done: int, total_: int | None = total, message: str = "") -> None:
            self.reporter.advance(name, done, total_, message)

        self._open_steps.append([])
        try:
            yield advance
        except BaseException as e:
            status = "interrupted" if isinstance(e, KeyboardInterrupt) else "failed"
            text = secrets.redact(str(e).splitlines()[0] if str(e) else type(e).__name__)
            self.state.set_step(name, status=status, error=text, finished=utc_now())
            raise
        finally:
            roles = self._open_steps.pop()
        dt = time.perf_counter() - t0
        self.timings[name] = self.timings.get(name, 0.0) + dt
        plugins = [self.resolved.stages[r][0].name for r in roles if r in self.resolved.stages]
        used = {"plugins": plugins} if plugins else {}
        self.state.set_step(name, status="done", seconds=round(dt, 4), finished=utc_now(), **used)
        self.redo.discard(name)
        label = step_label(name, plugins)
        if label != name and callable(getattr(self.reporter, "step_label", None)):
            self.reporter.step_label(name, label)
        self.reporter.step_finished(name, dt)


def provenance(ctx: RunContext) -> dict[str, Any]:
    """Profile, plugin versions, settings and timings of a run, for result.json."""
    used: dict[str, Any] = {}
    reg = ctx.pm.registry
    spec = ctx.resolved.job_spec
    used[f"job:{spec.name}"] = reg.entry("job", spec.name).provider
    for role, (s, _) in ctx.resolved.devices.items():
        used[f"device:{role}:{s.name}"] = reg.entry("device", s.name).provider
    for role, (s, _) in ctx.resolved.stages.items():
        used[f"stage:{role}:{s.name}"] = reg.entry("stage", s.name).provider
    try:
        version = md.version("weldcell")
    except md.PackageNotFoundError:
        version = "unknown"
    files = {str(f): hashlib.sha256(f.read_bytes()).hexdigest()[:16] for f in ctx.loaded.files}
    return {
        "weldcell": version,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "profile": str(ctx.loaded.path),
        "profile_files_sha256": files,
        "plugins": {
            k: {"plugin": p.plugin, "distribution": p.distribution, "version": p.version}
            for k, p in used.items()
        },
        "settings": settings_with_references(ctx),
        "secrets": secrets.known_references(),
        "timings_s": {k: round(v, 4) for k, v in ctx.timings.items()},
    }


def settings_with_references(ctx: RunContext) -> dict[str, Any]:
    """The run's settings as used, with every ``${env:NAME}`` value written as its reference."""
    out = {
        "job": ctx.settings.model_dump(mode="json") if ctx.settings is not None else {},
        "stages": {r: s.model_dump(mode="json") for r, (_, s) in ctx.resolved.stages.items()},
        "devices": {r: s.model_dump(mode="json") for r, (_, s) in ctx.resolved.devices.items()},
        "cell": ctx.profile.cell.model_dump(mode="json"),
    }
    for key, written in getattr(ctx.loaded, "secrets", {}).items():
        # profile key path -> where the same value sits in the dump above
        if key[:1] == ("job",) and key[1:2] == ("settings",):
            where = (out["job"], key[2:])
        elif key[:1] in (("devices",), ("stages",)) and len(key) > 3 and key[2] == "settings":
            where = (out[key[0]].get(key[1], {}), key[3:])
        elif key[:1] == ("cell",):
            where = (out["cell"], key[1:])
        else:
            continue
        node, rest = where
        for k in rest[:-1]:
            node = node[int(k)] if isinstance(node, list) and k.isdigit() else node.get(k, {})
        last = rest[-1] if rest else None
        if isinstance(node, dict) and last in node:
            node[last] = written
        elif isinstance(node, list) and last is not None and last.isdigit() and int(last) < len(node):
            node[int(last)] = written
    return secrets.redact_obj(out)


def prepare(profile_path: str | Path, pm: PluginManager) -> tuple[LoadedProfile, ResolvedProfile]:
    """Load and fully validate a profile (nothing is opened)."""
    loaded = load_profile(profile_path)
    resolved = validate_profile(loaded, pm.registry, extra_checks=pm.check_profile)
    return loaded, resolved


def new_run_dir(loaded: LoadedProfile, runs_dir: str | Path | None = None) -> Path:
    base = Path(runs_dir or loaded.profile.output.runs_dir)
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    run = base / f"{loaded.profile.name}-{stamp}"
    n = 1
    while run.exists():
        n += 1
        run = base / f"{loaded.profile.name}-{stamp}-{n}"
    run.mkdir(parents=True)
    return run


def open_devices(ctx: RunContext, stack: contextlib.ExitStack) -> None:
    """Create and activate every device of the profile; closed by ``stack`` in reverse order."""
    p = ctx.profile
    for role, (spec, settings) in ctx.resolved.devices.items():
        entry = p.devices[role]
        dctx = DeviceContext(
            role=role,
            mount=entry.mount,
            profile=ctx.loaded,
            shared=ctx.shared,
            devices=ctx.devices,
            dry_run=p.cell.dry_run,
            safety=p.cell.safety,
            seed=p.cell.seed,
        )
        with ctx.step(f"open {role} ({spec.name})", kind="setup"):
            device = spec.factory(settings, dctx)
            ctx.devices[role] = stack.enter_context(device)


def _device_fix(e: DeviceError, profile_path: str | Path, run: Path) -> str:
    """The fix of a device that dropped during a job: the device's own advice (unless it is an API hint
    such as 'call recover()') and the command that resumes the run."""
    own = e.fix if e.fix and "()" not in e.fix else "check its power, cable and network connection"
    return f"{own}; what was captured is kept: continue with `weldcell run {profile_path} --resume {run}`"


def _check_resume(ctx: RunContext, profile_path: str | Path) -> None:
    """Refuse a resume that would repeat an interrupted motion step (before any device opens)."""
    pending = [n for n in ctx.state.interrupted_motions() if n not in ctx.redo]
    if pending:
        ctx._guard_motion(pending[0])


def run_job(
    profile_path: str | Path,
    pm: PluginManager,
    *,
    run_dir: str | Path | None = None,
    runs_dir: str | Path | None = None,
    reporter: Reporter | None = None,
    overrides: Callable[[LoadedProfile], None] | None = None,
    redo: tuple[str, ...] | list[str] = (),
) -> tuple[Path, dict[str, Any]]:
    """Run the job of a profile; returns the run folder and the result dict.

    ``run_dir`` resumes an existing run folder where it stopped; ``redo`` names steps to run again
    although they were done or interrupted (``--redo``; only with ``run_dir``). Raises a
    :class:`WeldcellError` subclass on failure, after writing what was captured; ``result.json`` then
    holds the error. No message or file holds a ``${env:NAME}`` secret's value.
    """
    secrets.install_log_redaction()
    try:
        return _run_job(profile_path, pm, run_dir, runs_dir, reporter, overrides, tuple(redo))
    except WeldcellError as e:
        secrets.redact_error(e)
        raise


def _run_job(profile_path, pm, run_dir, runs_dir, reporter, overrides, redo):
    loaded, resolved = prepare(profile_path, pm)
    if overrides:
        overrides(loaded)
    if run_dir is not None:
        run = Path(run_dir)
        if not (run / "state.json").is_file():
            raise JobError(f"{run} is not a run folder (no state.json)", "give the folder of an earlier run")
    else:
        if redo:
            raise UsageError("--redo needs --resume RUN_DIR", "name the run folder whose step to run again")
        run = new_run_dir(loaded, runs_dir)
    ctx = RunContext(loaded, resolved, pm, run, reporter or Reporter(), redo=redo)
    _check_resume(ctx, profile_path)
    spec = resolved.job_spec
    attempts = ctx.state.data.setdefault("attempts", [])
    attempts.append({"started": utc_now(), "redo": sorted(ctx.redo)})
    ctx.state.save()
    result: dict[str, Any] = {
        "schema": RESULT_SCHEMA,
        "job": spec.name,
        "profile": loaded.profile.name,
        "started": attempts[0]["started"],
        "attempt": len(attempts),
    }
    if len(attempts) > 1:
        result["resumed"] = {"attempt_started": attempts[-1]["started"], "redo": sorted(ctx.redo)}
    try:
        with contextlib.ExitStack() as stack:
            open_devices(ctx, stack)
            figures = spec.run(ctx) or {}
        result.update(status="ok", figures=figures)
    except DeviceError as e:
        e.fix = _device_fix(e, profile_path, run)
        result.update(status="failed", error={"type": type(e).__name__, "message": e.message, "fix": e.fix})
        raise
    except WeldcellError as e:
        status = "warning" if getattr(e, "warning", False) else "failed"  # JobWarning: all was written
        result.update(status=status, error={"type": type(e).__name__, "message": e.message, "fix": e.fix})
        raise
    except KeyboardInterrupt:
        result.update(
            status="interrupted",
            error={
                "message": "interrupted by the operator",
                "fix": f"weldcell run {profile_path} --resume {run}",
            },
        )
        raise
    except Exception as e:
        result.update(status="failed", error={"type": type(e).__name__, "message": str(e)})
        raise JobError(
            f"job '{spec.name}' failed: {type(e).__name__}: {e}",
            f"captures so far are kept in {run}; rerun with --debug for the traceback, then continue with "
            f"`weldcell run {profile_path} --resume {run}`",
        ) from e
    finally:
        result["finished"] = datetime.now(UTC).isoformat()
        result["provenance"] = provenance(ctx)
        result["figures"] = {**ctx.figures, **result.get("figures", {})}
        attempts[-1].update(finished=utc_now(), status=result.get("status", "failed"))
        ctx.state.save()
        result = secrets.redact_obj(result)
        artifacts.write_json(run / "result.json", result)
    return run, result
