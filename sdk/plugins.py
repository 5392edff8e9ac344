"""The plugin manager: discovery through entry points, fault isolation, the registry of names.

* Every plugin, first-party or not, comes from the ``weldcell`` entry-point group.
* Discovery is fault-isolated per entry point: a plugin that fails to import, or whose hook raises,
  is recorded as a :class:`PluginFailure` and the others still load. ``strict=True`` (or the
  environment variable ``WELDCELL_STRICT_PLUGINS=1``) turns any failure into an error, for CI.
* Two plugins that register the same name are a conflict: the name cannot be selected, and the
  error names both providers. Nothing depends on the order plugins load in.
* ``WELDCELL_DISABLE_PLUGINS=a,b`` skips the entry points named ``a`` and ``b``.
"""

from __future__ import annotations

import contextlib
import difflib
import importlib.metadata as md
import os
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pluggy
from weldcell.sdk import hookspecs
from weldcell.sdk.descriptors import CommandSpec, Descriptor, DeviceSpec, ExporterSpec, JobSpec, StageSpec
from weldcell.sdk.errors import PluginError, UnknownPluginError

ENTRY_POINT_GROUP = "weldcell"
CATEGORIES = {
    "stage": ("weldcell_register_stages", StageSpec),
    "device": ("weldcell_register_devices", DeviceSpec),
    "job": ("weldcell_register_jobs", JobSpec),
    "exporter": ("weldcell_register_exporters", ExporterSpec),
    "command": ("weldcell_register_commands", CommandSpec),
}


@dataclass(frozen=True)
class Provider:
    """Where a plugin came from: its plugin name, and its distribution and version when installed."""

    plugin: str
    distribution: str | None = None
    version: str | None = None
    entry_point: str | None = None

    def __str__(self) -> str:
        dist = f" ({self.distribution} {self.version})" if self.distribution else ""
        return f"plugin '{self.plugin}'{dist}"


@dataclass(frozen=True)
class PluginFailure:
    """A plugin that could not be loaded or whose registration hook raised."""

    provider: Provider
    stage: str
    error: str
    traceback: str = ""

    def __str__(self) -> str:
        where = f" [{self.provider.entry_point}]" if self.provider.entry_point else ""
        return f"{self.provider}{where} failed to {self.stage}: {self.error}"


@dataclass(frozen=True)
class Registered:
    """A registered descriptor and the plugin that provided it."""

    descriptor: Any
    provider: Provider


@dataclass(frozen=True)
class Conflict:
    """Two or more plugins registered the same name."""

    category: str
    name: str
    providers: tuple[Provider, ...]

    def __str__(self) -> str:
        who = " and ".join(str(p) for p in self.providers)
        return f"{self.category} '{self.name}' is registered by {who}"


@dataclass
class Registry:
    """Everything the loaded plugins registered, by category and name."""

    entries: dict[str, dict[str, Registered]] = field(default_factory=lambda: {c: {} for c in CATEGORIES})
    conflicts: dict[tuple[str, str], Conflict] = field(default_factory=dict)
    failures: list[PluginFailure] = field(default_factory=list)

    def names(self, category: str, kind: str | None = None) -> list[str]:
        """Sorted names in ``category`` (only those of ``kind`` when given)."""
        items = self.entries[category].items()
        return sorted(n for n, r in items if kind is None or getattr(r.descriptor, "kind", None) == kind)

    def all(self, category: str) -> list[Registered]:
        """Every registered entry of a category, sorted by name."""
        return [self.entries[category][n] for n in sorted(self.entries[category])]

    def entry(self, category: str, name: str, kind: str | None = None) -> Registered:
        """The entry for ``name``; raises a clear error for unknown, conflicting or wrong-kind names."""
        if (category, name) in self.conflicts:
            raise PluginError(
                str(self.conflicts[(category, name)]),
                "uninstall one of them, or disable one with WELDCELL_DISABLE_PLUGINS=<plugin>",
            )
        found = self.entries[category].get(name)
        if found is None:
            raise UnknownPluginError(self._unknown_message(category, name, kind), self._unknown_fix(name))
        if kind is not None and found.descriptor.kind != kind:
            raise PluginError(
                f"{category} '{name}' is a {found.descriptor.kind}, not a {kind}",
                f"choose one of the {kind} {category}s: {', '.join(self.names(category, kind)) or '(none)'}",
            )
        return found

    def get(self, category: str, name: str, kind: str | None = None) -> Any:
        """The descriptor for ``name`` (see :meth:`entry`)."""
        return self.entry(category, name, kind).descriptor

    def _unknown_message(self, category: str, name: str, kind: str | None) -> str:
        avail = self.names(category, kind)
        close = difflib.get_close_matches(name, avail, n=3, cutoff=0.6)
        msg = f"no {category} named '{name}'"
        if close:
            msg += f" (did you mean {', '.join(repr(c) for c in close)}?)"
        what = f"{kind} {category}s" if kind else f"{category}s"
        msg += f"; available {what}: {', '.join(avail) if avail else '(none)'}"
        return msg

    def _unknown_fix(self, name: str) -> str:
        prefix = name.split(".")[0]
        broken = [
            f
            for f in self.failures
            if prefix in f.provider.plugin or prefix in (f.provider.distribution or "")
        ]
        if broken:
            return "this plugin failed to load and may provide it: " + "; ".join(str(f) for f in broken)
        if self.failures:
            names = ", ".join(f.provider.plugin for f in self.failures)
            return (
                f"plugins that failed to load may provide it ({names}); see `weldcell plugins`. "
                "Otherwise install the package that provides it "
                "(it registers through the 'weldcell' entry points)"
            )
        return (
            "install the package that provides it (its plugin registers through the 'weldcell' entry-point "
            "group); `weldcell plugins` lists what is installed"
        )


class PluginManager:
    """Loads plugins and collects what they register into a :class:`Registry`.

    ``discover=False`` starts empty (for tests: register plugins by hand with :meth:`register`
    or the :meth:`plugin` context manager).
    """

    def __init__(self, discover: bool = True, strict: bool | None = None) -> None:
        self._pm = pluggy.PluginManager(hookspecs.PROJECT)
        self._pm.add_hookspecs(hookspecs)
        self.strict = strict if strict is not None else os.environ.get("WELDCELL_STRICT_PLUGINS") == "1"
        self.providers: dict[str, Provider] = {}
        self.load_failures: list[PluginFailure] = []
        self._registry: Registry | None = None
        if discover:
            self.load_entrypoints()

    # -- discovery -------------------------------------------------------------------------------
    def load_entrypoints(self, group: str = ENTRY_POINT_GROUP) -> None:
        """Load every entry point of ``group``, recording failures instead of stopping."""
        disabled = {n.strip() for n in os.environ.get("WELDCELL_DISABLE_PLUGINS", "").split(",") if n.strip()}
        seen: set[str] = set()
        for ep in sorted(md.entry_points(group=group), key=lambda e: e.name):
            dist = getattr(ep, "dist", None)
            provider = Provider(
                plugin=ep.name,
                distribution=dist.metadata["Name"] if dist else None,
                version=dist.version if dist else None,
                entry_point=f"{ep.name} = {ep.value}",
            )
            if ep.name in disabled or ep.name in seen:
                continue
            seen.add(ep.name)
            if self._pm.get_plugin(ep.name) is not None:
                continue
            try:
                plugin = ep.load()
                self._pm.register(plugin, name=ep.name)
            except Exception as e:  # noqa: BLE001 - isolation is the point
                self.load_failures.append(
                    PluginFailure(provider, "load", f"{type(e).__name__}: {e}", traceback.format_exc())
                )
                continue
            self.providers[ep.name] = provider
        self._registry = None
        if self.strict and self.load_failures:
            raise PluginError(
                "plugins failed to load: " + "; ".join(str(f) for f in self.load_failures),
                "fix or uninstall the broken plugins (strict mode is on: WELDCELL_STRICT_PLUGINS=1)",
            )

    def register(self, plugin: Any, name: str | None = None, distribution: str | None = None) -> str:
        """Register a plugin object or module by hand; returns its name."""
        name = name or getattr(plugin, "__name__", None) or type(plugin).__name__
        self._pm.register(plugin, name=name)
        self.providers[name] = Provider(plugin=name, distribution=distribution)
        self._registry = None
        return name

    def unregister(self, name: str) -> None:
        """Remove a plugin registered under ``name``."""
        self._pm.unregister(name=name)
        self.providers.pop(name, None)
        self._registry = None

    @contextlib.contextmanager
    def plugin(self, plugin: Any, name: str | None = None) -> Iterator[str]:
        """Register ``plugin`` for the duration of a ``with`` block (handy in tests)."""
        registered = self.register(plugin, name)
        try:
            yield registered
        finally:
            self.unregister(registered)

    def plugin_names(self) -> list[str]:
        """Names of the plugins currently registered."""
        return sorted(n for n, _ in self._pm.list_name_plugin())

    def check_profile(self, loaded: Any) -> list[tuple[tuple[str, ...], str]]:
        """Problems that plugins find in a profile (``weldcell_check_profile``), fault-isolated."""
        problems: list[tuple[tuple[str, ...], str]] = []
        for impl in self._pm.hook.weldcell_check_profile.get_hookimpls():
            try:
                problems.extend(impl.function(profile=loaded) or [])
            except Exception as e:  # noqa: BLE001
                problems.append(
                    ((), f"plugin '{impl.plugin_name}' failed to check the profile: {type(e).__name__}: {e}")
                )
        return problems

    # -- collection ------------------------------------------------------------------------------
    @property
    def registry(self) -> Registry:
        """What the plugins registered (collected on first use, again after register/unregister)."""
        if self._registry is None:
            self._registry = self._collect()
        return self._registry

    def _collect(self) -> Registry:
        reg = Registry(failures=list(self.load_failures))
        owners: dict[tuple[str, str], list[Registered]] = {}
        for category, (hook_name, desc_type) in CATEGORIES.items():
            hook = getattr(self._pm.hook, hook_name)
            for impl in hook.get_hookimpls():
                provider = self.providers.get(impl.plugin_name, Provider(plugin=impl.plugin_name))
                got: list[Any] = []

                def register(item: Any, _got: list = got, _t: type = desc_type, _c: str = category) -> None:
                    if not isinstance(item, _t):
                        raise PluginError(
                            f"register() of {_c}s got a {type(item).__name__}, expected {_t.__name__}",
                            None,
                        )
                    _got.append(item)

                try:
                    impl.function(register=register)
                except Exception as e:  # noqa: BLE001 - one broken plugin must not stop the others
                    reg.failures.append(
                        PluginFailure(
                            provider,
                            f"register {category}s",
                            f"{type(e).__name__}: {e}",
                            traceback.format_exc(),
                        )
                    )
                    continue
                for item in got:
                    owners.setdefault((category, item.name), []).append(Registered(item, provider))
        for (category, name), regs in owners.items():
            providers = tuple(dict.fromkeys(r.provider for r in regs))
            if len(regs) > 1:
                reg.conflicts[(category, name)] = Conflict(category, name, providers)
            else:
                reg.entries[category][name] = regs[0]
        if self.strict and (reg.failures or reg.conflicts):
            problems = [str(f) for f in reg.failures] + [str(c) for c in reg.conflicts.values()]
            raise PluginError("plugin problems: " + "; ".join(problems), "fix them (strict mode is on)")
        return reg


_default: PluginManager | None = None


def get_plugin_manager() -> PluginManager:
    """The process-wide plugin manager, created with discovery on first use."""
    global _default
    if _default is None:
        _default = PluginManager(discover=True)
    return _default


def set_plugin_manager(pm: PluginManager | None) -> PluginManager | None:
    """Replace the process-wide manager (tests); returns the previous one."""
    global _default
    previous, _default = _default, pm
    return previous


def describe(descriptor: Descriptor | CommandSpec) -> str:
    """One line: the summary of a descriptor."""
    return getattr(descriptor, "summary", "") or ""
