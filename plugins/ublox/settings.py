"""Settings of the u-blox adapter (no vendor import here)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration


class UbloxSettings(Settings):
    """A u-blox receiver (M8T and other M8/gen9 receivers) on a serial or USB port, read with pyubx2."""

    port: str = Field("/dev/ttyACM0", description="serial port (USB: /dev/ttyACM0; UART: /dev/ttyUSB0)")
    baudrate: int = Field(9600, description="UART baud rate (the M8T's default is 9600; USB ignores it)")
    rate_hz: float = Field(1.0, gt=0, le=25, description="navigation rate set by CFG-RATE [Hz]")
    configure_receiver: bool = Field(True, description="send CFG-RATE and enable NAV-PVT on configure")
    config_messages: Literal["cfg-msg", "valset"] = Field(
        "cfg-msg", description="cfg-msg: CFG-RATE/CFG-MSG (M8, protocol < 27); valset: CFG-VALSET (gen9+)"
    )
    origin: tuple[float, float, float] | None = Field(
        None, description="latitude, longitude [deg], ellipsoidal height [m] of the local ENU origin"
    )
    ack_timeout: Duration = Field(1.5, gt=0, description="wait for ACK of a configuration message [s]")
    open_timeout: Duration = Field(3.0, gt=0, description="wait for the first message on configure [s]")
    silence_timeout: Duration = Field(3.0, gt=0, description="no byte for this long while active is a fault")
