"""The job runner: validates a profile, opens its devices, runs the job's steps, writes the run folder.

A run folder (``runs/<profile>-<time>/``) holds ``state.json`` (what is done, what was captured),
every artifact (written atomically), ``result.json`` (figures + provenance) and ``report.md``.
An interrupted run keeps everything captured so far; ``weldcell run PROFILE --resume RUN_DIR``
continues it, and jobs skip captures that ``state.json`` lists.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata as md
import platform
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk import artifacts
from weldcell.sdk.errors import DeviceError, JobError, WeldcellError
from weldcell.sdk.geometry import T_from_rpy
from weldcell.sdk.plugins import PluginManager
from weldcell.sdk.profile import LoadedProfile, Mount, load_profile, validate_profile

RESULT_SCHEMA = "weldcell/run-result@1"


class Reporter:
    """Progress output of a run. The default prints nothing; the CLI passes a rich-backed one."""

    def step_started(self, name: str, total: int | None = None) -> None:
        """A step began (``total`` units of work when known)."""

    def advance(self, name: str, done: int, total: int | None = None, message: str = "") -> None:
        """Progress inside a step."""

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


@dataclass
class RunState:
    """The resumable part of a run, saved to ``state.json`` after every change."""

    path: Path
    data: dict[str, Any] = field(default_factory=lambda: {"steps": {}, "captures": [], "notes": {}})

    @classmethod
    def load_or_new(cls, path: Path) -> RunState:
        if path.is_file():
            return cls(path, artifacts.read_json(path))
        state = cls(path)
        state.save()
        return state

    def save(self) -> None:
        artifacts.write_json(self.path, self.data)

    @property
    def captures(self) -> list[dict[str, Any]]:
        """Captures recorded so far (each a dict a job defines, e.g. file name + pose)."""
        return self.data["captures"]

    def add_capture(self, record: dict[str, Any]) -> None:
        """Record a capture and save at once, so an interruption never loses it."""
        self.data["captures"].append(record)
        self.save()

    def step_done(self, name: str) -> bool:
        return self.data["steps"].get(name, {}).get("status") == "done"


class RunContext:
    """Everything a job's ``run(ctx)`` uses: settings, devices, stages, the run folder, progress."""

    def __init__(
        self,
        loaded: LoadedProfile,
        resolved: dict[str, Any],
        pm: PluginManager,
        run_dir: Path,
        reporter: Reporter,
    ) -> None:
        self.loaded = loaded
        self.profile = loaded.profile
        self.resolved = resolved
        self.pm = pm
        self.run_dir = run_dir
        self.reporter = reporter
        self.settings = resolved["job"]
        self.devices: dict[str, Any] = {}
        self.shared: dict[str, Any] = {}
        self.timings: dict[str, float] = {}
        self.state = RunState.load_or_new(run_dir / "state.json")
        self.figures: dict[str, Any] = {}
        self._stages: dict[str, Any] = {}
        self.rng = np.random.default_rng(self.profile.cell.seed)

    # -- methods ---------------------------------------------------------------------------------
    def stage(self, role: str) -> Any:
        """The stage object filling ``role`` (built once from its plugin and settings)."""
        if role not in self._stages:
            spec, settings = self.resolved["stages"][role]
            self._stages[role] = spec.factory(settings)
        return self._stages[role]

    def stage_settings(self, role: str) -> Any:
        return self.resolved["stages"][role][1]

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
        return artifacts.write_json(self.path(name), data)

    def write_text(self, name: str, text: str) -> Path:
        return artifacts.write_text(self.path(name), text)

    @contextlib.contextmanager
    def step(self, name: str, total: int | None = None) -> Iterator[Callable[..., None]]:
        """Time a step, show its progress and record it in ``state.json``.

        Yields ``advance(done, total=None, message="")`` for progress inside the step.
        """
        self.reporter.step_started(name, total)
        self.state.data["steps"][name] = {"status": "running"}
        self.state.save()
        t0 = time.perf_counter()

        def advance(done: int, total_: int | None = total, message: str = "") -> None:
            self.reporter.advance(name, done, total_, message)

        try:
            yield advance
        except BaseException as e:
            self.state.data["steps"][name] = {
                "status": "failed",
                "error": str(e).splitlines()[0] if str(e) else type(e).__name__,
            }
            self.state.save()
            raise
        dt = time.perf_counter() - t0
        self.timings[name] = self.timings.get(name, 0.0) + dt
        self.state.data["steps"][name] = {"status": "done", "seconds": round(dt, 4)}
        self.state.save()
        self.reporter.step_finished(name, dt)


def provenance(ctx: RunContext) -> dict[str, Any]:
    """Profile, plugin versions, settings and timings of a run, for result.json."""
    used: dict[str, Any] = {}
    reg = ctx.pm.registry
    spec = ctx.resolved["job_spec"]
    used[f"job:{spec.name}"] = reg.entry("job", spec.name).provider
    for role, (s, _) in ctx.resolved["devices"].items():
        used[f"device:{role}:{s.name}"] = reg.entry("device", s.name).provider
    for role, (s, _) in ctx.resolved["stages"].items():
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
        "settings": {
            "job": ctx.settings.model_dump(mode="json") if ctx.settings is not None else {},
            "stages": {r: s.model_dump(mode="json") for r, (_, s) in ctx.resolved["stages"].items()},
            "devices": {r: s.model_dump(mode="json") for r, (_, s) in ctx.resolved["devices"].items()},
            "cell": ctx.profile.cell.model_dump(mode="json"),
        },
        "timings_s": {k: round(v, 4) for k, v in ctx.timings.items()},
    }


def prepare(profile_path: str | Path, pm: PluginManager) -> tuple[LoadedProfile, dict[str, Any]]:
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
    for role, (spec, settings) in ctx.resolved["devices"].items():
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
        with ctx.step(f"open {role} ({spec.name})"):
            device = spec.factory(settings, dctx)
            ctx.devices[role] = stack.enter_context(device)


def run_job(
    profile_path: str | Path,
    pm: PluginManager,
    *,
    run_dir: str | Path | None = None,
    runs_dir: str | Path | None = None,
    reporter: Reporter | None = None,
    overrides: Callable[[LoadedProfile], None] | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Run the job of a profile; returns the run folder and the result dict.

    ``run_dir`` resumes an existing run folder. Raises a :class:`WeldcellError` subclass on
    failure, after writing what was captured; ``result.json`` then holds the error.
    """
    loaded, resolved = prepare(profile_path, pm)
    if overrides:
        overrides(loaded)
    if run_dir is not None:
        run = Path(run_dir)
        if not (run / "state.json").is_file():
            raise JobError(f"{run} is not a run folder (no state.json)", "give the folder of an earlier run")
    else:
        run = new_run_dir(loaded, runs_dir)
    ctx = RunContext(loaded, resolved, pm, run, reporter or Reporter())
    spec = resolved["job_spec"]
    started = datetime.now(UTC).isoformat()
    result: dict[str, Any] = {
        "schema": RESULT_SCHEMA,
        "job": spec.name,
        "profile": loaded.profile.name,
        "started": started,
    }
    try:
        with contextlib.ExitStack() as stack:
            open_devices(ctx, stack)
            figures = spec.run(ctx) or {}
        result.update(status="ok", figures=figures)
    except WeldcellError as e:
        result.update(status="failed", error={"type": type(e).__name__, "message": e.message, "fix": e.fix})
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
            f"captures so far are kept in {run}; rerun with --debug for the traceback",
        ) from e
    finally:
        result["finished"] = datetime.now(UTC).isoformat()
        result["provenance"] = provenance(ctx)
        result["figures"] = {**ctx.figures, **result.get("figures", {})}
        artifacts.write_json(run / "result.json", result)
    return run, result
