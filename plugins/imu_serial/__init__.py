"""USB-serial IMU (HandsFree HFI-A9, WitMotion protocol) as device ``imu.serial``. Registration only."""

from __future__ import annotations

from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import MissingExtraError
from weldcell.sdk.hookspecs import hookimpl

NAME = "imu.serial"


def _factory(settings, ctx):
    try:
        from weldcell.plugins.imu_serial.adapter import SerialImu
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "serial", "serial") from None
    return SerialImu(settings, name=ctx.role)


def probe(settings) -> str:
    """Open the port, wait for one valid frame, report the measured frame rate."""
    import time

    dev = _factory(settings, type("Ctx", (), {"role": "probe"})())
    try:
        dev.configure()
        dev.activate()
        t0 = time.monotonic()
        n = 0
        while time.monotonic() - t0 < 0.5:
            n += len(dev._read_burst(0.1))
        rate = n / (time.monotonic() - t0)
    finally:
        dev.close()
    return f"{settings.protocol} IMU at {settings.port}: {rate:.0f} readings/s"


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.imu_serial.settings import ImuSerialSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="imu",
            summary="USB-serial IMU: HandsFree HFI-A9 or WitMotion 0x55 protocol (buffered stream)",
            settings=ImuSerialSettings,
            factory=_factory,
            probe=probe,
            requires={"serial": "serial"},
        )
    )
