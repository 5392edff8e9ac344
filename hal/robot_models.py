"""Published kinematic parameters of the robot arms weldcell models (data only, SI units).

Every table says where its numbers come from. Numbers a vendor does not publish (joint accelerations
of UR, AUBO and ABB arms; ABB's TCP speed) are marked ``ASSUMED`` with the rule used to pick them; the
maths that turns these tables into :class:`weldcell.hal.kinematics.RobotModel` objects lives in
``kinematics.py``.

DH conventions
--------------
* ``standard`` (Denavit-Hartenberg 1955, as in UR's tables):
  ``A_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``; joint *i* turns about z of frame *i-1*.
* ``modified`` (Craig 1986, as in Franka's, AUBO's and the ABB table below):
  ``A_i = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i)``; joint *i* turns about z of frame *i*.
  Row *i* of a modified table stores ``(a_{i-1}, alpha_{i-1}, d_i, offset_i)``.

``theta_i = q_i + offset_i`` where ``q`` is the joint value the robot's controller reports.
``flange`` is the fixed transform from the last DH frame to the tool flange (ISO 9409-1 frame).
"""

from __future__ import annotations

import math
from typing import Any

_PI = math.pi
_H = math.pi / 2
_DEG = math.pi / 180.0


def _deg(*values: float) -> list[float]:
    return [v * _DEG for v in values]


def _ramp(speeds_deg: list[float], seconds: float) -> list[float]:
    """ASSUMED accelerations: reach the joint's top speed in ``seconds`` (vendor does not publish them)."""
    return [v * _DEG / seconds for v in speeds_deg]


# Universal Robots, "DH parameters for calculations of kinematics and dynamics"
# (universal-robots.com/articles/ur/application-installation/
#  dh-parameters-for-calculations-of-kinematics-and-dynamics/).
# UR5 (CB3) technical specifications: reach 850 mm, payload 5 kg, all joints +-360 deg at 180 deg/s,
# tool typical speed 1 m/s.
UR5: dict[str, Any] = {
    "name": "ur5",
    "aliases": (),
    "convention": "standard",
    # a, alpha, d, offset
    "dh": [
        (0.0, _H, 0.089159, 0.0),
        (-0.425, 0.0, 0.0, 0.0),
        (-0.39225, 0.0, 0.0, 0.0),
        (0.0, _H, 0.10915, 0.0),
        (0.0, -_H, 0.09465, 0.0),
        (0.0, 0.0, 0.0823, 0.0),
    ],
    "flange": None,
    "joint_limits_deg": [(-360.0, 360.0)] * 6,
    "joint_speed_deg": [180.0] * 6,
    "joint_accel": _ramp([180.0] * 6, 0.25),
    "max_tcp_speed": 1.0,
    "max_tcp_rot_speed": _PI,  # ASSUMED: 180 deg/s, the wrist joints' top speed
    "reach": 0.850,
    "payload": 5.0,
    # flange 0.34 m in front (base +x), 0.41 m up, tool pointing straight down.
    "home_deg": [180.0, -110.0, 110.0, -90.0, -90.0, 0.0],
    "sources": "UR DH-parameter article (UR5 table); UR5 CB3 technical specifications",
}

# UR10e: same UR DH article (UR10e table). UR10e technical specifications: reach 1300 mm, payload 10 kg
# (12.5 kg with the 2023 payload upgrade), joints +-360 deg; base and shoulder 120 deg/s, elbow and wrists
# 180 deg/s; TCP typical speed 1 m/s.
UR10E: dict[str, Any] = {
    "name": "ur10e",
    "aliases": ("ur10-e",),
    "convention": "standard",
    "dh": [
        (0.0, _H, 0.1807, 0.0),
        (-0.6127, 0.0, 0.0, 0.0),
        (-0.57155, 0.0, 0.0, 0.0),
        (0.0, _H, 0.17415, 0.0),
        (0.0, -_H, 0.11985, 0.0),
        (0.0, 0.0, 0.11655, 0.0),
    ],
    "flange": None,
    "joint_limits_deg": [(-360.0, 360.0)] * 6,
    "joint_speed_deg": [120.0, 120.0, 180.0, 180.0, 180.0, 180.0],
    "joint_accel": _ramp([120.0, 120.0, 180.0, 180.0, 180.0, 180.0], 0.25),
    "max_tcp_speed": 1.0,
    "max_tcp_rot_speed": _PI,  # ASSUMED
    "reach": 1.300,
    "payload": 10.0,
    "home_deg": [180.0, -110.0, 110.0, -90.0, -90.0, 0.0],
    "sources": "UR DH-parameter article (UR10e table); UR10e technical specifications",
}

# Franka Emika Panda: Franka Control Interface documentation, "Robot and interface specifications"
# (frankaemika.github.io/docs/control_parameters.html): modified (Craig) DH table, flange d = 0.107 m,
# joint position / velocity / acceleration limits, Cartesian limits 1.7 m/s, 2.5 rad/s, 13 m/s^2, 25 rad/s^2.
# Datasheet: reach 855 mm, payload 3 kg.
PANDA: dict[str, Any] = {
    "name": "franka-panda",
    "aliases": ("franka", "panda"),
    "convention": "modified",
    # a_{i-1}, alpha_{i-1}, d_i, offset_i
    "dh": [
        (0.0, 0.0, 0.333, 0.0),
        (0.0, -_H, 0.0, 0.0),
        (0.0, _H, 0.316, 0.0),
        (0.0825, _H, 0.0, 0.0),
        (-0.0825, -_H, 0.384, 0.0),
        (0.0, _H, 0.0, 0.0),
        (0.088, _H, 0.0, 0.0),
    ],
    # flange: a=0, alpha=0, d=0.107, theta=0 after joint 7
    "flange": [(0.0, 0.0, 0.107, 0.0)],
    "joint_limits_rad": [
        (-2.8973, 2.8973),
        (-1.7628, 1.7628),
        (-2.8973, 2.8973),
        (-3.0718, -0.0698),
        (-2.8973, 2.8973),
        (-0.0175, 3.7525),
        (-2.8973, 2.8973),
    ],
    "joint_speed_rad": [2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100],
    "joint_accel": [15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0],
    "max_tcp_speed": 1.7,
    "max_tcp_rot_speed": 2.5,
    "reach": 0.855,
    "payload": 3.0,
    # libfranka's "ready" pose: flange 0.31 m in front, 0.49 m up, pointing down.
    "home_rad": [0.0, -_PI / 4, 0.0, -3 * _PI / 4, 0.0, _H, _PI / 4],
    "sources": "Franka Control Interface docs, robot and interface specifications; Panda datasheet",
}

# AUBO i5: modified DH table of AUBO's kinematics library / aubo_robot ROS package (aubo_i5 description):
# d1 = 0.122 (base plate to shoulder), d2 = 0.1215, a2 = 0.408, a3 = 0.376, d5 = 0.1025, d6 = 0.094,
# alpha = (0, -90, 180, 180, -90, 90) deg, zero offsets (180, -90, 0, -90, 0, 0) deg.
# AUBO i5 datasheet: reach 886.5 mm, payload 5 kg, all joints +-175 deg at 150 deg/s, TCP speed 2.8 m/s.
AUBO_I5: dict[str, Any] = {
    "name": "aubo-i5",
    "aliases": ("aubo",),
    "convention": "modified",
    "dh": [
        (0.0, 0.0, 0.122, _PI),
        (0.0, -_H, 0.1215, -_H),
        (0.408, _PI, 0.0, 0.0),
        (0.376, _PI, 0.0, -_H),
        (0.0, -_H, 0.1025, 0.0),
        (0.0, _H, 0.094, 0.0),
    ],
    "flange": None,
    "joint_limits_deg": [(-175.0, 175.0)] * 6,
    "joint_speed_deg": [150.0] * 6,
    "joint_accel": _ramp([150.0] * 6, 0.25),
    "max_tcp_speed": 2.8,
    "max_tcp_rot_speed": _PI,  # ASSUMED
    "reach": 0.8865,
    "payload": 5.0,
    "home_deg": [0.0, 20.0, 110.0, 0.0, 90.0, 0.0],
    "sources": "AUBO kinematics library / aubo_robot aubo_i5 description (DH); AUBO i5 datasheet",
}

# ABB IRB 2600-12/1.65: product specification IRB 2600 (3HAC035960-001), dimension drawings:
# axis 2 at 150 mm forward / 445 mm up, lower arm 700 mm, axis 3 -> wrist offset 115 mm up,
# 795 mm to the wrist centre, wrist centre -> flange 85 mm. Working range (deg): ax1 +-180, ax2 -95..+155,
# ax3 -180..+75, ax4 +-400, ax5 +-120, ax6 +-400. Max axis speed (deg/s) 175, 175, 175, 360, 360, 510.
# Reach 1.65 m, payload 12 kg.  Written as a modified DH table with ABB's joint signs and zero position
# (upper arm vertical, lower arm horizontal, tool0 z pointing forward along base x).
ABB_IRB2600: dict[str, Any] = {
    "name": "abb-irb2600",
    "aliases": ("irb2600", "abb-irb2600-12-1.65"),
    "convention": "modified",
    "dh": [
        (0.0, 0.0, 0.445, 0.0),
        (0.150, -_H, 0.0, -_H),
        (0.700, 0.0, 0.0, 0.0),
        (0.115, -_H, 0.795, 0.0),
        (0.0, _H, 0.0, 0.0),
        (0.0, -_H, 0.0, _PI),
    ],
    # tool0: 85 mm along the axis-6 line (frame 6 z), same orientation as frame 6.
    "flange": [(0.0, 0.0, 0.085, 0.0)],
    "joint_limits_deg": [
        (-180.0, 180.0),
        (-95.0, 155.0),
        (-180.0, 75.0),
        (-400.0, 400.0),
        (-120.0, 120.0),
        (-400.0, 400.0),
    ],
    "joint_speed_deg": [175.0, 175.0, 175.0, 360.0, 360.0, 510.0],
    "joint_accel": _ramp([175.0, 175.0, 175.0, 360.0, 360.0, 510.0], 0.25),
    "max_tcp_speed": 7.0,  # ASSUMED: RAPID's largest predefined speeddata (v7000); not in the spec
    "max_tcp_rot_speed": 2 * _PI,  # ASSUMED
    "reach": 1.65,
    "payload": 12.0,
    "home_deg": [0.0, 10.0, 30.0, 0.0, 50.0, 0.0],
    "sources": "ABB product specification IRB 2600 (3HAC035960-001), variant 12/1.65",
}

ROBOT_TABLES: tuple[dict[str, Any], ...] = (UR5, UR10E, PANDA, AUBO_I5, ABB_IRB2600)
