"""Cell-wide settings that every job shares: the safety limits and the run options."""

from __future__ import annotations

import math

from pydantic import Field, model_validator
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Acceleration, AngularAcceleration, AngularSpeed, Length, Speed


class SafetyLimits(Settings):
    """What every motion command is checked against before it reaches a robot (see docs/safety.md)."""

    workspace_min: tuple[Length, Length, Length] = Field(
        (-1.0, -1.0, -0.05), description="lower corner of the allowed TCP box in the robot base frame [m]"
    )
    workspace_max: tuple[Length, Length, Length] = Field(
        (1.0, 1.0, 1.2), description="upper corner of the allowed TCP box in the robot base frame [m]"
    )
    max_linear_speed: Speed = Field(0.25, gt=0, description="TCP speed cap [m/s]")
    max_linear_accel: Acceleration = Field(1.2, gt=0, description="TCP acceleration cap [m/s^2]")
    max_angular_speed: AngularSpeed = Field(1.0, gt=0, description="TCP rotation speed cap [rad/s]")
    max_joint_speed: AngularSpeed = Field(1.5, gt=0, description="joint speed cap [rad/s]")
    max_joint_accel: AngularAcceleration = Field(4.0, gt=0, description="joint acceleration cap [rad/s^2]")
    max_reach: Length | None = Field(
        None,
        gt=0,
        description="TCP distance from the base axis above which a target is refused [m]; "
        "default: the robot model's reach",
    )
    path_check_step: Length = Field(
        0.005, ge=1e-4, le=0.1, description="largest spacing of the checks along a linear path [m]"
    )

    @model_validator(mode="after")
    def _box_ordered(self) -> SafetyLimits:
        for name in type(self).model_fields:
            value = getattr(self, name)
            values = value if isinstance(value, tuple) else (value,)
            if any(v is not None and not math.isfinite(v) for v in values):
                raise ValueError(
                    f"{name} must be finite, got {value!r}: a NaN or infinite limit would disable the check; "
                    "give a finite value with its unit"
                )
        for axis, lo, hi in zip("xyz", self.workspace_min, self.workspace_max, strict=True):
            if lo >= hi:
                raise ValueError(f"workspace_min.{axis} ({lo}) must be below workspace_max.{axis} ({hi})")
        return self


class CellSettings(Settings):
    """The ``[cell]`` table of a profile."""

    safety: SafetyLimits = Field(default_factory=SafetyLimits, description="motion limits of this cell")
    dry_run: bool = Field(False, description="log the motion commands that would be sent instead of moving")
    seed: int = Field(0, description="random seed for everything simulated in a run")
