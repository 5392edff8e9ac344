"""AUBO i-series arms (``robot.aubo``) through pyaubo-sdk (ARCS JSON-RPC on port 30004)."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.hookspecs import hookimpl


def _adapter():
    try:
        from . import adapter
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] == "pyaubo_sdk":
            from weldcell.sdk.errors import MissingExtraError

            raise MissingExtraError("device 'robot.aubo'", "pyaubo_sdk", "aubo") from e
        raise
    return adapter


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
