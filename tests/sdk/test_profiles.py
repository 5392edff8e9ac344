"""Cell profiles: extends, env secrets, and every problem reported with file, key path and fix."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import pytest
from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import ProfileError
from weldcell.sdk.hookspecs import hookimpl
from weldcell.sdk.jobs import prepare
from weldcell.sdk.plugins import PluginManager
from weldcell.sdk.profile import load_profile, validate_profile
from weldcell.sdk.settings import NoSettings

REPO = Path(__file__).resolve().parents[2]

HEADER = """\
schema = "weldcell/profile@1"
name = "t"
[job]
name = "fixture-job"
"""
ROBOT = """
[devices.robot]
plugin = "robot.sim"
"""


def write(tmp_path: Path, text: str, name: str = "cell.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text))
    return p


def problems_of(path: Path, pm) -> list[str]:
    with pytest.raises(ProfileError) as e:
        prepare(path, pm)
    assert e.value.exit_code == 3
    assert e.value.problems, "a ProfileError about keys lists its problems"
    assert str(path.resolve()) in e.value.message
    return e.value.problems


def only(problems: list[str], needle: str) -> str:
    hits = [p for p in problems if needle in p]
    assert len(hits) == 1, f"expected one problem with {needle!r} in {problems}"
    return hits[0]


# -- a good profile ------------------------------------------------------------------------------
def test_fixture_profile_validates_with_units_converted(fixture_pm, fixtures_dir):
    loaded, resolved = prepare(fixtures_dir / "fixture-job-sim.toml", fixture_pm)
    assert loaded.profile.name == "fixture-sim"
    assert resolved.job.standoff == pytest.approx(0.015)  # "15 mm"
    assert resolved.job.passes == 2
    spec, settings = resolved.devices["robot"]
    assert spec.name == "robot.sim" and settings.tcp_xyz == pytest.approx((0.0, 0.0, 0.1))  # "100 mm"
    assert (
        resolved.stages["scale"][0].name == "scale.multiply"
        and resolved.stages["scale"][1].factor == 2.0
    )
    assert "camera" not in resolved.devices  # optional role, not given


def test_resolved_profile_is_typed_frozen_and_keeps_the_old_keys_deprecated(fixture_pm, fixtures_dir):
    import dataclasses

    from weldcell.sdk.profile import ResolvedProfile

    _, resolved = prepare(fixtures_dir / "fixture-job-sim.toml", fixture_pm)
    assert isinstance(resolved, ResolvedProfile)
    assert resolved.job_spec.name == "fixture-job" and resolved.exporters == []
    with pytest.raises(dataclasses.FrozenInstanceError):
        resolved.job = None
    # third-party code written against the old dict still reads the same objects, with a warning
    with pytest.warns(DeprecationWarning, match=r"resolved\.stages"):
        assert resolved["stages"] is resolved.stages
    with pytest.raises(KeyError):
        resolved["settings"]


def test_stage_default_is_used_when_the_profile_is_silent(fixture_pm, tmp_path):
    loaded, resolved = prepare(write(tmp_path, HEADER + ROBOT), fixture_pm)
    assert resolved.stages["scale"][0].name == "scale.multiply"
    assert resolved.stages["scale"][1].factor == 1.0


# -- extends ----------------------------------------------------------------------------------
def test_child_overrides_base_and_sources_are_tracked(fixtures_dir):
    loaded = load_profile(fixtures_dir / "child.toml")
    p = loaded.profile
    base, child = (fixtures_dir / "base.toml").resolve(), (fixtures_dir / "child.toml").resolve()
    assert p.name == "child-cell"
    assert p.job.settings == {"passes": 4, "label": "from-base"}  # merged key by key
    assert p.stages["scale"].settings == {"factor": 5.0}
    assert p.devices["robot"].plugin == "robot.sim"
    assert loaded.files == [child, base]
    assert loaded.source_of(("job", "settings", "passes")) == child
    assert loaded.source_of(("job", "settings", "label")) == base
    assert loaded.source_of(("devices", "robot", "settings", "speeed")) == base
    assert loaded.source_of(("stages", "scale", "settings", "factor")) == child


def test_error_in_a_key_set_by_the_base_names_the_base_file(fixture_pm, fixtures_dir):
    problems = problems_of(fixtures_dir / "child.toml", fixture_pm)
    line = only(problems, "speeed")
    base = str((fixtures_dir / "base.toml").resolve())
    assert line == f"{base}: devices.robot.settings.speeed: unknown key; remove it or check its spelling"


def test_extends_cycle_is_refused(fixtures_dir):
    with pytest.raises(ProfileError) as e:
        load_profile(fixtures_dir / "cycle_a.toml")
    assert "cycle" in e.value.message
    assert "cycle_a.toml" in e.value.message and "cycle_b.toml" in e.value.message
    assert "extends" in e.value.fix


def test_extends_missing_base(tmp_path):
    p = write(tmp_path, 'extends = "nowhere/base.toml"\nname = "x"\n')
    with pytest.raises(ProfileError) as e:
        load_profile(p)
    assert str(p.resolve()) in e.value.message and "nowhere/base.toml" in e.value.message
    assert "relative to this file" in e.value.fix


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(ProfileError, match="profile not found"):
        load_profile(tmp_path / "absent.toml")
    bad = write(tmp_path, 'name = "x"\n[job\n', "bad.toml")
    with pytest.raises(ProfileError) as e:
        load_profile(bad)
    assert str(bad.resolve()) in e.value.message and "not valid TOML" in e.value.message


# -- env secrets -----------------------------------------------------------------------------
def test_env_substitution(fixture_pm, tmp_path, monkeypatch):
    monkeypatch.setenv("WELDCELL_TEST_CELL_LABEL", "bay-7")
    p = write(tmp_path, HEADER + '[job.settings]\nlabel = "cell ${env:WELDCELL_TEST_CELL_LABEL}!"\n' + ROBOT)
    loaded, resolved = prepare(p, fixture_pm)
    assert resolved.job.label == "cell bay-7!"


def test_missing_env_var_names_the_variable_and_key(tmp_path, monkeypatch):
    monkeypatch.delenv("WELDCELL_TEST_UNSET_SECRET", raising=False)
    p = write(tmp_path, HEADER + '[job.settings]\nlabel = "${env:WELDCELL_TEST_UNSET_SECRET}"\n' + ROBOT)
    with pytest.raises(ProfileError) as e:
        load_profile(p)
    line = only(e.value.problems, "WELDCELL_TEST_UNSET_SECRET")
    assert line.startswith(f"{p.resolve()}: job.settings.label: ")
    assert "is not set" in line and "export WELDCELL_TEST_UNSET_SECRET=" in line


# -- settings problems ---------------------------------------------------------------------
def test_unknown_key_gives_file_key_path_and_fix(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + ROBOT + "[devices.robot.settings]\nspeeed = 0.1\n")
    line = only(problems_of(p, fixture_pm), "speeed")
    assert (
        line == f"{p.resolve()}: devices.robot.settings.speeed: unknown key; remove it or check its spelling"
    )


def test_unknown_top_level_key(fixture_pm, tmp_path):
    p = write(tmp_path, 'colour = "red"\n' + HEADER + ROBOT)
    with pytest.raises(ProfileError) as e:
        load_profile(p)
    assert (
        only(e.value.problems, "colour")
        == f"{p.resolve()}: colour: unknown key; remove it or check its spelling"
    )


def test_wrong_type(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + '[job.settings]\npasses = "many"\n' + ROBOT)
    line = only(problems_of(p, fixture_pm), "job.settings.passes")
    assert "valid integer" in line and "'many'" in line


def test_out_of_range_value(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + "[job.settings]\npasses = 50\n" + ROBOT)
    line = only(problems_of(p, fixture_pm), "job.settings.passes")
    assert "less than or equal to 10" in line and "(got 50)" in line


def test_out_of_range_in_a_device_setting(fixture_pm, tmp_path):
    p = write(
        tmp_path,
        HEADER + ROBOT + '[devices.camera]\nplugin = "camera.sim"\n'
        "[devices.camera.settings]\ndecimation = 20\n",
    )
    line = only(problems_of(p, fixture_pm), "decimation")
    assert f"{p.resolve()}: devices.camera.settings.decimation:" in line and "less than or equal to 8" in line


def test_unit_strings_are_converted_and_wrong_units_refused(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + '[job.settings]\nstandoff = "15 mm"\n' + ROBOT)
    assert prepare(p, fixture_pm)[1].job.standoff == pytest.approx(0.015)
    p = write(tmp_path, HEADER + '[job.settings]\nstandoff = "15 kg"\n' + ROBOT, "kg.toml")
    line = only(problems_of(p, fixture_pm), "standoff")
    assert line.startswith(f"{p.resolve()}: job.settings.standoff: ")
    assert "'kg' is not a unit of length" in line and "use one of m, cm, mm, um, in" in line


def test_mount_units_and_unknown_mount_parent(fixture_pm, tmp_path):
    p = write(
        tmp_path,
        HEADER + ROBOT + '[devices.camera]\nplugin = "camera.sim"\n'
        'mount = { parent = "robot.flange", xyz = ["0 mm", "-60 mm", "4 cm"], rpy = ["90 deg", 0, 0] }\n',
    )
    loaded, resolved = prepare(p, fixture_pm)
    mount = loaded.profile.devices["camera"].mount
    assert mount.xyz == pytest.approx((0.0, -0.06, 0.04)) and mount.rpy[0] == pytest.approx(1.5707963)
    p = write(
        tmp_path,
        HEADER + ROBOT + '[devices.camera]\nplugin = "camera.sim"\nmount = { parent = "arm.flange" }\n',
        "m2.toml",
    )
    line = only(problems_of(p, fixture_pm), "mount.parent")
    assert "'arm.flange' names no device of this profile" in line


def test_every_problem_is_reported_at_once(fixture_pm, fixtures_dir):
    path = fixtures_dir / "bad-three-problems.toml"
    problems = problems_of(path, fixture_pm)
    assert len(problems) == 3
    assert any("job.settings.passes" in p and "less than or equal to 10" in p for p in problems)
    assert any("job.settings.standoff" in p and "'kg'" in p for p in problems)
    assert any("devices.robot.settings.speeed: unknown key" in p for p in problems)
    assert all(p.startswith(str(path.resolve())) for p in problems)


# -- plugins named in the profile --------------------------------------------------------------
def test_unknown_device_plugin_lists_available_names(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + '[devices.robot]\nplugin = "robot.simm"\n')
    line = only(problems_of(p, fixture_pm), "robot.simm")
    assert line.startswith(f"{p.resolve()}: devices.robot.plugin: ")
    assert "did you mean 'robot.sim'" in line and "available robot devices: robot.sim" in line


def test_device_plugin_of_the_wrong_kind(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + '[devices.robot]\nplugin = "camera.sim"\n')
    line = only(problems_of(p, fixture_pm), "devices.robot.plugin")
    assert "device 'camera.sim' is a depth_camera, not a robot" in line and "robot.sim" in line


def test_unknown_job_lists_jobs(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER.replace("fixture-job", "fixture-jb") + ROBOT)
    line = only(problems_of(p, fixture_pm), "job.name")
    assert "no job named 'fixture-jb'" in line and "did you mean 'fixture-job'" in line


def test_unknown_stage_and_wrong_stage_kind(fixture_pm, tmp_path):
    p = write(
        tmp_path, HEADER + ROBOT + '[stages.scale]\nplugin = "offset.add"\n[stages.blur]\nplugin = "x.y"\n'
    )
    problems = problems_of(p, fixture_pm)
    assert "stage 'offset.add' is a offset, not a scale" in only(problems, "stages.scale.plugin")
    assert "job 'fixture-job' has no stage 'blur'; its stages are: scale" in only(problems, "stages.blur")


def test_unknown_exporter(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + ROBOT + '[output]\nexporters = ["export.urscrpt"]\n')
    line = only(problems_of(p, fixture_pm), "output.exporters.0")
    assert "no exporter named 'export.urscrpt'" in line


def test_missing_extra_names_the_pip_install(fixture_pm, register_plugin, tmp_path):
    class NeedsExtra:
        @hookimpl
        def weldcell_register_devices(self, register):
            register(
                DeviceSpec(
                    name="robot.fancy",
                    kind="robot",
                    summary="needs a vendor SDK",
                    settings=NoSettings,
                    requires={"not_a_real_module_xyz": "foo"},
                )
            )

    with register_plugin(NeedsExtra(), "fancy"):
        p = write(tmp_path, HEADER + '[devices.robot]\nplugin = "robot.fancy"\n')
        line = only(problems_of(p, fixture_pm), "robot.fancy")
    assert line.startswith(f"{p.resolve()}: devices.robot.plugin: ")
    assert "'not_a_real_module_xyz', which is not installed" in line
    assert "pip install 'weldcell[foo]'" in line


def test_device_role_the_job_does_not_use(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + ROBOT + '[devices.laser]\nplugin = "displacement.sim"\n')
    line = only(problems_of(p, fixture_pm), "devices.laser")
    assert "job 'fixture-job' uses no device 'laser'; its devices are: robot, camera" in line


def test_missing_required_device_role(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER)
    line = only(problems_of(p, fixture_pm), "devices.robot")
    assert "job 'fixture-job' needs a robot as device 'robot'" in line
    assert "add [devices.robot] with a plugin" in line


def test_missing_calibration_file(fixture_pm, tmp_path):
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "present.json").write_text("{}")
    p = write(
        tmp_path,
        HEADER + ROBOT + '[calibration]\nhandeye = "calib/handeye.json"\npresent = "calib/present.json"\n',
    )
    problems = problems_of(p, fixture_pm)
    line = only(problems, "calibration.handeye")
    assert f"file not found: {(tmp_path / 'calib' / 'handeye.json').resolve()}" in line
    assert "weldcell calibrate" in line
    assert not any("present" in x for x in problems)


def test_calibration_path_is_relative_to_the_file_that_wrote_it(fixture_pm, tmp_path):
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "handeye.json").write_text("{}")
    write(tmp_path, HEADER + ROBOT + '[calibration]\nhandeye = "handeye.json"\n', "base/base.toml")
    child = write(tmp_path, 'extends = "base/base.toml"\nname = "child"\n', "child.toml")
    loaded, _ = prepare(child, fixture_pm)  # found beside base.toml, not beside child.toml
    assert loaded.profile.calibration == {"handeye": "handeye.json"}


def test_sim_workpiece_with_unknown_kind(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + ROBOT + '[[sim.workpieces]]\nkind = "fillet-tee"\n')
    line = only(problems_of(p, fixture_pm), "sim.workpieces.0.kind")
    assert "unknown workpiece kind 'fillet-tee'" in line and "fillet-t" in line


def test_sim_workpiece_with_unknown_parameter(fixture_pm, tmp_path):
    p = write(tmp_path, HEADER + ROBOT + '[[sim.workpieces]]\nkind = "fillet-t"\nparams = { lenght = 0.3 }\n')
    line = only(problems_of(p, fixture_pm), "lenght")
    assert line.startswith(f"{p.resolve()}: sim.workpieces.0.params.lenght: ")
    assert "'fillet-t' has no parameter 'lenght'" in line and "length" in line


def test_schema_must_match(tmp_path):
    p = write(tmp_path, HEADER.replace("profile@1", "profile@9") + ROBOT)
    with pytest.raises(ProfileError) as e:
        load_profile(p)
    assert "unsupported schema 'weldcell/profile@9'" in e.value.problems[0]


def test_unsafe_cell_limits_are_refused(fixture_pm, tmp_path):
    p = write(
        tmp_path,
        HEADER + ROBOT + "[cell.safety]\nworkspace_min = [0.5, 0, 0]\nworkspace_max = [0.2, 1, 1]\n"
        'max_linear_speed = "-5 mm/s"\n',
    )
    with pytest.raises(ProfileError) as e:
        load_profile(p)
    text = "\n".join(e.value.problems)
    assert "cell.safety.max_linear_speed" in text and "greater than 0" in text


def test_validate_profile_with_extra_checks_hook(fixture_pm, fixtures_dir):
    loaded = load_profile(fixtures_dir / "fixture-job-sim.toml")
    with pytest.raises(ProfileError) as e:
        validate_profile(
            loaded,
            fixture_pm.registry,
            extra_checks=lambda lp: [(("job", "settings", "label"), "labels must be shouty")],
        )
    assert e.value.problems == [f"{loaded.path}: job.settings.label: labels must be shouty"]


# -- the shipped profiles ----------------------------------------------------------------------
PROFILES = sorted((REPO / "profiles").glob("*.toml"))


@pytest.fixture(scope="module")
def installed_pm():
    return PluginManager(discover=True)


def _is_sim(path: Path, loaded) -> bool:
    return "sim" in path.stem.split("-") or all(
        d.plugin.endswith(".sim") for d in loaded.profile.devices.values()
    )


@pytest.mark.parametrize("path", PROFILES, ids=[p.name for p in PROFILES])
def test_every_shipped_profile_validates(path, installed_pm, monkeypatch):
    # a hardware template names its secrets as ${env:NAME}; the integrator exports them before a run
    for name in re.findall(r"\$\{env:([A-Za-z_][A-Za-z0-9_]*)\}", path.read_text()):
        monkeypatch.setenv(name, "not-a-real-secret")
    loaded = load_profile(path)
    reg = installed_pm.registry
    names = [("job", loaded.profile.job.name)]
    names += [("device", d.plugin) for d in loaded.profile.devices.values()]
    names += [("stage", s.plugin) for s in loaded.profile.stages.values() if s.plugin]
    names += [("exporter", e) for e in loaded.profile.output.exporters]
    missing = [f"{c} '{n}'" for c, n in names if n not in reg.entries[c]]
    if missing and not _is_sim(path, loaded):
        pytest.skip(f"{path.name}: plugins not installed yet: {', '.join(missing)}")
    try:
        validate_profile(loaded, reg, extra_checks=installed_pm.check_profile)
    except ProfileError as e:
        pytest.fail(f"{path.name} does not validate:\n" + "\n".join(e.problems or [str(e)]))


def test_shipped_profiles_include_the_simulated_cell():
    assert any(re.search(r"sim", p.stem) for p in PROFILES)
