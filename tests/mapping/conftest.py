"""Shared pieces of the cell-4 mapping tests: the simulated site and a rendered frame pair."""

from __future__ import annotations

import pytest
from weldcell.hal.sim.site import RouteSettings, install_site
from weldcell.hal.sim.world import SimWorld


@pytest.fixture(scope="module")
def site():
    w = SimWorld([])
    s = install_site(w, seed=0)
    s.set_route(RouteSettings(length=30.0))
    return s


@pytest.fixture
def map_pm(sim_pm):
    """The simulated cell's plugin manager with the mapping and ONNX detector plugins."""
    import weldcell.plugins.mapping as mapping_plugin
    import weldcell.plugins.onnx_detector as onnx_plugin

    sim_pm.register(mapping_plugin, "mapping", distribution="weldcell")
    sim_pm.register(onnx_plugin, "onnx_detector", distribution="weldcell")
    return sim_pm
