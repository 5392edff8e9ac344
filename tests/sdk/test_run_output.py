"""What a run leaves behind and prints: file modes from the user's umask, output to a file or a pipe
without colour codes or mid-phrase wrapping, step labels that name the plugin that ran, and the
``--debug`` hint only where a traceback helps."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from weldcell.sdk import artifacts


@pytest.fixture
def umask():
    old = os.umask(0o022)

    def set_(mask: int) -> None:
        os.umask(mask)

    yield set_
    os.umask(old)


def _mode(p) -> int:
    return stat.S_IMODE(os.stat(p).st_mode)


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_artifacts_are_created_with_the_users_umask(tmp_path, umask, mask):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    umask(mask)
    fig, ax = plt.subplots()
    ax.plot([0, 1])
    files = [
        artifacts.write_text(tmp_path / "a.txt", "x"),
        artifacts.write_json(tmp_path / "b.json", {"a": np.arange(3)}),
        artifacts.write_bytes(tmp_path / "c.bin", b"\0"),
        artifacts.save_figure(fig, tmp_path / "d.png"),
    ]
    plt.close(fig)
    reference = tmp_path / "plain.txt"
    reference.write_text("what open() makes")
    for f in files:
        assert _mode(f) == 0o666 & ~mask == _mode(reference), f
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.json", "c.bin", "d.png", "plain.txt"]


def test_rewriting_a_file_keeps_its_mode(tmp_path, umask):
    umask(0o022)
    f = artifacts.write_text(tmp_path / "summary.txt", "one")
    os.chmod(f, 0o640)
    artifacts.write_text(f, "two")
    assert f.read_text() == "two" and _mode(f) == 0o640


def test_umask_is_read_without_changing_it(umask):
    umask(0o027)
    assert artifacts.current_umask() == 0o027
    assert os.umask(0o027) == 0o027  # still the same afterwards


def _run_cli(tmp_path, *args: str) -> subprocess.CompletedProcess:
    """``weldcell`` in a child process with stdout and stderr to pipes (not a terminal)."""
    env = {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "COLUMNS", "TTY_COMPATIBLE")}
    env["TERM"] = "xterm-256color"  # a colour terminal type: colours must still be left out of a pipe
    return subprocess.run(
        [sys.executable, "-m", "weldcell.sdk.cli", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=120,
    )


def test_errors_to_a_pipe_have_no_colour_codes_no_wrapping_and_no_needless_debug_hint(tmp_path):
    long_dir = tmp_path / ("a-folder-with-a-rather-long-name-" * 3)
    long_dir.mkdir()
    missing = long_dir / "cell-profile-that-does-not-exist.toml"
    r = _run_cli(tmp_path, "run", str(missing))
    assert r.returncode == 3
    assert "\x1b[" not in r.stderr + r.stdout
    lines = r.stderr.splitlines()
    err = [ln for ln in lines if ln.startswith("error:")]
    assert len(err) == 1 and err[0].endswith(f"{missing}")  # the whole message on one line
    assert any(ln.strip().startswith("fix: check the path") for ln in lines)
    # a missing file is explained by its message: a traceback would not help
    assert "--debug" not in r.stderr


def test_the_debug_hint_shows_where_a_traceback_helps():
    from weldcell.sdk.cli import _traceback_helps
    from weldcell.sdk.errors import DataError, DeviceError, JobError

    assert not _traceback_helps(DataError("bad file", "fix it"))
    try:
        try:
            raise ConnectionResetError("peer reset")
        except ConnectionResetError as e:
            raise DeviceError("robot: read failed", "check the cable") from e
    except DeviceError as err:
        assert _traceback_helps(err)  # a library failed underneath: its traceback tells where
    try:
        raise DataError("x", "y") from None
    except DataError as err:
        assert not _traceback_helps(err)
    wrapped = JobError("job failed: KeyError", "rerun with --debug for the traceback")
    wrapped.__cause__ = KeyError("k")
    assert not _traceback_helps(wrapped)  # the fix already says it


def test_run_output_to_a_pipe_is_one_line_per_message(tmp_path, fixtures_dir):
    """A whole `weldcell run` through a pipe: no colour, no blank lines from progress bars, long
    lines whole, and step labels that name the stage plugin that ran."""
    code = textwrap.dedent(
        f"""
        import sys
        sys.path.insert(0, {str(fixtures_dir)!r})
        import fixture_plugins
        from weldcell.sdk import cli
        from weldcell.sdk.plugins import PluginManager, set_plugin_manager
        from weldcell.plugins import sim
        pm = PluginManager(discover=False)
        pm.register(sim, "sim", distribution="weldcell")
        pm.register(fixture_plugins, "fixture", distribution="weldcell-tests")
        set_plugin_manager(pm)
        cli.main(["run", {str(fixtures_dir / "fixture-job-sim.toml")!r}, "--runs-dir", {str(tmp_path)!r}])
        """
    )
    env = {k: v for k, v in os.environ.items() if k not in ("FORCE_COLOR", "COLUMNS")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "\x1b[" not in r.stderr + r.stdout
    steps = [ln.strip() for ln in r.stderr.splitlines() if ln.strip().startswith("✓")]
    assert any(s.startswith("✓ scale (scale.multiply)") for s in steps), steps
    assert "" not in r.stderr.splitlines()[1:], r.stderr  # no blank lines left by progress bars
    assert "run folder: " in r.stdout


def test_step_label_names_the_plugin_that_ran():
    from weldcell.sdk.jobs import step_label

    assert step_label("denoise (bilateral filter)", ["denoise.my-filter"]) == "denoise (denoise.my-filter)"
    assert step_label("denoise (bilateral filter)", []) == "denoise (bilateral filter)"
    assert step_label("solve (handeye.svd, scaled)", ["handeye.svd"]) == "solve (handeye.svd, scaled)"
    assert step_label("metrics", ["a.b", "c.d"]) == "metrics (a.b, c.d)"
