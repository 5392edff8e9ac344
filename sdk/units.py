"""Unit-aware settings fields.

A profile may write a length as a number in metres (``0.015``) or as a string with its unit
(``"15 mm"``); an angle as radians or ``"30 deg"``; and so on. Inside weldcell every value is SI.
A string in the wrong dimension (``"15 kg"`` for a length) is refused with the accepted units.

Use the annotated types in settings models::

    class TorchSettings(Settings):
        standoff: Length = Field(0.015, description="torch tip to work distance")
        work_angle: Angle = Field(0.785, description="about the travel axis")
"""

from __future__ import annotations

import math
import re
from typing import Annotated

from pydantic import BeforeValidator, WithJsonSchema

UNITS: dict[str, dict[str, float]] = {
    "length": {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "in": 0.0254},
    "angle": {"rad": 1.0, "deg": math.pi / 180.0, "°": math.pi / 180.0},
    "time": {"s": 1.0, "ms": 1e-3, "min": 60.0},
    "speed": {"m/s": 1.0, "mm/s": 1e-3, "m/min": 1 / 60.0, "mm/min": 1e-3 / 60.0},
    "angular_speed": {"rad/s": 1.0, "deg/s": math.pi / 180.0},
    "acceleration": {"m/s^2": 1.0, "mm/s^2": 1e-3, "m/s2": 1.0, "mm/s2": 1e-3},
    "angular_acceleration": {
        "rad/s^2": 1.0,
        "deg/s^2": math.pi / 180.0,
        "rad/s2": 1.0,
        "deg/s2": math.pi / 180.0,
    },
    "frequency": {"Hz": 1.0, "kHz": 1e3},
}
SI = {
    "length": "m",
    "angle": "rad",
    "time": "s",
    "speed": "m/s",
    "angular_speed": "rad/s",
    "acceleration": "m/s^2",
    "angular_acceleration": "rad/s^2",
    "frequency": "Hz",
}
_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([^\d\s].*?)?\s*$")


def parse_quantity(value: object, dimension: str) -> float:
    """Convert ``value`` (a number in SI or a string like ``"15 mm"``) to a float in SI units."""
    if isinstance(value, bool):
        raise ValueError(f"expected a {dimension} ({SI[dimension]}), got a boolean")
    if isinstance(value, int | float):
        return _finite(float(value), value, dimension)
    if isinstance(value, str):
        m = _QUANTITY.match(value)
        if not m:
            raise ValueError(f"cannot read {value!r} as a {dimension}; write e.g. '1.5 {SI[dimension]}'")
        number, unit = float(m.group(1)), (m.group(2) or SI[dimension]).strip()
        table = UNITS[dimension]
        if unit not in table:
            raise ValueError(
                f"{value!r}: '{unit}' is not a unit of {dimension}; use one of {', '.join(table)}"
            )
        return _finite(number * table[unit], value, dimension)
    raise ValueError(f"expected a {dimension} as a number ({SI[dimension]}) or a string with units")


def _finite(v: float, given: object, dimension: str) -> float:
    """A quantity must be finite: NaN or infinity (or ``1e400 m``) would disable the check it feeds."""
    if not math.isfinite(v):
        raise ValueError(f"{given!r} is not a finite {dimension}; give a number in {SI[dimension]}")
    return v


def _quantity(dimension: str):
    return Annotated[
        float,
        BeforeValidator(lambda v: parse_quantity(v, dimension)),
        WithJsonSchema({"type": ["number", "string"], "unit": SI[dimension], "dimension": dimension}),
    ]


Length = _quantity("length")
Angle = _quantity("angle")
Duration = _quantity("time")
Speed = _quantity("speed")
AngularSpeed = _quantity("angular_speed")
Acceleration = _quantity("acceleration")
AngularAcceleration = _quantity("angular_acceleration")
Frequency = _quantity("frequency")


def unit_of(annotation_metadata: list) -> str | None:
    """The SI unit of a field made with one of the types above (for docs), else None."""
    for item in annotation_metadata:
        if isinstance(item, WithJsonSchema) and isinstance(item.json_schema, dict):
            return item.json_schema.get("unit")
    return None
