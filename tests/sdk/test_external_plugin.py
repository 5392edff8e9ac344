"""A third-party plugin package found through REAL entry-point metadata (a ``*.dist-info`` on sys.path):
listed by `weldcell plugins` with its distribution and version, its stage selected by a profile, and its
job run end to end. A broken one is listed as failed while the built-in plugins still load."""

from __future__ import annotations

import json
import textwrap

import pytest
from click.testing import CliRunner
from weldcell.sdk.cli import main
from weldcell.sdk.jobs import run_job
from weldcell.sdk.plugins import PluginManager, set_plugin_manager


@pytest.fixture
def demo_installed(make_distribution, fixtures_dir):
    return make_distribution(
        "weldcell-demo-plugin",
        "0.1",
        modules={"weldcell_demo_plugin": fixtures_dir / "external" / "weldcell_demo_plugin.py"},
        entry_points={"weldcell": {"demo": "weldcell_demo_plugin"}, "console_scripts": {"demo-x": "x:y"}},
    )


@pytest.fixture
def discovered_pm():
    """Set after the distribution is installed: a fresh manager with real discovery, used by the CLI."""
    holder = {}

    def _make() -> PluginManager:
        pm = PluginManager(discover=True)
        holder["previous"] = set_plugin_manager(pm)
        holder["set"] = True
        return pm

    yield _make
    if holder.get("set"):
        set_plugin_manager(holder["previous"])


@pytest.fixture
def wide(monkeypatch):
    from weldcell.sdk import cli

    monkeypatch.setattr(cli.console, "_width", 400)
    monkeypatch.setattr(cli.out, "_width", 400)


def test_demo_plugin_is_discovered_through_its_entry_point(demo_installed, discovered_pm):
    pm = discovered_pm()
    assert "demo" in pm.plugin_names()
    entry = pm.registry.entry("stage", "demo.round")
    assert entry.provider.plugin == "demo"
    assert entry.provider.distribution == "weldcell-demo-plugin" and entry.provider.version == "0.1"
    assert entry.provider.entry_point == "demo = weldcell_demo_plugin"
    assert pm.registry.get("job", "demo-job").stages[0].default == "demo.round"
    assert "robot.sim" in pm.registry.names("device")  # the built-ins are there as well


def test_weldcell_plugins_lists_the_demo_plugin(demo_installed, discovered_pm, wide):
    pm = discovered_pm()
    r = CliRunner().invoke(main, ["plugins"])
    failures_elsewhere = bool(pm.registry.failures or pm.registry.conflicts)
    assert r.exit_code == (4 if failures_elsewhere else 0), r.output
    assert "plugin demo — weldcell-demo-plugin 0.1" in r.output
    row = next(line for line in r.output.splitlines() if "demo.round" in line)
    assert "stage" in row and "demo-round" in row and "round coordinates to a grid" in row
    assert "plugin sim — weldcell" in r.output
    data = json.loads(CliRunner().invoke(main, ["plugins", "--json"]).output)
    rows = {(x["category"], x["name"]): x for x in data["registered"]}
    assert rows[("job", "demo-job")]["distribution"] == "weldcell-demo-plugin"
    assert rows[("job", "demo-job")]["version"] == "0.1"
    assert not [f for f in data["failures"] if f["plugin"] == "demo"]


def test_demo_stage_selected_by_a_profile_and_its_job_run_end_to_end(demo_installed, discovered_pm, tmp_path):
    pm = discovered_pm()
    profile = tmp_path / "demo.toml"
    profile.write_text(
        textwrap.dedent("""\
        schema = "weldcell/profile@1"
        name = "demo-cell"
        [job]
        name = "demo-job"
        [devices.robot]
        plugin = "robot.sim"
        settings = { model = "ur5", start_xyz = [0.4, 0.1, 0.3] }
        [stages.round]
        plugin = "demo.round"
        settings = { grid = "5 cm" }
        """)
    )
    run, result = run_job(profile, pm, runs_dir=tmp_path / "runs")
    assert run.parent == tmp_path / "runs" and run.name.startswith("demo-cell-")
    assert result["status"] == "ok"
    assert result["figures"]["grid"] == pytest.approx(0.05)
    out = json.loads((run / "demo.json").read_text())
    assert out["tcp"] == pytest.approx([0.4, 0.1, 0.3], abs=1e-6)
    assert out["rounded"] == pytest.approx([0.4, 0.1, 0.3], abs=1e-9)
    assert result["figures"]["rounded_x"] == pytest.approx(0.4)
    saved = json.loads((run / "result.json").read_text())
    assert saved["status"] == "ok"
    prov = saved["provenance"]["plugins"]
    assert prov["job:demo-job"] == {
        "plugin": "demo",
        "distribution": "weldcell-demo-plugin",
        "version": "0.1",
    }
    assert prov["stage:round:demo.round"]["distribution"] == "weldcell-demo-plugin"
    assert prov["device:robot:robot.sim"]["distribution"] == "weldcell"
    state = json.loads((run / "state.json").read_text())
    assert state["steps"]["round"]["status"] == "done"


def test_broken_external_plugin_is_listed_as_failed_and_builtins_still_load(
    make_distribution, fixtures_dir, discovered_pm, wide
):
    make_distribution(
        "weldcell-broken-plugin",
        "3.2",
        modules={"weldcell_broken_plugin": fixtures_dir / "external" / "weldcell_broken_plugin.py"},
        entry_points={"weldcell": {"broken": "weldcell_broken_plugin"}},
    )
    pm = discovered_pm()
    r = CliRunner().invoke(main, ["plugins"])
    assert r.exit_code == 4
    assert "failed to load:" in r.output
    line = next(x for x in r.output.splitlines() if "plugin 'broken'" in x)
    assert "weldcell-broken-plugin 3.2" in line and "broken = weldcell_broken_plugin" in line
    assert "ImportError" in line and "frobnicator" in line
    assert "plugin sim — weldcell" in r.output and "robot.sim" in r.output
    assert "robot.sim" in pm.registry.names("device")
    data = json.loads(CliRunner().invoke(main, ["plugins", "--json"]).output)
    broken = [f for f in data["failures"] if f["plugin"] == "broken"]
    assert broken and broken[0]["distribution"] == "weldcell-broken-plugin" and broken[0]["stage"] == "load"


def test_broken_external_plugin_is_fatal_with_strict_plugins(
    make_distribution, fixtures_dir, discovered_pm, monkeypatch, wide
):
    make_distribution(
        "weldcell-broken-plugin",
        "3.2",
        modules={"weldcell_broken_plugin": fixtures_dir / "external" / "weldcell_broken_plugin.py"},
        entry_points={"weldcell": {"broken": "weldcell_broken_plugin"}},
    )
    discovered_pm()  # restored afterwards, also when --strict-plugins replaces it
    monkeypatch.delenv("WELDCELL_STRICT_PLUGINS", raising=False)
    r = CliRunner().invoke(main, ["--strict-plugins", "plugins"])
    import os

    os.environ.pop("WELDCELL_STRICT_PLUGINS", None)
    assert r.exit_code == 4
    assert "weldcell_broken_plugin" in r.output and "strict" in r.output
    assert "Traceback" not in r.output
