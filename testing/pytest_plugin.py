"""weldcell's pytest plugin (entry point ``pytest11``), for plugin authors and weldcell itself.

Fixtures:

* ``weldcell_pm``: a :class:`~weldcell.sdk.plugins.PluginManager` with discovery off, installed as
  the process-wide manager for the test (the CLI and jobs use it); register plugins by hand.
* ``register_plugin``: ``with register_plugin(module_or_object, name): ...`` registers a plugin
  for the block and unregisters it after.
* ``sim_pm``: a plugin manager with only weldcell's simulated cell loaded (no other discovery).
* ``run_dir``: an empty folder for run artifacts.

Device conformance suites live in :mod:`weldcell.testing.conformance`.
"""

from __future__ import annotations

import contextlib

import pytest
from weldcell.sdk.plugins import PluginManager, set_plugin_manager


@pytest.fixture
def weldcell_pm():
    """An empty plugin manager (no entry-point discovery), used by the CLI during the test."""
    pm = PluginManager(discover=False)
    previous = set_plugin_manager(pm)
    try:
        yield pm
    finally:
        set_plugin_manager(previous)


@pytest.fixture
def register_plugin(weldcell_pm):
    """Context manager registering a plugin on ``weldcell_pm`` for one block."""

    @contextlib.contextmanager
    def _register(plugin, name: str | None = None):
        with weldcell_pm.plugin(plugin, name) as registered:
            yield registered

    return _register


@pytest.fixture
def sim_pm(weldcell_pm):
    """A plugin manager holding only the simulated cell's plugins."""
    import weldcell.plugins.sim as sim_plugin

    weldcell_pm.register(sim_plugin, "sim", distribution="weldcell")
    return weldcell_pm


@pytest.fixture
def run_dir(tmp_path):
    """An empty folder for a run's artifacts."""
    d = tmp_path / "runs"
    d.mkdir()
    return d
