"""Moved to :mod:`weldcell.hal.robot_models`; kept for existing imports."""

from weldcell.hal.robot_models import ABB_IRB2600, AUBO_I5, PANDA, ROBOT_TABLES, UR5, UR10E

__all__ = ["ABB_IRB2600", "AUBO_I5", "PANDA", "ROBOT_TABLES", "UR5", "UR10E"]
