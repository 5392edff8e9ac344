"""Settings of the ABB adapter (no vendor import here: profiles validate without abb-robot-client)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, SecretStr
from weldcell.hal.robot import RobotMotionSettings
from weldcell.sdk.units import Duration


class ABBSettings(RobotMotionSettings):
    """An ABB IRC5 (RobotWare 6) arm through Robot Web Services 1.0 and EGM (abb-robot-client).

    Motions run in the RAPID server module ``WeldcellServer`` (plugins/abb/rapid/WeldcellServer.mod),
    which must be loaded in the motion task; see docs/devices/abb.md.
    """

    url: str = Field(
        "http://192.168.125.1:80",
        description="RWS base URL of the controller (the WAN or service port; RobotStudio: "
        "http://127.0.0.1:80)",
    )
    username: str = Field("Default User", description="RWS user (HTTP Digest authentication)")
    password: SecretStr | None = Field(
        None,
        description='RWS password; never write it into a profile: use password = "${env:ABB_RWS_PASSWORD}"',
    )
    model: Literal["abb-irb2600"] = Field(
        "abb-irb2600", description="robot model; the safety gate uses its kinematics and limits"
    )
    task: str = Field("T_ROB1", description="RAPID motion task that runs WeldcellServer")
    module: str = Field("WeldcellServer", description="name of the RAPID server module")
    mechunit: str = Field("ROB_1", description="mechanical unit of the arm")
    start_program: bool = Field(
        True,
        description="start RAPID execution (from main) on configure/recover when it is stopped; "
        "the controller must be in AUTO with motors on",
    )
    install_module: bool = Field(
        False,
        description="upload and load WeldcellServer.mod through RWS on configure when the task has none or "
        "another version (AUTO mode; stops RAPID)",
    )
    motors_on: bool = Field(
        False,
        description="switch the motors on through RWS when they are off (AUTO only; the controller "
        "refuses it after an emergency stop until the stop is reset)",
    )
    use_egm: bool = Field(
        True,
        description="read the robot state from the EGM stream (250 Hz) and servo through EGM; "
        "False: poll the state through RWS and refuse speed_linear",
    )
    egm_host: str = Field(
        "0.0.0.0", description="local address the EGM UDP socket binds (the controller's UC device target)"
    )
    egm_port: int = Field(6510, ge=0, le=65535, description="local UDP port of EGM (0: any free port)")
    egm_timeout: Duration = Field(
        1.0, gt=0, description="wait this long for the first EGM message on configure [s]"
    )
    state_timeout: Duration = Field(0.3, gt=0, description="EGM feedback older than this is a fault [s]")
    motion_timeout_margin: Duration = Field(
        5.0,
        gt=0,
        description="extra time allowed over the planned motion time before a move is "
        "declared failed (and the robot stopped) [s]",
    )
    poll_period: Duration = Field(0.01, gt=0, description="period of RWS polling while a motion runs [s]")
    path_chunk: int = Field(
        100, ge=2, le=100, description="targets per RAPID path buffer (wc_path{100} in the module)"
    )
    version: Literal["rws1"] = Field(
        "rws1",
        description="RWS version: 'rws1' (IRC5, RobotWare 6, HTTP Digest). OmniCore/RobotWare 7 "
        "(RWS 2.0, HTTPS + Basic) is not supported by abb-robot-client 0.4",
    )
