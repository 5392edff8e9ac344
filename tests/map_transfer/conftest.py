"""Fixtures of the map-transfer tests: a synthetic map and map servers that are always stopped."""

from __future__ import annotations

import pytest
from map_transfer_data import corridor


@pytest.fixture
def small_map():
    return corridor()


@pytest.fixture
def serve():
    """``serve(root, **kw)`` starts a MapServer on a free loopback port; all are stopped afterwards."""
    from weldcell.plugins.map_transfer.server import MapServer

    started = []

    def start(root, **kw):
        kw.setdefault("bind", "tcp://127.0.0.1:*")
        srv = MapServer(root, **kw).start()
        started.append(srv)
        return srv

    yield start
    for srv in started:
        assert srv.stop(), "a map server thread did not stop"
