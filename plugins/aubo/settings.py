"""Settings of the AUBO adapter (no vendor import here)."""

from __future__ import annotations

from pydantic import Field
from weldcell.hal.robot import RobotMotionSettings
from weldcell.sdk.units import Duration


class AuboSettings(RobotMotionSettings):
    """``robot.aubo``: an AUBO i-series arm (ARCS controller) through pyaubo-sdk's JSON-RPC client."""

    host: str = Field("192.168.1.10", description="controller address")
    port: int = Field(30004, gt=0, lt=65536, description="ARCS RPC port (JSON-RPC over TCP)")
    user: str = Field("aubo", description="RPC login user")
    password_env: str = Field(
        "AUBO_PASSWORD",
        description="name of the environment variable holding the RPC "
        "password (unset: the controller's factory default)",
    )
    robot_name: str = Field("", description="robot name on the controller (e.g. 'rob1'); empty: the first")
    model: str = Field("aubo-i5", description="kinematic model for the safety gate (weldcell.hal.kinematics)")
    request_timeout: Duration = Field(2.0, gt=0, description="timeout of one RPC request [s]")
    motion_timeout: Duration = Field(120.0, gt=0, description="longest wait for one motion to finish [s]")
    poll_period: Duration = Field(0.01, gt=0, description="period of the motion-progress polling [s]")
