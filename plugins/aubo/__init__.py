"""AUBO i-series arms (``robot.aubo``) through pyaubo-sdk (ARCS JSON-RPC on port 30004)."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec, import_adapter
from weldcell.sdk.hookspecs import hookimpl


def _adapter():
    return import_adapter(f"{__name__}.adapter", {"pyaubo_sdk": "aubo"}, "device 'robot.aubo'")


def _factory(settings, ctx):
    return _adapter().make_aubo(settings, ctx)


def _probe(settings) -> str:
    return _adapter().probe_aubo(settings)


@hookimpl
def weldcell_register_devices(register):
    from .settings import AuboSettings

    register(
        DeviceSpec(
            name="robot.aubo",
            kind="robot",
            summary="AUBO i-series (ARCS) through pyaubo-sdk RPC",
            settings=AuboSettings,
            factory=_factory,
            requires={"pyaubo_sdk": "aubo"},
            probe=_probe,
        )
    )
