"""u-blox GNSS receivers (M8T and others) through pyubx2 as device ``gnss.ublox``. Registration only."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import MissingExtraError
from weldcell.sdk.hookspecs import hookimpl

NAME = "gnss.ublox"


def _factory(settings, ctx):
    try:
        from weldcell.plugins.ublox.adapter import UbloxGnss
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "pyubx2", "ublox") from None
    return UbloxGnss(settings, name=ctx.role)


def probe(settings) -> str:
    """Open the port and read messages for up to ``open_timeout`` (nothing is sent to the receiver)."""
    dev = _factory(
        settings.model_copy(update={"configure_receiver": False}), type("C", (), {"role": "probe"})()
    )
    try:
        dev.configure()
        dev.activate()
        fix = dev.read(timeout=settings.open_timeout)
    finally:
        dev.close()
    sv = "?" if fix.num_sv is None else fix.num_sv
    acc = "?" if fix.h_acc is None else f"{fix.h_acc:.2f}"
    return f"u-blox receiver at {settings.port}: fix {fix.fix_type}, {sv} satellites, hAcc {acc} m"


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.ublox.settings import UbloxSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="gnss",
            summary="u-blox GNSS receiver (M8T, ...): UBX NAV-PVT with NMEA fallback, UBX-CFG",
            settings=UbloxSettings,
            factory=_factory,
            probe=probe,
            requires={"pyubx2": "ublox", "serial": "serial"},
        )
    )
