"""Franka Emika Panda / FR3 (``robot.franka``) through franky-control."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec, import_adapter
from weldcell.sdk.hookspecs import hookimpl


def _adapter():
    return import_adapter(f"{__name__}.adapter", {"franky": "franka"}, "device 'robot.franka'")


def _factory(settings, ctx):
    return _adapter().make_franka(settings, ctx)


def _probe(settings) -> str:
    return _adapter().probe_franka(settings)


@hookimpl
def weldcell_register_devices(register):
    from .settings import FrankaSettings

    register(
        DeviceSpec(
            name="robot.franka",
            kind="robot",
            summary="Franka Emika Panda / FR3 through franky (FCI)",
            settings=FrankaSettings,
            factory=_factory,
            requires={"franky": "franka"},
            probe=_probe,
        )
    )
