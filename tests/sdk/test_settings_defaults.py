"""``with_defaults``: the user's settings win; cell values fill only the fields a settings class has."""

from __future__ import annotations

from pydantic import Field
from weldcell.sdk.settings import Settings, with_defaults
from weldcell.sdk.units import Length


class Program(Settings):
    robot_model: str | None = Field(None, description="robot model")
    retract: Length = Field(0.05, description="retract [m]")


def test_cell_values_fill_only_what_the_user_left_unset():
    cell = {"robot_model": "ur5", "retract": 0.2, "not_a_field": 1}
    assert with_defaults(Program, None, cell).robot_model == "ur5"
    assert with_defaults(Program, None, cell).retract == 0.2
    given = Program(robot_model="abb-irb2600")
    got = with_defaults(Program, given, cell)
    assert got.robot_model == "abb-irb2600" and got.retract == 0.2


def test_none_cell_values_leave_the_default():
    assert with_defaults(Program, None, {"robot_model": None}).robot_model is None
