"""Fixtures of the SDK tests: the fixture plugin, fake installed distributions, a wide terminal."""

from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path

import pytest

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
REPO = Path(__file__).resolve().parents[2]


def _load_module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # pydantic resolves the postponed annotations through sys.modules
    spec.loader.exec_module(module)
    return module


fixture_plugins = _load_module("weldcell_tests_fixture_plugins", FIXTURES / "fixture_plugins.py")


@pytest.fixture
def fixtures_dir() -> Path:
    return FIXTURES


@pytest.fixture
def fixture_pm(sim_pm):
    """The simulated cell plus the fixture job (``fixture-job``) and its stages, registered by hand."""
    sim_pm.register(fixture_plugins, "fixture", distribution="weldcell-tests")
    return sim_pm


@pytest.fixture
def make_distribution(tmp_path, monkeypatch):
    """Install a fake distribution in ``tmp_path``: modules + a ``<name>-<version>.dist-info`` folder.

    ``make_distribution(name, version, modules={module: source_or_path}, entry_points={group: {ep: value}})``
    writes real metadata that :mod:`importlib.metadata` finds once ``tmp_path`` is on ``sys.path``.
    """
    site = tmp_path / "site"
    site.mkdir(exist_ok=True)
    monkeypatch.syspath_prepend(str(site))
    created: list[str] = []

    def _make(
        name: str, version: str, modules: dict[str, str | Path], entry_points: dict[str, dict[str, str]]
    ):
        for mod, src in modules.items():
            target = site / f"{mod}.py"
            if isinstance(src, Path):
                shutil.copyfile(src, target)
            else:
                target.write_text(src)
            created.append(mod)
        info = site / f"{name.replace('-', '_')}-{version}.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
        lines = []
        for group, eps in entry_points.items():
            lines.append(f"[{group}]")
            lines += [f"{k} = {v}" for k, v in eps.items()]
            lines.append("")
        (info / "entry_points.txt").write_text("\n".join(lines))
        importlib.invalidate_caches()
        return info

    yield _make
    for mod in created:
        sys.modules.pop(mod, None)


@pytest.fixture
def wide_console(monkeypatch):
    """Make the CLI's rich consoles wide so long messages are not wrapped in the captured output."""
    from weldcell.sdk import cli

    monkeypatch.setattr(cli.console, "_width", 400)
    monkeypatch.setattr(cli.out, "_width", 400)
    return cli
