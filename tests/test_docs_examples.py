"""The docs' runnable parts: the example plugin's own tests pass; the profile reference and the CLI help
shown in the docs are current."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "docs" / "examples" / "weldcell-plugin-example"


def _env(**extra: str) -> dict[str, str]:
    drop = ("WELDCELL_DISABLE_PLUGINS", "WELDCELL_STRICT_PLUGINS")
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env.update(extra)
    return env


def test_example_plugin_tests_pass():
    """The third-party example runs its own tests with weldcell's pytest fixtures (not pip-installed)."""
    path = os.pathsep.join(p for p in (str(EXAMPLE), os.environ.get("PYTHONPATH", "")) if p)
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", str(EXAMPLE / "tests"), "-q", "-p", "no:cacheprovider"],
        cwd=ROOT,
        env=_env(PYTHONPATH=path),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, f"example plugin tests failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-2000:]}"
    assert " passed" in proc.stdout and "failed" not in proc.stdout


@pytest.mark.parametrize(
    "generator",
    ["gen_profile_reference.py", "gen_cli_help.py"],
    ids=["profile-reference", "cli-help"],
)
def test_generated_docs_are_up_to_date(generator):
    """docs/profile-reference.md matches the settings models in the code, and every `weldcell ... --help`
    shown in docs/cli.md is what the command prints."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "docs" / generator), "--check"],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, f"stale; run `python docs/{generator}`\n" + proc.stderr[-3000:]
