"""Unit-aware settings: numbers are SI, strings carry their unit, the wrong dimension is refused."""

from __future__ import annotations

import math

import pytest
from pydantic import Field, ValidationError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import (
    SI,
    UNITS,
    Acceleration,
    Angle,
    AngularSpeed,
    Duration,
    Frequency,
    Length,
    Speed,
    parse_quantity,
    unit_of,
)


@pytest.mark.parametrize(
    ("text", "dimension", "si"),
    [
        ("15 mm", "length", 0.015),
        ("15mm", "length", 0.015),
        ("  2.5 cm ", "length", 0.025),
        ("1 in", "length", 0.0254),
        ("-3 um", "length", -3e-6),
        ("1e3 mm", "length", 1.0),
        (".5 m", "length", 0.5),
        ("0.2", "length", 0.2),  # a bare number in a string is SI
        ("30 deg", "angle", math.pi / 6),
        ("90 °", "angle", math.pi / 2),
        ("1.5 rad", "angle", 1.5),
        ("250 ms", "time", 0.25),
        ("2 min", "time", 120.0),
        ("250 mm/s", "speed", 0.25),
        ("6 m/min", "speed", 0.1),
        ("600 mm/min", "speed", 0.01),
        ("180 deg/s", "angular_speed", math.pi),
        ("500 mm/s^2", "acceleration", 0.5),
        ("2 m/s2", "acceleration", 2.0),
        ("90 deg/s^2", "angular_acceleration", math.pi / 2),
        ("2 kHz", "frequency", 2000.0),
    ],
)
def test_strings_with_units_become_si(text, dimension, si):
    assert parse_quantity(text, dimension) == pytest.approx(si)


def test_numbers_are_taken_as_si():
    assert parse_quantity(0.015, "length") == 0.015
    assert parse_quantity(3, "angle") == 3.0


def test_wrong_dimension_names_the_accepted_units():
    with pytest.raises(ValueError) as e:
        parse_quantity("15 kg", "length")
    assert str(e.value) == "'15 kg': 'kg' is not a unit of length; use one of m, cm, mm, um, in"
    with pytest.raises(ValueError, match="'mm' is not a unit of angle; use one of rad, deg"):
        parse_quantity("3 mm", "angle")
    with pytest.raises(ValueError, match="'m' is not a unit of speed"):
        parse_quantity("3 m", "speed")


@pytest.mark.parametrize("bad", ["fast", "mm 15", "", "1.2.3 mm"])
def test_unreadable_strings_show_an_example(bad):
    with pytest.raises(ValueError) as e:
        parse_quantity(bad, "length")
    assert "m" in str(e.value)


def test_booleans_and_other_types_are_refused():
    with pytest.raises(ValueError, match="got a boolean"):
        parse_quantity(True, "length")
    with pytest.raises(ValueError, match="as a number"):
        parse_quantity([1, 2], "length")


def test_every_dimension_has_its_si_unit_at_scale_one():
    for dim, unit in SI.items():
        assert UNITS[dim][unit] == 1.0


class Torch(Settings):
    standoff: Length = Field(0.015, gt=0, description="torch tip to work distance")
    work_angle: Angle = Field(0.785, description="about the travel axis")
    travel: Speed = Field(0.005, description="welding speed")
    dwell: Duration = Field(0.0, description="pause at the start")
    spin: AngularSpeed = Field(0.0, description="wrist rotation speed")
    accel: Acceleration = Field(1.0, description="ramp")
    rate: Frequency = Field(100.0, description="servo rate")
    xyz: tuple[Length, Length, Length] = Field((0.0, 0.0, 0.0), description="offset")


def test_settings_fields_accept_unit_strings():
    t = Torch(
        standoff="12 mm",
        work_angle="45 deg",
        travel="300 mm/min",
        dwell="200 ms",
        spin="10 deg/s",
        accel="500 mm/s^2",
        rate="1 kHz",
        xyz=["1 cm", 0.02, "30 mm"],
    )
    assert t.standoff == pytest.approx(0.012)
    assert t.work_angle == pytest.approx(math.pi / 4)
    assert t.travel == pytest.approx(0.005)
    assert t.dwell == pytest.approx(0.2)
    assert t.spin == pytest.approx(math.radians(10))
    assert t.accel == pytest.approx(0.5)
    assert t.rate == 1000.0
    assert t.xyz == pytest.approx((0.01, 0.02, 0.03))


def test_settings_refuse_wrong_units_unknown_keys_and_limits():
    with pytest.raises(ValidationError) as e:
        Torch(standoff="15 kg")
    assert "'kg' is not a unit of length" in str(e.value)
    with pytest.raises(ValidationError, match="greater than 0"):
        Torch(standoff="-1 mm")
    with pytest.raises(ValidationError, match="Extra inputs are not permitted"):
        Torch(standof=0.01)
    t = Torch()
    with pytest.raises(ValidationError):  # validated on assignment too
        t.standoff = "3 deg"
    t.standoff = "20 mm"
    assert t.standoff == pytest.approx(0.02)


def test_json_schema_and_unit_of_document_the_unit():
    schema = Torch.model_json_schema()
    assert schema["properties"]["standoff"]["unit"] == "m"
    assert schema["properties"]["work_angle"]["unit"] == "rad"
    assert schema["properties"]["standoff"]["description"] == "torch tip to work distance"
    assert unit_of(Torch.model_fields["travel"].metadata) == "m/s"
    assert unit_of(Torch.model_fields["rate"].metadata) == "Hz"
    assert unit_of([]) is None


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf"), "1e400 m", "nan mm", "inf m"])
def test_non_finite_quantities_are_refused(value):
    with pytest.raises(ValueError, match="not a finite length|cannot read"):
        parse_quantity(value, "length")
