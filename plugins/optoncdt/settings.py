"""Settings of the Micro-Epsilon optoNCDT 1402 adapter (no vendor import here)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Duration, Length


class OptoNcdtSettings(Settings):
    """An optoNCDT 1402 on RS422 through a USB converter (ILD1402 data protocol, binary output).

    ``measuring_range`` and ``start_of_range`` come from the sensor's data sheet (ILD1402-<MR>); the
    adapter checks ``measuring_range`` against the "MR" the sensor reports.
    """

    family: Literal["1402", "1420"] = Field(
        "1402",
        description="1402: ILD1402 protocol; 1420: the 1420/1320 protocol (3-byte values, ASCII commands)",
    )
    port: str = Field("/dev/ttyUSB0", description="serial port of the RS422-USB converter (or pyserial URL)")
    baudrate: int = Field(115200, description="ILD1402 protocol: 115200; 1420/1320: 921600 (the defaults)")
    measuring_range: Length = Field(0.05, gt=0, description="MR of the model, e.g. 50 mm for ILD1402-50")
    start_of_range: Length = Field(0.045, ge=0, description="SMR: sensor face to the start of the range")
    rate_hz: float = Field(
        1500,
        gt=0,
        description="measuring rate [Hz]: 1402 1500|1000|750|375|50 (set on configure); 1420/1320: the rate "
        "set in the sensor (250..4000), used to time-stamp bursts",
    )
    averaging: Literal["moving", "median"] = Field("moving", description="the sensor's filter")
    averaging_number: int = Field(1, ge=1, le=128, description="moving: 1..128; median: 3, 5, 7 or 9")
    laser: bool = Field(True, description="switch the laser on (False: off) when configured")
    apply_settings: bool = Field(True, description="send rate/averaging/output settings on configure")
    reply_timeout: Duration = Field(1.0, gt=0, description="wait for a command reply [s]")
    reboot_timeout: Duration = Field(
        5.0, gt=0, description="wait for the sensor to reboot after a rate change"
    )
    silence_timeout: Duration = Field(0.5, gt=0, description="no byte for this long while active is a fault")

    @model_validator(mode="before")
    @classmethod
    def _family_defaults(cls, data):
        if isinstance(data, dict) and data.get("family") == "1420":
            data = {"baudrate": 921600, "rate_hz": 1000, **data}
        return data

    @model_validator(mode="after")
    def _median_sizes(self):
        if self.family == "1402" and self.rate_hz not in (1500, 1000, 750, 375, 50):
            raise ValueError("the ILD1402 measures at 1500, 1000, 750, 375 or 50 Hz")
        if self.averaging == "median" and self.averaging_number not in (3, 5, 7, 9):
            raise ValueError("median averaging_number must be 3, 5, 7 or 9")
        return self
