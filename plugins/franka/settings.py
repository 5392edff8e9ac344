"""Settings of the Franka adapter (no vendor import here)."""

from __future__ import annotations

from pydantic import Field
from weldcell.hal.robot import RobotMotionSettings
from weldcell.sdk.units import Acceleration, AngularAcceleration, AngularSpeed, Duration, Speed


class FrankaSettings(RobotMotionSettings):
    """``robot.franka``: a Franka Emika Panda / FR3 through franky (libfranka, FCI)."""

    host: str = Field("172.16.0.2", description="FCI address of the robot's control unit")
    model: str = Field(
        "franka-panda", description="kinematic model for the safety gate (weldcell.hal.kinematics)"
    )
    relative_dynamics_factor: float = Field(
        1.0, gt=0, le=1, description="global franky dynamics factor (multiplies every motion's)"
    )
    max_translation_speed: Speed = Field(
        1.7,
        gt=0,
        description="Franka's Cartesian speed limit [m/s] "
        "(Panda 1.7, FR3 3.0); a TCP speed is commanded as a fraction of it",
    )
    max_translation_accel: Acceleration = Field(
        13.0, gt=0, description="Franka's Cartesian acceleration limit"
    )
    max_joint_speed: AngularSpeed = Field(2.175, gt=0, description="smallest joint speed limit [rad/s]")
    max_joint_accel: AngularAcceleration = Field(15.0, gt=0, description="smallest joint acceleration limit")
    torque_threshold: float = Field(20.0, gt=0, description="collision reflex torque threshold [Nm]")
    force_threshold: float = Field(30.0, gt=0, description="collision reflex force threshold [N]")
    motion_timeout: Duration = Field(120.0, gt=0, description="longest wait for one motion to finish [s]")
