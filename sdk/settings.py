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
