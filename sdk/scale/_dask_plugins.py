"""Dask worker plugins (imported only when Dask is used)."""

from __future__ import annotations

from collections.abc import Sequence

from distributed.diagnostics.plugin import WorkerPlugin


class PluginModules(WorkerPlugin):
    """Registers plugin modules in each worker's plugin manager at start, and again in a worker that
    replaced one that died (the scheduler keeps the plugin for workers that join later)."""

    name = "weldcell-plugin-modules"

    def __init__(self, modules: Sequence[str]) -> None:
        self.modules = tuple(modules)

    def setup(self, worker) -> None:  # noqa: D401 - dask's hook
        from weldcell.sdk.scale.cluster import register_plugin_modules

        register_plugin_modules(self.modules)
