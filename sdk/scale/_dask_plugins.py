"""Dask worker plugins (imported only when Dask is used)."""

from __future__ import annotations

from collections.abc import Sequence

from distributed.diagnostics.plugin import WorkerPlugin


class PluginModules(WorkerPlugin):
    """Puts folders on each worker's ``sys.path`` and registers plugin modules in its plugin manager at
    start, and again in a worker that replaced one that died (the scheduler keeps the plugin for workers
    that join later)."""

    name = "weldcell-plugin-modules"

    def __init__(self, modules: Sequence[str], python_path: Sequence[str] = ()) -> None:
        self.modules = tuple(modules)
        self.python_path = tuple(python_path)

    def setup(self, worker) -> None:  # noqa: D401 - dask's hook
        from weldcell.sdk.scale.cluster import add_python_path, register_plugin_modules

        add_python_path(self.python_path)
        register_plugin_modules(self.modules)
