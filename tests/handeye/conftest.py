from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
FLANGE = DATA / "flange-handeye-ancorasir"
ARUCO = DATA / "opencv-aruco-charuco-images"


@pytest.fixture
def flange_data() -> Path:
    if not FLANGE.is_dir():
        pytest.skip(f"shared data not found at {FLANGE} (the ancorasir flange hand-eye set)")
    return FLANGE


@pytest.fixture
def aruco_data() -> Path:
    if not ARUCO.is_dir():
        pytest.skip(f"shared data not found at {ARUCO} (OpenCV ArUco/ChArUco photos)")
    return ARUCO
