"""Test-wide settings: no windows for plots, and the shared recorded data located once."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the repository; tests that need it skip with the reason when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(
            f"recorded data not found at {SHARED_DATA} (clone the repo beside shared/ to run this test)"
        )
    return SHARED_DATA
