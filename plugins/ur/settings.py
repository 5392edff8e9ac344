"""Settings of the UR adapter (no vendor import here: profiles validate without ur-rtde)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.hal.robot import RobotMotionSettings
from weldcell.sdk.units import Duration, Frequency

URModel = Literal["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30"]


class URSettings(RobotMotionSettings):
    """A Universal Robots arm (CB3 >= 3.3 or e-Series) driven through ur-rtde."""

    host: str = Field("192.168.1.10", description="IP address or host name of the robot controller")
    model: URModel = Field(
        "ur5",
        description="robot model; the safety gate uses its kinematics where weldcell "
        "has them (ur5, ur10e) for reach and joint limits",
    )
    frequency: Frequency | None = Field(
        None,
        gt=0,
        le=500,
        description="RTDE frequency [Hz]; default: the controller's (125 Hz CB3, 500 Hz e-Series)",
    )
    dashboard_port: int = Field(
        29999, ge=1, le=65535, description="Dashboard server port (protective-stop unlock)"
    )
    use_external_control_urcap: bool = Field(
        False,
        description="run the control script through the "
        "External Control URCap instead of uploading it (ur_rtde flag)",
    )
    ur_cap_port: int = Field(50002, ge=1, le=65535, description="port of the External Control URCap")
    connect_timeout: Duration = Field(2.0, gt=0, description="TCP connect / dashboard timeout [s]")
    state_timeout: Duration = Field(0.5, gt=0, description="RTDE data older than this is a fault [s]")
