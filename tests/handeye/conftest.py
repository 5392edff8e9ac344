from pathlib import Path

import pytest
import weldcell.plugins.handeye as handeye_plugin

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


@pytest.fixture
def he_pm(sim_pm):
    """The simulated cell's plugin manager with the handeye plugin registered."""
    sim_pm.register(handeye_plugin, "handeye", distribution="weldcell")
    return sim_pm


@pytest.fixture
def extend_profile(tmp_path):
    """``extend_profile(base, name, text)``: a profile in tmp_path that extends ``base`` with ``text``."""

    def write(base: Path, name: str, text: str) -> Path:
        p = tmp_path / name
        p.write_text(f'extends = "{base}"\n{text}')
        return p

    return write


@pytest.fixture
def cli(weldcell_pm):
    """``weldcell calibrate hand-eye ARGS...`` through the real command line: (exit code, output with
    whitespace runs collapsed, since rich wraps lines at the terminal width)."""
    from click.testing import CliRunner
    from weldcell.sdk.cli import main

    weldcell_pm.register(handeye_plugin, "handeye", distribution="weldcell")
    runner = CliRunner()

    def invoke(*args):
        r = runner.invoke(main, ["calibrate", "hand-eye", *map(str, args)], catch_exceptions=False)
        return r.exit_code, " ".join(r.output.split())

    return invoke
