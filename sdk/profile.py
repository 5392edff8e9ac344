"""Cell profiles: TOML files that choose a job, its devices and its methods for one physical cell.

Loading a profile (``load_profile``) reads the file and the chain of files it ``extends``,
substitutes ``${env:NAME}`` secrets, and validates the structure. ``validate_profile`` then checks
it against the installed plugins: the job and every device and stage plugin exist and are of the
right kind, their settings validate against the plugins' settings models, optional dependencies
are installed and calibration files exist. Every problem is reported at once, each with the file,
the key path and what to change. Nothing opens a device before validation passes.
"""

from __future__ import annotations

import os
import re
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError
from weldcell.sdk.cell import CellSettings
from weldcell.sdk.descriptors import DeviceSpec, ExporterSpec, JobSpec, StageSpec
from weldcell.sdk.errors import ProfileError, WeldcellError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Length

SCHEMA = "weldcell/profile@1"
_ENV = re.compile(r"\$\{env:([A-Za-z_][A-Za-z0-9_]*)\}")


class Mount(Settings):
    """Where a device sits: ``parent`` frame (``world``, ``base`` or ``<role>.flange``) and the offset."""

    parent: str = Field("world", description="parent frame: 'world', or '<device role>.flange'")
    xyz: tuple[Length, Length, Length] = Field((0.0, 0.0, 0.0), description="offset in the parent [m]")
    rpy: tuple[Angle, Angle, Angle] = Field((0.0, 0.0, 0.0), description="roll, pitch, yaw [rad]")


class DeviceEntry(Settings):
    """``[devices.<role>]``: the plugin that drives this device, its settings and its mount."""

    plugin: str = Field(description="device plugin name, e.g. 'robot.ur-rtde' or 'camera.sim'")
    settings: dict[str, Any] = Field(default_factory=dict, description="the plugin's settings")
    mount: Mount = Field(default_factory=Mount, description="where the device is mounted")


class StageEntry(Settings):
    """``[stages.<role>]``: the method plugin for one step of the job and its settings."""

    plugin: str | None = Field(None, description="stage plugin name; the job's default when omitted")
    settings: dict[str, Any] = Field(default_factory=dict, description="the plugin's settings")


class JobEntry(Settings):
    """``[job]``: which job this cell runs and its settings."""

    name: str = Field(description="job name, e.g. 'scan-and-plan'")
    settings: dict[str, Any] = Field(default_factory=dict, description="the job's settings")


class WorkpiecePlacement(Settings):
    """One workpiece of the simulated cell: kind, size parameters and pose in the world frame."""

    kind: str = Field(description="workpiece kind, e.g. 'v-groove-butt' (see docs/simulated-cell.md)")
    params: dict[str, Any] = Field(default_factory=dict, description="size parameters of the kind")
    xyz: tuple[Length, Length, Length] = Field((0.5, 0.0, 0.0), description="position in the world [m]")
    rpy: tuple[Angle, Angle, Angle] = Field((0.0, 0.0, 0.0), description="orientation [rad]")


class SimSection(Settings):
    """``[sim]``: the scene of the simulated cell (ignored by hardware devices)."""

    workpieces: list[WorkpiecePlacement] = Field(default_factory=list, description="parts on the table")
    table_height: Length = Field(0.0, description="height of the table top in the world [m]")


class OutputSettings(Settings):
    """``[output]``: where runs are written and what else to produce."""

    runs_dir: str = Field("runs", description="folder for run folders, relative to the working directory")
    exporters: list[str] = Field(default_factory=list, description="exporter plugins to run on the result")
    exporter_settings: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description='settings per exporter name, e.g. [output.exporter_settings."export.urscript"]',
    )
    report: bool = Field(True, description="write report.md and pictures")


class Profile(Settings):
    """A whole cell profile (see docs/profiles.md)."""

    schema_: str = Field(SCHEMA, alias="schema", description="profile schema id")
    name: str = Field(description="short name of this cell")
    description: str = Field("", description="what this cell is")
    extends: str | None = Field(None, description="a base profile this one overrides, relative path")
    job: JobEntry
    cell: CellSettings = Field(default_factory=CellSettings)
    devices: dict[str, DeviceEntry] = Field(default_factory=dict)
    stages: dict[str, StageEntry] = Field(default_factory=dict)
    calibration: dict[str, str] = Field(
        default_factory=dict, description="name -> file, relative to the profile"
    )
    sim: SimSection = Field(default_factory=SimSection)
    output: OutputSettings = Field(default_factory=OutputSettings)

    model_config = {"populate_by_name": True}


@dataclass
class LoadedProfile:
    """A validated profile and where its keys came from."""

    profile: Profile
    path: Path
    sources: dict[tuple[str, ...], Path] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    # key path -> the text as written, for every value that holds a ``${env:NAME}`` reference: run
    # folders and messages record the reference, never the substituted secret (weldcell.sdk.secrets)
    secrets: dict[tuple[str, ...], str] = field(default_factory=dict)

    def source_of(self, keypath: tuple[str, ...]) -> Path:
        """The file that set ``keypath`` (the nearest set parent key, else the profile itself)."""
        for n in range(len(keypath), 0, -1):
            if keypath[:n] in self.sources:
                return self.sources[keypath[:n]]
        return self.path

    def resolve(self, relative: str) -> Path:
        """A path written in the profile, relative to the file that wrote it."""
        return (self.path.parent / relative).resolve()


def _merge(base: dict, over: dict, src: Path, sources: dict, prefix: tuple[str, ...] = ()) -> dict:
    out = dict(base)
    for k, v in over.items():
        key = (*prefix, k)
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v, src, sources, key)
        else:
            out[k] = v
            _mark(v, src, sources, key)
    return out


def _mark(v: Any, src: Path, sources: dict, key: tuple[str, ...]) -> None:
    sources[key] = src
    if isinstance(v, dict):
        for k2, v2 in v.items():
            _mark(v2, src, sources, (*key, k2))


#: how many profiles an ``extends`` chain may hold (a deeper chain is a mistake, or a generated attack)
MAX_EXTENDS_DEPTH = 32
_MAX_PROFILE_BYTES = 4 << 20


def _read_toml(path: Path) -> dict:
    if not path.is_file():
        raise ProfileError(f"profile not found: {path}", "check the path (profiles live in profiles/)")
    try:
        if path.stat().st_size > _MAX_PROFILE_BYTES:
            raise ProfileError(f"{path}: {path.stat().st_size} bytes is no profile", "check the path")
        raw = path.read_bytes()
    except OSError as e:
        raise ProfileError(f"cannot read profile {path}: {e.strerror}", "check its permissions") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ProfileError(
            f"{path}: not UTF-8 text (byte {e.start} is 0x{raw[e.start]:02x}); is it a binary file?",
            "save the profile as UTF-8 text (a TOML file)",
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ProfileError(f"{path}: not valid TOML: {e}", "fix the TOML syntax at that line") from None
    except RecursionError:
        data = None
    if data is None or _nesting(data) > _MAX_NESTING:
        raise ProfileError(
            f"{path}: tables or arrays nested deeper than {_MAX_NESTING} levels",
            "no profile needs that; fix the file",
        )
    return data


_MAX_NESTING = 64


def _nesting(value: Any) -> int:
    """How deep tables and arrays nest in ``value`` (iterative: no recursion limit to hit)."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        deepest = max(deepest, d)
        if d > _MAX_NESTING:
            break
        if isinstance(v, dict):
            stack.extend((x, d + 1) for x in v.values())
        elif isinstance(v, list):
            stack.extend((x, d + 1) for x in v)
    return deepest


def read_profile_file(path: str | Path) -> dict:
    """The TOML table of one profile file (no ``extends``, no validation); ProfileError when it is
    missing, not UTF-8 text, not TOML or absurdly nested."""
    return _read_toml(Path(path))


def _load_chain(path: Path, sources: dict, files: list[Path], seen: tuple[Path, ...] = ()) -> dict:
    path = path.resolve()
    if path in seen:
        chain = " -> ".join(str(p) for p in (*seen, path))
        raise ProfileError(f"profiles extend each other in a cycle: {chain}", "remove one 'extends'")
    if len(seen) >= MAX_EXTENDS_DEPTH:
        raise ProfileError(
            f"{seen[0]}: the 'extends' chain is deeper than {MAX_EXTENDS_DEPTH} profiles (at {path})",
            f"extend at most {MAX_EXTENDS_DEPTH} levels: merge some base profiles into one",
        )
    data = _read_toml(path)
    files.append(path)
    merged: dict = {}
    if "extends" in data:
        if not isinstance(data["extends"], str) or not data["extends"].strip():
            raise ProfileError(
                f"{path}: extends: {data['extends']!r} is not a file name",
                'write extends = "base.toml" (a path relative to this file)',
            )
        base_path = (path.parent / data["extends"]).resolve()
        if not base_path.is_file():
            raise ProfileError(
                f"{path}: extends: base profile not found: {base_path}",
                "fix the 'extends' path (it is relative to this file)",
            )
        merged = _load_chain(base_path, sources, files, (*seen, path))
    data_wo = {k: v for k, v in data.items() if k != "extends"}
    merged = _merge(merged, data_wo, path, sources)
    if "extends" in data:
        merged["extends"] = data["extends"]
        sources[("extends",)] = path
    return merged


def _substitute_env(
    value: Any,
    keypath: tuple[str, ...],
    problems: list[tuple[tuple[str, ...], str]],
    found: dict[tuple[str, ...], str] | None = None,
) -> Any:
    """Substitute ``${env:NAME}``; ``found`` collects key path -> text as written, and every value is
    registered with :mod:`weldcell.sdk.secrets` so that no output ever shows it."""
    if isinstance(value, dict):
        return {k: _substitute_env(v, (*keypath, k), problems, found) for k, v in value.items()}
    if isinstance(value, list):
        return [_substitute_env(v, (*keypath, str(i)), problems, found) for i, v in enumerate(value)]
    if isinstance(value, str) and _ENV.search(value):
        from weldcell.sdk import secrets

        def repl(m: re.Match) -> str:
            name = m.group(1)
            if name not in os.environ:
                problems.append((keypath, f"environment variable {name} is not set; export {name}=... first"))
                return ""
            secrets.register(os.environ[name], m.group(0))
            return os.environ[name]

        if found is not None:
            found[keypath] = value
        return _ENV.sub(repl, value)
    return value


def _fmt(loc: tuple) -> str:
    return ".".join(str(p) for p in loc) or "(top level)"


def pydantic_problems(
    err: ValidationError, prefix: tuple[str, ...] = ()
) -> list[tuple[tuple[str, ...], str]]:
    """Turn pydantic errors into (key path, 'what is wrong; what to do') pairs."""
    out = []
    for e in err.errors():
        loc = tuple(str(p) for p in e["loc"] if not str(p).startswith("function-after"))
        loc = tuple(p for p in loc if p not in ("tagged-union", "constrained-float"))
        key = (*prefix, *loc)
        if e["type"] == "extra_forbidden":
            msg = "unknown key; remove it or check its spelling"
        elif e["type"] == "missing":
            msg = "required key is missing; add it"
        else:
            msg = e["msg"].removeprefix("Value error, ")
            if "input" in e and not isinstance(e["input"], dict | list):
                msg += f" (got {e['input']!r})"
        out.append((key, msg))
    return out


def load_profile(path: str | Path) -> LoadedProfile:
    """Read and structurally validate a profile (with its ``extends`` chain and env secrets).

    Raises :class:`ProfileError` listing every problem with file and key path.
    """
    path = Path(path)
    sources: dict[tuple[str, ...], Path] = {}
    files: list[Path] = []
    raw = _load_chain(path, sources, files)
    env_problems: list[tuple[tuple[str, ...], str]] = []
    found: dict[tuple[str, ...], str] = {}
    raw = _substitute_env(raw, (), env_problems, found)
    loaded = LoadedProfile(profile=None, path=path.resolve(), sources=sources, files=files)  # type: ignore[arg-type]
    loaded.secrets = found
    problems = list(env_problems)
    try:
        loaded.profile = Profile.model_validate(raw)
    except ValidationError as e:
        problems += pydantic_problems(e)
    if problems:
        raise _profile_error(loaded, problems)
    if loaded.profile.schema_ != SCHEMA:
        raise _profile_error(
            loaded, [(("schema",), f"unsupported schema {loaded.profile.schema_!r}; use {SCHEMA!r}")]
        )
    return loaded


def _profile_error(loaded: LoadedProfile, problems: list[tuple[tuple[str, ...], str]]) -> ProfileError:
    from weldcell.sdk.secrets import redact

    # a secret in a wrongly typed key is named by its reference ("cannot read '${env:TOKEN}' as a length")
    lines = [redact(f"{loaded.source_of(k)}: {_fmt(k)}: {msg}") for k, msg in problems]
    return ProfileError(
        f"profile {loaded.path} is invalid ({len(lines)} problem{'s' if len(lines) != 1 else ''})",
        "fix the keys listed; `weldcell profiles validate FILE` checks again",
        problems=lines,
    )


def _dist(registry, category: str, name: str) -> str | None:
    """The distribution that provides a registered name (for the install hint of a missing extra)."""
    entry = getattr(registry, "entry", None)
    return entry(category, name).provider.distribution if entry else None


_OLD_KEYS = ("job_spec", "job", "devices", "stages", "exporters", "exporter_settings")


@dataclass(frozen=True)
class ResolvedProfile:
    """What :func:`validate_profile` found: the plugins a profile chose, with their validated settings.

    ``job_spec``/``job``: the job's descriptor and its settings object; ``devices`` and ``stages``:
    ``{role: (spec, settings)}`` (devices as written in the profile, stages for every stage role of
    the job, the job's default plugin where the profile names none); ``exporters``: the exporters'
    descriptors in the profile's order; ``exporter_settings``: ``{exporter name: settings}``.
    Frozen: a job that runs another job as a phase derives its view with :func:`dataclasses.replace`.
    """

    job_spec: JobSpec
    job: Settings
    devices: dict[str, tuple[DeviceSpec, Settings]] = field(default_factory=dict)
    stages: dict[str, tuple[StageSpec, Settings]] = field(default_factory=dict)
    exporters: list[ExporterSpec] = field(default_factory=list)
    exporter_settings: dict[str, Settings] = field(default_factory=dict)

    def __getitem__(self, key: str) -> Any:
        """Deprecated: the dict access of earlier versions (``resolved["stages"]``); use the attributes."""
        if key not in _OLD_KEYS:
            raise KeyError(key)
        warnings.warn(
            f'resolved["{key}"] is deprecated; use resolved.{key} (weldcell.sdk.profile.ResolvedProfile)',
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(self, key)


def validate_profile(loaded: LoadedProfile, registry, extra_checks=None) -> ResolvedProfile:
    """Check a loaded profile against the installed plugins.

    Returns the plugins chosen and their validated settings (:class:`ResolvedProfile`). Raises
    :class:`ProfileError` with every problem found. ``extra_checks(loaded)`` adds plugins' own checks
    (:meth:`weldcell.sdk.plugins.PluginManager.check_profile`).
    """
    p = loaded.profile
    problems: list[tuple[tuple[str, ...], str]] = []
    try:
        job = registry.get("job", p.job.name)
    except WeldcellError as e:
        problems.append((("job", "name"), f"{e.message}; {e.fix}" if e.fix else e.message))
        raise _profile_error(loaded, problems) from None
    job_settings = _settings_for(problems, job, p.job.settings, ("job", "settings"))
    devices = _resolve_devices(p, job, registry, problems)
    stages = _resolve_stages(p, job, registry, problems)
    exporters, exporter_settings = _resolve_exporters(p, registry, problems)
    _check_calibration_files(loaded, problems)
    if extra_checks is not None:
        problems.extend(extra_checks(loaded))

    if problems:
        raise _profile_error(loaded, problems)
    return ResolvedProfile(job, job_settings, devices, stages, exporters, exporter_settings)


Problems = list[tuple[tuple[str, ...], str]]


def _settings_for(problems: Problems, spec, values: dict, key: tuple[str, ...]):
    """``spec``'s settings model validated from ``values``; None (and the problems noted) when invalid."""
    try:
        return spec.settings.model_validate(values)
    except ValidationError as e:
        problems.extend(pydantic_problems(e, key))
        return None


def _resolve_devices(p, job, registry, problems: Problems) -> dict[str, tuple[Any, Any]]:
    """``{role: (DeviceSpec, settings)}`` of the profile's devices, checked against the job's roles."""
    devices: dict[str, tuple[Any, Any]] = {}
    roles = {r.role: r for r in job.devices}
    for role, entry in p.devices.items():
        key = ("devices", role)
        if role not in roles and job.any_devices:
            try:
                spec = registry.get("device", entry.plugin)
                spec.check_available(_dist(registry, "device", entry.plugin))
            except WeldcellError as e:
                problems.append(((*key, "plugin"), f"{e.message}; {e.fix}" if e.fix else e.message))
                continue
            devices[role] = (spec, _settings_for(problems, spec, entry.settings, (*key, "settings")))
            continue
        if role not in roles:
            problems.append(
                (
                    key,
                    f"job '{job.name}' uses no device '{role}'; its devices are: "
                    f"{', '.join(roles) or '(none)'}",
                )
            )
            continue
        try:
            spec = registry.get("device", entry.plugin, kind=roles[role].kind)
            spec.check_available(_dist(registry, "device", entry.plugin))
        except WeldcellError as e:
            problems.append(((*key, "plugin"), f"{e.message}; {e.fix}" if e.fix else e.message))
            continue
        settings = _settings_for(problems, spec, entry.settings, (*key, "settings"))
        if entry.mount.parent not in ("world", "base") and not entry.mount.parent.endswith(".flange"):
            problems.append(
                (
                    (*key, "mount", "parent"),
                    f"unknown frame '{entry.mount.parent}'; use 'world' or '<device role>.flange'",
                )
            )
        elif (
            entry.mount.parent.endswith(".flange") and entry.mount.parent[: -len(".flange")] not in p.devices
        ):
            problems.append(
                ((*key, "mount", "parent"), f"'{entry.mount.parent}' names no device of this profile")
            )
        devices[role] = (spec, settings)
    for role, r in roles.items():
        if role not in p.devices and not r.optional:
            problems.append(
                (
                    ("devices", role),
                    f"job '{job.name}' needs a {r.kind} as device '{role}' "
                    f"({r.summary}); add [devices.{role}] with a plugin",
                )
            )

    return devices


def _resolve_stages(p, job, registry, problems: Problems) -> dict[str, tuple[Any, Any]]:
    """``{role: (StageSpec, settings)}`` of every stage role of the job (the profile's plugin, else the
    default)."""
    stages: dict[str, tuple[Any, Any]] = {}
    stage_roles = {r.role: r for r in job.stages}
    for role in p.stages:
        if role not in stage_roles:
            problems.append(
                (
                    ("stages", role),
                    f"job '{job.name}' has no stage '{role}'; its stages are: "
                    f"{', '.join(stage_roles) or '(none)'}",
                )
            )
    for role, r in stage_roles.items():
        entry = p.stages.get(role)
        name = (entry.plugin if entry and entry.plugin else None) or r.default
        key = ("stages", role)
        try:
            spec = registry.get("stage", name, kind=r.kind)
            spec.check_available(_dist(registry, "stage", name))
        except WeldcellError as e:
            problems.append(((*key, "plugin"), f"{e.message}; {e.fix}" if e.fix else e.message))
            continue
        stages[role] = (
            spec,
            _settings_for(problems, spec, entry.settings if entry else {}, (*key, "settings")),
        )

    return stages


def _resolve_exporters(p, registry, problems: Problems) -> tuple[list[Any], dict[str, Any]]:
    """The profile's exporters and their settings."""
    exporters: list[Any] = []
    exporter_settings: dict[str, Any] = {}
    for i, name in enumerate(p.output.exporters):
        try:
            spec = registry.get("exporter", name)
            spec.check_available(_dist(registry, "exporter", name))
            exporters.append(spec)
        except WeldcellError as e:
            problems.append(
                (("output", "exporters", str(i)), f"{e.message}; {e.fix}" if e.fix else e.message)
            )
            continue
        exporter_settings[name] = _settings_for(
            problems, spec, p.output.exporter_settings.get(name, {}), ("output", "exporter_settings", name)
        )
    for name in p.output.exporter_settings:
        if name not in p.output.exporters:
            problems.append(
                (
                    ("output", "exporter_settings", name),
                    f"'{name}' is not in output.exporters; add it there or remove these settings",
                )
            )

    return exporters, exporter_settings


def _check_calibration_files(loaded: LoadedProfile, problems: Problems) -> None:
    """Every ``[calibration]`` file exists (relative to the profile that names it)."""
    for name, rel in loaded.profile.calibration.items():
        f = (loaded.source_of(("calibration", name)).parent / rel).resolve()
        if not f.is_file():
            problems.append(
                (("calibration", name), f"file not found: {f}; run `weldcell calibrate` or fix the path")
            )
