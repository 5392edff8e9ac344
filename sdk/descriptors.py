"""Typed descriptors that plugins register through the hooks of :mod:`weldcell.sdk.hookspecs`.

Every descriptor has a ``category`` (stage, device, job, exporter, command), a ``kind`` inside it
(e.g. a stage of kind ``seam``, a device of kind ``robot``), a dotted ``name`` that profiles use
(``seam.edge-intensity``, ``robot.ur-rtde``), a pydantic ``settings`` model, and optional
``requires``: Python modules mapped to the weldcell extra that installs them. Descriptors hold
factories, never device connections: importing a plugin must not touch hardware.
"""

from __future__ import annotations

import importlib.util
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

from weldcell.sdk.errors import MissingExtraError, PluginError
from weldcell.sdk.settings import NoSettings, Settings

NAME_RE = re.compile(r"^[a-z][a-z0-9]*(?:[-_][a-z0-9]+)*(?:\.[a-z0-9]+(?:[-_][a-z0-9]+)*)+$")

DEVICE_KINDS = (
    "robot",
    "depth_camera",
    "gesture_sensor",
    "displacement_sensor",
    "laser_projector",
    "tactile_camera",
    "imu",
    "gnss",
)


def import_adapter(module: str, requires: dict[str, str], what: str, distribution: str = "weldcell"):
    """Import a plugin's adapter module lazily (inside a factory or probe).

    A vendor package listed in ``requires`` (module -> weldcell extra) that is missing becomes a
    :class:`MissingExtraError` naming the extra (of ``distribution``) to install; any other import
    error propagates.
    """
    import importlib

    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as e:
        top = (e.name or "").split(".")[0]
        for vendor, extra in requires.items():
            if top == vendor.split(".")[0]:
                raise MissingExtraError(what, vendor, extra, distribution) from e
        raise


@dataclass(frozen=True)
class Descriptor:
    """Common fields of everything a plugin registers."""

    name: str
    kind: str
    summary: str
    settings: type[Settings] = NoSettings
    requires: dict[str, str] = field(default_factory=dict)
    """Python module -> weldcell extra, e.g. ``{"rtde_control": "ur"}``."""

    category: ClassVar[str] = "thing"

    def __post_init__(self) -> None:
        if not NAME_RE.match(self.name):
            raise PluginError(
                f"{self.category} name {self.name!r} is not a dotted lower-case name",
                "name things like 'seam.edge-intensity' or 'robot.ur-rtde'",
            )
        if not (isinstance(self.settings, type) and issubclass(self.settings, Settings)):
            raise PluginError(
                f"{self.category} {self.name!r}: settings must be a weldcell.sdk.settings.Settings subclass",
                "derive the settings model from weldcell.sdk.settings.Settings",
            )

    def missing_extras(self) -> list[tuple[str, str]]:
        """(module, extra) pairs whose module cannot be imported here."""
        missing = []
        for module, extra in self.requires.items():
            try:
                found = importlib.util.find_spec(module) is not None
            except (ImportError, ValueError):
                found = False
            if not found:
                missing.append((module, extra))
        return missing

    def check_available(self, distribution: str | None = None) -> None:
        """Raise :class:`MissingExtraError` naming the extra (of ``distribution``, default weldcell)
        when a required module is missing."""
        for module, extra in self.missing_extras():
            raise MissingExtraError(
                f"{self.category} '{self.name}'", module, extra, distribution or "weldcell"
            )


@dataclass(frozen=True)
class StageSpec(Descriptor):
    """A method: ``factory(settings) -> stage object`` whose interface is fixed by ``kind``.

    Stage kinds and their call signatures are documented in :mod:`weldcell.sdk.stages`.
    """

    factory: Callable[[Any], Any] | None = None
    category: ClassVar[str] = "stage"


@dataclass(frozen=True)
class DeviceSpec(Descriptor):
    """A device adapter: ``factory(settings, context) -> Device`` of HAL kind ``kind``.

    ``kind`` is one of :data:`DEVICE_KINDS`. ``simulated`` marks the simulated cell's devices.
    ``probe(settings) -> str`` (optional) says whether the device is reachable, for ``weldcell devices``;
    it raises :class:`weldcell.sdk.errors.DeviceError` when it is not.
    """

    factory: Callable[..., Any] | None = None
    simulated: bool = False
    probe: Callable[[Any], str] | None = None
    category: ClassVar[str] = "device"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.kind not in DEVICE_KINDS:
            raise PluginError(
                f"device {self.name!r} has unknown kind {self.kind!r}",
                f"use one of {', '.join(DEVICE_KINDS)}",
            )


@dataclass(frozen=True)
class DeviceRole:
    """A device a job uses: profiles bind a device to each role under ``[devices.<role>]``."""

    role: str
    kind: str
    summary: str
    optional: bool = False


@dataclass(frozen=True)
class StageRole:
    """A method slot of a job, filled by a stage plugin of ``kind`` (``default`` if the profile is silent)."""

    role: str
    kind: str
    default: str
    summary: str


@dataclass(frozen=True)
class JobSpec(Descriptor):
    """A job (``scan-and-plan``, ``calibrate``, ...): ``run(ctx) -> dict`` of result figures.

    ``devices`` and ``stages`` declare the roles a profile fills. The job name is a plain
    lower-case name (``scan-and-plan``) rather than a dotted one.
    """

    run: Callable[[Any], dict] | None = None
    devices: tuple[DeviceRole, ...] = ()
    stages: tuple[StageRole, ...] = ()
    any_devices: bool = False
    """Accept any device roles (a job that works on whatever the cell has, like ``check-devices``)."""
    category: ClassVar[str] = "job"

    def __post_init__(self) -> None:
        if not re.match(r"^[a-z][a-z0-9-]*$", self.name):
            raise PluginError(f"job name {self.name!r} must be lower-case words joined by '-'", None)
        if not (isinstance(self.settings, type) and issubclass(self.settings, Settings)):
            raise PluginError(f"job {self.name!r}: settings must be a Settings subclass", None)


@dataclass(frozen=True)
class ExporterSpec(Descriptor):
    """Turns a weld path into a robot program or table: ``export(weld_path: dict, settings) -> str``.

    ``suffix`` is the file ending written (``.script``, ``.mod``, ``.csv``). A language whose programs
    are several files (KUKA ``.src`` + ``.dat``) may also give ``files(weld_path, settings) ->
    {file name: text}``; ``export`` then returns the one file that runs alone.
    """

    export: Callable[[dict, Any], str] | None = None
    suffix: str = ".txt"
    files: Callable[[dict, Any], dict[str, str]] | None = None
    category: ClassVar[str] = "exporter"


@dataclass(frozen=True)
class BatchSpec:
    """How ``weldcell batch`` runs an offline command on one input (one Dask task per input).

    The worker calls the command as ``[subcommand] [batch --args] INPUT -o OUT_DIR/<input>/<output>``
    (plus ``report_option <folder>`` when given), exactly as a user would one input at a time.
    ``inputs``: what one input is, ``"file"``, ``"dir"`` or ``"any"``; a folder given to the batch is
    one input when it holds one of ``markers`` (``state.json`` of a run folder), else it expands to its
    files matching ``patterns`` and its sub-folders holding a marker. See docs/scale-out.md.
    """

    output: str
    """File name the command writes with ``-o`` (``path.json``, ``model.ply``)."""
    subcommand: str = ""
    """For a command group: the batchable sub-command (``"hand-eye"`` of ``calibrate``)."""
    inputs: str = "file"
    patterns: tuple[str, ...] = ()
    markers: tuple[str, ...] = ()
    report_option: str | None = None
    """An option that writes a report folder for one input (``--report``), kept with its result."""

    def __post_init__(self) -> None:
        if self.inputs not in ("file", "dir", "any"):
            raise PluginError(f"BatchSpec inputs {self.inputs!r} is not 'file', 'dir' or 'any'", None)
        if not self.output or "/" in self.output:
            raise PluginError(f"BatchSpec output {self.output!r} must be a plain file name", None)


@dataclass(frozen=True)
class CommandSpec:
    """A click command added to the ``weldcell`` CLI (``weldcell seam``, ``weldcell calibrate``, ...).

    A ``name`` with a space, ``"map relocalize"``, adds a sub-command to a group that several plugins
    share (``weldcell map relocalize``); the CLI makes the group from its members. ``batch`` declares
    the command (or sub-commands of a group) that ``weldcell batch`` may run over many inputs.
    """

    name: str
    command: Any
    summary: str = ""
    batch: tuple[BatchSpec, ...] = ()
    category: ClassVar[str] = "command"
    kind: ClassVar[str] = "command"
