"""The UR Real-Time Data Exchange (RTDE) wire format, protocol version 2 (no vendor library).

Every package is ``uint16 size | uint8 type | payload`` (big-endian, ``size`` counts the 3-byte
header). The client asks for protocol version 2 (``V``), the controller version (``v``), sets up an
output recipe (``O``: ``double frequency`` + comma-separated variable names; the reply is the recipe
id + comma-separated types, ``NOT_FOUND`` for unknown names), starts (``S``), and then receives
``DATA_PACKAGE`` (``U``: recipe id + the values in recipe order). ``P`` pauses, ``M`` is a text
message. Source: UR's "Real-Time Data Exchange (RTDE) Guide" and its reference client ``rtde.py``.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Sequence

HEADER = struct.Struct(">HB")

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
CONTROL_PACKAGE_START = ord("S")
CONTROL_PACKAGE_PAUSE = ord("P")

PROTOCOL_VERSION = 2
PORT = 30004

TYPE_FORMATS: dict[str, str] = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}
"""RTDE type name -> struct format of one value."""

_V6 = "VECTOR6D"
OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": _V6,
    "target_qd": _V6,
    "target_qdd": _V6,
    "target_current": _V6,
    "target_moment": _V6,
    "actual_q": _V6,
    "actual_qd": _V6,
    "actual_current": _V6,
    "actual_current_window": _V6,
    "joint_control_output": _V6,
    "actual_TCP_pose": _V6,
    "actual_TCP_speed": _V6,
    "actual_TCP_force": _V6,
    "target_TCP_pose": _V6,
    "target_TCP_speed": _V6,
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": _V6,
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": _V6,
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": _V6,
    "script_control_line": "UINT32",
    "ft_raw_wrench": _V6,
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
    "actual_robot_energy_consumed": "DOUBLE",
    "actual_robot_braking_energy_dissipated": "DOUBLE",
}
"""Output variables of the controller and their types (the RTDE guide's output table)."""

_REGISTER = re.compile(r"^(output|input)_(bit|int|double)_register_(\d+)$")
_REGISTER_TYPES = {"bit": "BOOL", "int": "INT32", "double": "DOUBLE"}

ROBOT_MODES = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
    8: "UPDATING_FIRMWARE",
}
SAFETY_MODES = {
    1: "NORMAL",
    2: "REDUCED",
    3: "PROTECTIVE_STOP",
    4: "RECOVERY",
    5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP",
    7: "ROBOT_EMERGENCY_STOP",
    8: "VIOLATION",
    9: "FAULT",
    10: "VALIDATE_JOINT_ID",
    11: "UNDEFINED_SAFETY_MODE",
    12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
STOPPED_SAFETY_MODES = frozenset({3, 5, 6, 7, 8, 9, 12, 13})
"""Safety modes in which the arm does not move (stops, emergency stops, violation, fault)."""
SAFETY_BIT_PROTECTIVE_STOPPED = 2
"""Bit of ``safety_status_bits`` set while protective-stopped."""


class ProtocolError(Exception):
    """A package that does not follow the RTDE protocol."""


def variable_type(name: str) -> str:
    """The RTDE type of a variable, ``NOT_FOUND`` when the controller has no such variable."""
    if name in OUTPUT_TYPES:
        return OUTPUT_TYPES[name]
    m = _REGISTER.match(name)
    if m and int(m.group(3)) < 48:
        return _REGISTER_TYPES[m.group(2)]
    return "NOT_FOUND"


def pack(command: int, payload: bytes = b"") -> bytes:
    """One package: header + payload."""
    return HEADER.pack(HEADER.size + len(payload), command) + payload


def recipe_struct(types: Sequence[str]) -> struct.Struct:
    """The struct of a data package's values for a recipe of ``types`` (after the recipe id)."""
    try:
        return struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in types))
    except KeyError as e:
        raise ProtocolError(f"unknown RTDE type {e.args[0]!r} in a recipe") from None


def pack_values(types: Sequence[str], values: Sequence[object]) -> bytes:
    """Flatten ``values`` (scalars and vectors) in recipe order."""
    flat: list[object] = []
    for t, v in zip(types, values, strict=True):
        if TYPE_FORMATS[t][0].isdigit():
            flat.extend(v)  # type: ignore[arg-type]
        else:
            flat.append(v)
    return recipe_struct(types).pack(*flat)


def unpack_values(types: Sequence[str], data: bytes) -> list[object]:
    """Inverse of :func:`pack_values`: vectors come back as tuples."""
    flat = recipe_struct(types).unpack(data)
    out: list[object] = []
    i = 0
    for t in types:
        fmt = TYPE_FORMATS[t]
        n = int(fmt[:-1]) if fmt[0].isdigit() else 0
        if n:
            out.append(tuple(flat[i : i + n]))
            i += n
        else:
            out.append(flat[i])
            i += 1
    return out
