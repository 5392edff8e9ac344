"""Moved to :mod:`weldcell.hal.kinematics` (real robots' safety gates use it); kept for existing imports."""

from weldcell.hal.kinematics import (
    MODELS,
    DHTable,
    RobotModel,
    build_model,
    get_model,
    trapezoid_position,
    trapezoid_time,
)

__all__ = [
    "MODELS",
    "DHTable",
    "RobotModel",
    "build_model",
    "get_model",
    "trapezoid_position",
    "trapezoid_time",
]
