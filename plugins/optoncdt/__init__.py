"""Micro-Epsilon optoNCDT 1402 laser displacement sensor over RS422 (device ``displacement.optoncdt``).

Registration only: the adapter (and pyserial) load when the device is built.
"""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import MissingExtraError
from weldcell.sdk.hookspecs import hookimpl

NAME = "displacement.optoncdt"


def _factory(settings, ctx):
    try:
        if settings.family == "1420":
            from weldcell.plugins.optoncdt.adapter_1420 import OptoNcdt1420 as cls
        else:
            from weldcell.plugins.optoncdt.adapter import OptoNcdt as cls
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "serial", "serial") from None
    return cls(settings, name=ctx.role)


def probe(settings) -> str:
    """Open the port, ask GET_INFO (GETINFO), close again (laser and output are left as they were)."""
    if settings.family == "1420":
        dev = _factory(settings, type("C", (), {"role": "probe"})())
        try:
            dev.configure()
        finally:
            dev.close()
        info = dev.info
        return (
            f"optoNCDT {info.get('Name', '?')} S/N {info.get('Serial', '?')}, "
            f"MR {info.get('Measuring range', '?')} at {settings.port}"
        )
    try:
        from weldcell.plugins.optoncdt.adapter import OptoNcdt
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "serial", "serial") from None
    dev = OptoNcdt(settings.model_copy(update={"apply_settings": False}), name="probe")
    try:
        dev.port.open()
        from weldcell.plugins.optoncdt.adapter import parse_info
        from weldcell.plugins.optoncdt.protocol import GET_INFO

        info = parse_info(dev._send(GET_INFO).data)
    finally:
        dev.port.close()
    return (
        f"optoNCDT {info.get('ILD 1402', '').strip() or '1402'} S/N {info.get('S/N', '?')}, "
        f"MR {info.get('MR', '?')} mm, {info.get('Scanrate', '?')} at {settings.port}"
    )


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.optoncdt.settings import OptoNcdtSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="displacement_sensor",
            summary="Micro-Epsilon optoNCDT 1402 laser displacement sensor (RS422, binary output)",
            settings=OptoNcdtSettings,
            factory=_factory,
            probe=probe,
            requires={"serial": "serial"},
        )
    )
