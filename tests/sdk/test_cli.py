"""The `weldcell` command line: help, profile validation, errors without tracebacks, devices, plugins."""

from __future__ import annotations

import json
import textwrap

import pytest
import weldcell.plugins.exporters as exporters_plugin
import weldcell.plugins.scan_plan as scan_plan_plugin
from click.testing import CliRunner
from weldcell.sdk.cli import main
from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import ProfileError
from weldcell.sdk.hookspecs import hookimpl
from weldcell.sdk.settings import NoSettings


@pytest.fixture
def runner():
    return CliRunner()


@pytest.fixture
def cell_pm(sim_pm):
    """The plugins the shipped simulated profile needs (registered by hand, no discovery)."""
    sim_pm.register(scan_plan_plugin, "scan_plan", distribution="weldcell")
    sim_pm.register(exporters_plugin, "exporters", distribution="weldcell")
    return sim_pm


def invoke(runner, *args):
    return runner.invoke(main, list(args), catch_exceptions=False)


# -- help ------------------------------------------------------------------------------------
def test_help_lists_the_commands(runner, weldcell_pm):
    r = invoke(runner, "--help")
    assert r.exit_code == 0
    for cmd in ("run", "plugins", "profiles", "devices"):
        assert cmd in r.output
    assert "--debug" in r.output and "weldcell run profiles/cell1-scan-and-plan-sim.toml" in r.output


def test_run_help_lists_its_options(runner, weldcell_pm):
    r = invoke(runner, "run", "--help")
    assert r.exit_code == 0
    for opt in ("PROFILE", "--resume", "--runs-dir", "--dry-run", "--quiet"):
        assert opt in r.output


def test_plugin_commands_appear_in_the_cli(runner, weldcell_pm, register_plugin):
    import click
    from weldcell.sdk.descriptors import CommandSpec

    @click.command()
    def hello():
        """Say hello from a plugin."""
        click.echo("hello from the plugin")

    class Commands:
        @hookimpl
        def weldcell_register_commands(self, register):
            register(CommandSpec(name="hello", command=hello, summary="greets"))

    with register_plugin(Commands(), "greeter"):
        assert "hello" in invoke(runner, "--help").output
        r = invoke(runner, "hello")
        assert r.exit_code == 0 and "hello from the plugin" in r.output
    assert invoke(runner, "hello").exit_code == 2  # gone with the plugin


# -- profiles validate ---------------------------------------------------------------------------
def test_validate_good_profile(runner, fixture_pm, fixtures_dir, wide_console):
    r = invoke(runner, "profiles", "validate", str(fixtures_dir / "fixture-job-sim.toml"))
    assert r.exit_code == 0, r.output
    assert (
        "fixture-job-sim.toml" in r.output and "job=fixture-job" in r.output and "robot=robot.sim" in r.output
    )


def test_validate_bad_profile_prints_every_problem(runner, fixture_pm, fixtures_dir, wide_console):
    good, bad = fixtures_dir / "fixture-job-sim.toml", fixtures_dir / "bad-three-problems.toml"
    r = invoke(runner, "profiles", "validate", str(good), str(bad))
    assert r.exit_code == 3
    out = r.output
    assert "✓" in out and "✗" in out
    assert f"{bad.resolve()}: devices.robot.settings.speeed: unknown key" in out
    assert "job.settings.passes" in out and "job.settings.standoff" in out
    assert "'kg' is not a unit of length" in out
    assert "1 of 2 profile(s) invalid" in out
    assert "Traceback" not in out


def test_validate_prints_the_missing_extra_verbatim(
    runner, fixture_pm, register_plugin, tmp_path, wide_console
):
    """Brackets in messages (``weldcell[foo]``) must reach the terminal, not be eaten as rich markup."""

    class NeedsExtra:
        @hookimpl
        def weldcell_register_devices(self, register):
            register(
                DeviceSpec(
                    name="robot.fancy",
                    kind="robot",
                    summary="needs [vendor] SDK",
                    settings=NoSettings,
                    requires={"not_a_real_module_xyz": "foo"},
                )
            )

    p = tmp_path / "fancy.toml"
    p.write_text(
        'schema = "weldcell/profile@1"\nname = "f"\n[job]\nname = "fixture-job"\n'
        '[devices.robot]\nplugin = "robot.fancy"\n'
    )
    with register_plugin(NeedsExtra(), "fancy"):
        r = invoke(runner, "profiles", "validate", str(p))
        assert r.exit_code == 3
        assert "pip install 'weldcell[foo]'" in r.output
        r = invoke(runner, "devices")
        assert r.exit_code == 0
        assert "weldcell[foo]" in r.output and "not_a_real_module_xyz" in r.output
        assert "needs [vendor] SDK" in r.output


def test_unknown_profile_path_is_a_clear_error(runner, weldcell_pm, tmp_path, wide_console):
    missing = tmp_path / "nope.toml"
    for args in (("run", str(missing)), ("profiles", "validate", str(missing)), ("devices", str(missing))):
        r = runner.invoke(main, list(args))
        assert r.exit_code == 3, (args, r.output)
        assert f"profile not found: {missing}" in r.output
        assert "Traceback" not in r.output
        assert not isinstance(r.exception, ProfileError)  # handled, not propagated


def test_error_prints_message_fix_and_no_traceback(runner, weldcell_pm, tmp_path, wide_console):
    missing = tmp_path / "nope.toml"
    r = runner.invoke(main, ["run", str(missing)])
    assert r.exit_code == 3
    assert "error: profile not found" in r.output
    assert "fix: check the path" in r.output
    assert "--debug" not in r.output  # a missing file needs no traceback
    assert "Traceback" not in r.output


def test_debug_shows_the_traceback(runner, weldcell_pm, tmp_path, wide_console):
    r = runner.invoke(main, ["--debug", "run", str(tmp_path / "nope.toml")])
    assert r.exit_code == 3
    assert "Traceback (most recent call last)" in r.output
    assert "ProfileError" in r.output and "profile not found" in r.output


def test_run_with_an_invalid_profile_lists_problems(runner, fixture_pm, fixtures_dir, tmp_path, wide_console):
    bad = fixtures_dir / "bad-three-problems.toml"
    r = runner.invoke(main, ["run", str(bad), "--runs-dir", str(tmp_path)])
    assert r.exit_code == 3
    assert "devices.robot.settings.speeed: unknown key" in r.output
    assert list(tmp_path.iterdir()) == []  # nothing was created before validation passed


def test_run_fixture_job_end_to_end(runner, fixture_pm, fixtures_dir, tmp_path, wide_console):
    r = invoke(runner, "run", str(fixtures_dir / "fixture-job-sim.toml"), "--runs-dir", str(tmp_path), "-q")
    assert r.exit_code == 0, r.output
    runs = list(tmp_path.iterdir())
    assert len(runs) == 1 and runs[0].name.startswith("fixture-sim-")
    result = json.loads((runs[0] / "result.json").read_text())
    assert result["status"] == "ok" and result["figures"]["factor"] == 2.0
    assert result["figures"]["standoff"] == pytest.approx(0.015)
    assert f"run folder: {runs[0]}" in r.output


# -- devices ---------------------------------------------------------------------------------
def test_devices_lists_device_plugins_and_extras(runner, sim_pm, register_plugin, wide_console):
    class Vendor:
        @hookimpl
        def weldcell_register_devices(self, register):
            register(
                DeviceSpec(
                    name="robot.vendor",
                    kind="robot",
                    summary="a vendor arm",
                    settings=NoSettings,
                    requires={"json": "vendor"},
                )
            )

    with register_plugin(Vendor(), "vendor"):
        r = invoke(runner, "devices")
    assert r.exit_code == 0
    lines = r.output.splitlines()
    for name, kind in [
        ("robot.sim", "robot"),
        ("camera.sim", "depth_camera"),
        ("gesture.sim", "gesture_sensor"),
        ("displacement.sim", "displacement_sensor"),
        ("projector.sim", "laser_projector"),
        ("imu.sim", "imu"),
        ("gnss.sim", "gnss"),
        ("robot.vendor", "robot"),
    ]:
        row = next((line for line in lines if f" {name} " in f" {line} "), None)
        assert row is not None, f"{name} missing from:\n{r.output}"
        assert kind in row
    vendor = next(line for line in lines if "robot.vendor" in line)
    assert "weldcell[vendor]" in vendor and "missing" not in vendor
    sim = next(line for line in lines if "robot.sim" in line)
    assert "yes" in sim  # simulated


def test_devices_with_profile_probes_the_sim_devices(runner, cell_pm, wide_console):
    from pathlib import Path

    profile = Path(__file__).resolve().parents[2] / "profiles" / "cell1-scan-and-plan-sim.toml"
    r = invoke(runner, "devices", str(profile))
    assert r.exit_code == 0, r.output
    for role, name in (("robot", "robot.sim"), ("camera", "camera.sim"), ("gesture", "gesture.sim")):
        assert f"{role}: {name}: reachable simulated (always reachable)" in r.output


def test_devices_probe_failure_exits_5(runner, fixture_pm, register_plugin, tmp_path, wide_console):
    from weldcell.sdk.errors import DeviceError

    def probe(settings):
        raise DeviceError("no answer from 10.0.0.9:30004 within 1.0 s", "check the cable and the robot's IP")

    class Unreachable:
        @hookimpl
        def weldcell_register_devices(self, register):
            register(
                DeviceSpec(name="robot.faraway", kind="robot", summary="", settings=NoSettings, probe=probe)
            )

    p = tmp_path / "far.toml"
    p.write_text(
        textwrap.dedent("""\
        schema = "weldcell/profile@1"
        name = "far"
        [job]
        name = "fixture-job"
        [devices.robot]
        plugin = "robot.faraway"
        """)
    )
    with register_plugin(Unreachable(), "faraway"):
        r = invoke(runner, "devices", str(p))
    assert r.exit_code == 5
    assert "robot: robot.faraway: not reachable: no answer from 10.0.0.9:30004" in r.output
    assert "check the cable" in r.output


# -- plugins ---------------------------------------------------------------------------------
def test_plugins_json_is_valid_json(runner, cell_pm):
    r = invoke(runner, "plugins", "--json")
    assert r.exit_code == 0
    data = json.loads(r.output)
    rows = {(row["category"], row["name"]): row for row in data["registered"]}
    assert rows[("device", "robot.sim")]["plugin"] == "sim"
    assert rows[("device", "robot.sim")]["distribution"] == "weldcell"
    assert rows[("job", "scan-and-plan")]["status"] == "ok"
    assert ("exporter", "export.urscript") in rows
    assert data["failures"] == [] and data["conflicts"] == []


def test_plugins_reports_conflicts_with_exit_4(runner, weldcell_pm, wide_console):
    from weldcell.sdk.descriptors import StageSpec

    class P:
        @hookimpl
        def weldcell_register_stages(self, register):
            register(StageSpec(name="seam.same", kind="seam", summary=""))

    weldcell_pm.register(P(), "first")
    weldcell_pm.register(P(), "second")
    r = invoke(runner, "plugins")
    assert r.exit_code == 4
    assert "conflicts:" in r.output
    assert (
        "stage 'seam.same' is registered by plugin 'first' and plugin 'second'" in r.output
        or "stage 'seam.same' is registered by plugin 'second' and plugin 'first'" in r.output
    )
    data = json.loads(invoke(runner, "plugins", "--json").output)
    assert len(data["conflicts"]) == 1


def test_failed_run_keeps_its_captures_and_resumes(runner, fixture_pm, fixtures_dir, tmp_path, wide_console):
    profile = tmp_path / "failing.toml"
    profile.write_text(
        (fixtures_dir / "fixture-job-sim.toml")
        .read_text()
        .replace('standoff = "15 mm"', 'label = "fail-after-capture"')
    )
    runs = tmp_path / "runs"
    r = runner.invoke(main, ["run", str(profile), "--runs-dir", str(runs)])
    assert r.exit_code == 1
    assert "job 'fixture-job' failed: RuntimeError: the welding power source did not answer" in r.output
    assert "captures so far are kept in" in r.output and "Traceback" not in r.output
    (run,) = runs.iterdir()
    result = json.loads((run / "result.json").read_text())
    assert result["status"] == "failed" and result["error"]["type"] == "RuntimeError"
    state = json.loads((run / "state.json").read_text())
    assert state["captures"][0]["file"] == "capture-0.json" and (run / "capture-0.json").is_file()
    assert state["steps"]["read robot"]["status"] == "done"
    r = runner.invoke(main, ["run", str(profile), "--resume", str(run), "-q"])
    assert r.exit_code == 0, r.output
    assert list(runs.iterdir()) == [run]  # resumed in place
    result = json.loads((run / "result.json").read_text())
    assert result["status"] == "ok" and (run / "scaled.json").is_file()


def test_resume_of_a_folder_that_is_not_a_run(runner, fixture_pm, fixtures_dir, tmp_path, wide_console):
    r = runner.invoke(main, ["run", str(fixtures_dir / "fixture-job-sim.toml"), "--resume", str(tmp_path)])
    assert r.exit_code == 1
    assert f"{tmp_path} is not a run folder (no state.json)" in r.output
