"""Settings of the serial IMU adapter (no vendor import here)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration


class ImuSerialSettings(Settings):
    """A USB-serial IMU that streams frames on its own: HandsFree HFI-A9 or a WitMotion-protocol IMU."""

    port: str = Field("/dev/ttyUSB0", description="serial port (or pyserial URL)")
    protocol: Literal["hfi-a9", "witmotion"] = Field("hfi-a9", description="frame protocol of the IMU")
    baudrate: int = Field(921600, description="HFI-A9: 921600; WitMotion: usually 9600 or 115200")
    rate_hz: float = Field(
        200.0, gt=0, description="nominal output rate, used to stamp bursts until the rate is measured"
    )
    mag_scale: float = Field(
        1.0, description="factor from the IMU's magnetometer units to uT (the A9's units are not published)"
    )
    open_timeout: Duration = Field(1.0, gt=0, description="wait for the first good frame on configure [s]")
    silence_timeout: Duration = Field(0.5, gt=0, description="no byte for this long while active is a fault")
