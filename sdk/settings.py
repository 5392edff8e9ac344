"""Base class of every settings model (stages, devices, jobs, exporters, the cell)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Settings(BaseModel):
    """Settings of a plugin: unknown keys are refused, values are validated on assignment.

    Give every field a default, a ``description`` and, for physical quantities, one of the
    unit-aware types of :mod:`weldcell.sdk.units` so profiles may write ``"15 mm"``.
    """

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False)


class NoSettings(Settings):
    """For plugins that take no settings."""


def with_defaults(cls: type[Settings], given: Settings | None, defaults: dict) -> Settings:
    """``cls`` settings where the fields the user set (in ``given``) win, and the other fields of ``cls``
    named in ``defaults`` take those values (e.g. an exporter's robot model and tool from the cell).

    Keys of ``defaults`` that ``cls`` does not have are ignored, so one set of cell values serves every
    exporter or stage.
    """
    user = given.model_dump(exclude_unset=True) if given is not None else {}
    fill = {k: v for k, v in defaults.items() if k in cls.model_fields and k not in user and v is not None}
    return cls.model_validate({**fill, **user})
