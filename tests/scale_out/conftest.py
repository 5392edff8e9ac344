"""A real ``distributed.LocalCluster``: two single-threaded worker processes on loopback TCP, shared by
the scale-out tests (started once: worker processes take seconds to start and import weldcell)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from weldcell.sdk.plugins import PluginManager, get_plugin_manager, set_plugin_manager

from .probe_plugin import MODULE

TESTS_DIR = str(Path(__file__).resolve().parents[1])


@pytest.fixture(scope="session")
def cluster():
    """The cluster; its workers import the probe plugin by name (tests/ is on their PYTHONPATH)."""
    dask = pytest.importorskip("dask")
    distributed = pytest.importorskip("distributed")
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = TESTS_DIR + (os.pathsep + old if old else "")
    try:
        with dask.config.set({"distributed.scheduler.allowed-failures": 3}):
            cl = distributed.LocalCluster(
                n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None
            )
        assert cl.scheduler_address.startswith("tcp://127.0.0.1:")
        yield cl
        cl.close()
    finally:
        if old is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = old


@pytest.fixture
def plugins():
    """A fresh process-wide plugin manager with the probe plugin (restored afterwards)."""
    import importlib

    pm = PluginManager(discover=True)
    pm.register(importlib.import_module(MODULE), name=MODULE)
    previous = set_plugin_manager(pm)
    try:
        yield pm
    finally:
        set_plugin_manager(previous)


def options(cluster, **kw):
    """ClusterOptions for the shared cluster (through its scheduler address, as a remote one)."""
    from weldcell.sdk.scale.cluster import ClusterOptions

    if cluster is None:
        return ClusterOptions(workers=0, plugin_modules=(MODULE,), **kw)
    return ClusterOptions(scheduler=cluster.scheduler_address, plugin_modules=(MODULE,), **kw)


def get_pm():
    return get_plugin_manager()
