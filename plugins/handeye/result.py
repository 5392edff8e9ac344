"""Moved to :mod:`weldcell.sdk.handeye_files` (other plugins and tools read these records); kept so
existing imports (benchmarks, user scripts, docs/methods/hand-eye.md) keep working."""

from weldcell.sdk.handeye_files import (
    CONFIGS,
    CONVENTION,
    MAX_TRANSLATION,
    NULL_REASONS,
    SCHEMA,
    HandEyeResult,
    HandEyeSample,
    config_name,
    finite_json,
    sample_id,
)

__all__ = [
    "CONFIGS",
    "CONVENTION",
    "MAX_TRANSLATION",
    "NULL_REASONS",
    "SCHEMA",
    "HandEyeResult",
    "HandEyeSample",
    "config_name",
    "finite_json",
    "sample_id",
]
