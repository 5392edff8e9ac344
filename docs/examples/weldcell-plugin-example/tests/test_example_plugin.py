"""Tests of the example plugin, with the fixtures of weldcell's pytest plugin."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import DataError, ProfileError
from weldcell.sdk.geometry import T_from_rpy, transform_points, transform_vectors

import weldcell_plugin_example
from weldcell_plugin_example.gcode import GcodeSettings, to_gcode
from weldcell_plugin_example.height_step import HeightStepSeams, HeightStepSettings

THICKNESS = 0.005


def lap_joint(yaw_deg: float = 0.0, step: float = THICKNESS, seed: int = 0):
    """A lap joint seen from above: lower plate x in [0, 0.2], upper plate (``step`` thick) x in [0.1, 0.3],
    its edge face at x = 0.1; 0.2 mm noise. Returns the cloud and T_base_part (the seam is x = 0.1, z = 0)."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, 0.15, 0.001)
    lower = np.array([[x, y, 0.0] for x in np.arange(0.0, 0.1, 0.001) for y in g])
    upper = np.array([[x, y, step] for x in np.arange(0.1, 0.3, 0.001) for y in g])
    face = np.array([[0.1, y, z] for z in np.arange(0.0005, step, 0.001) for y in g]).reshape(-1, 3)
    P = np.vstack([lower, upper, face])
    P += rng.normal(0.0, 0.0002, P.shape)
    T = T_from_rpy([0.0, 0.0, np.radians(yaw_deg)], [0.4, -0.1, 0.02])
    return PointCloud(transform_points(T, P), frame="base"), T


@pytest.mark.parametrize("yaw", [0.0, 35.0])
def test_finds_the_lap_seam_where_it_is(yaw):
    cloud, T = lap_joint(yaw)
    result = HeightStepSeams(HeightStepSettings())(cloud)
    assert len(result.seams) == 1
    seam = result.seams[0]
    assert seam.joint_class == "lap" and not seam.closed
    local = transform_points(np.linalg.inv(T), seam.points)
    assert np.sqrt(np.mean((local[:, 0] - 0.1) ** 2)) < 0.001, "seam must lie at the upper plate's edge"
    assert np.sqrt(np.mean(local[:, 2] ** 2)) < 0.001, "seam must lie on the lower plate"
    assert abs(seam.length - 0.15) < 0.006
    expected = transform_vectors(T, np.array([[1.0, 0.0, -1.0]]) / np.sqrt(2))[0]
    assert np.degrees(np.arccos(np.clip(seam.normals @ expected, -1, 1))).max() < 10.0


def test_no_seam_on_a_small_step_or_a_flat_plate():
    small, _ = lap_joint(step=0.001)
    assert HeightStepSeams(HeightStepSettings(min_step="2 mm"))(small).seams == []
    flat = PointCloud(np.column_stack([np.random.default_rng(1).uniform(0, 0.1, (2000, 2)), np.zeros(2000)]))
    assert HeightStepSeams(HeightStepSettings())(flat).seams == []


def test_settings_take_units_and_refuse_unknown_keys():
    assert HeightStepSettings(min_step="3 mm").min_step == pytest.approx(0.003)
    with pytest.raises(ValueError, match="not a unit of length"):
        HeightStepSettings(radius="3 kg")
    with pytest.raises(ValueError, match="extra"):
        HeightStepSettings(min_stepp=0.003)


def test_registered_names_are_selectable(weldcell_pm, register_plugin):
    with register_plugin(weldcell_plugin_example, "example"):
        stage = weldcell_pm.registry.get("stage", "seam.height-step", kind="seam")
        assert stage.factory is HeightStepSeams and stage.settings is HeightStepSettings
        exporter = weldcell_pm.registry.get("exporter", "export.gcode-like")
        assert exporter.suffix == ".nc"
    assert "seam.height-step" not in weldcell_pm.registry.names("stage")  # unregistered after the block


PROFILE = """
schema = "weldcell/profile@1"
name = "lap-cell"
[job]
name = "scan-and-plan"
[devices.robot]
plugin = "robot.sim"
[devices.camera]
plugin = "camera.sim"
mount = {{ parent = "robot.flange" }}
[devices.gesture]
plugin = "gesture.sim"
[[sim.workpieces]]
kind = "fillet-t"
[stages.seam]
plugin = "seam.height-step"
settings = {{ {settings} }}
[output]
exporters = ["export.gcode-like"]
"""


def test_a_profile_selects_the_stage_and_exporter(sim_pm, register_plugin, tmp_path):
    import weldcell.plugins.scan_plan as scan_plan
    from weldcell.sdk.jobs import prepare

    sim_pm.register(scan_plan, "scan_plan")
    f = tmp_path / "lap.toml"
    f.write_text(PROFILE.format(settings='min_step = "3 mm"'))
    with register_plugin(weldcell_plugin_example, "example"):
        _, resolved = prepare(f, sim_pm)
        spec, settings = resolved.stages["seam"]
        assert spec.name == "seam.height-step" and settings.min_step == pytest.approx(0.003)
        assert [e.name for e in resolved.exporters] == ["export.gcode-like"]
        f.write_text(PROFILE.format(settings='min_step = "3 kg"'))
        with pytest.raises(ProfileError) as err:
            prepare(f, sim_pm)
        assert any("stages.seam.settings.min_step" in p and "kg" in p for p in err.value.problems)


def test_gcode_export_of_a_planned_path():
    from weldcell.plugins.scan_plan.stages import TorchPathPlanner, TorchPathSettings

    cloud, _ = lap_joint()
    seams = HeightStepSeams(HeightStepSettings())(cloud).seams
    path = TorchPathPlanner(TorchPathSettings())(seams)  # weldcell's own path stage accepts these seams
    text = to_gcode(path.to_json(), GcodeSettings(feed="10 mm/s"))
    lines = text.splitlines()
    g1 = [ln for ln in lines if ln.startswith("G1")]
    assert len(g1) == len(path.seams[0].poses)
    assert all(ln.endswith("F600") for ln in g1)
    assert lines.index("M3") < lines.index("M5") and lines[-1] == "M2"
    x0 = float(g1[0].split()[1][1:])
    assert x0 == pytest.approx(path.seams[0].poses[0][0, 3] * 1000, abs=1e-3)
    with pytest.raises(DataError, match="schema"):
        to_gcode({"schema": "something/else@1"})
