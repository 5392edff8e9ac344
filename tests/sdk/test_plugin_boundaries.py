"""What plugins share goes through public sdk/hal modules (docs/architecture.md): no plugin imports
another plugin's modules, and the shared pieces are reachable at their public names."""

from __future__ import annotations

import ast
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _imports(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append(node.module)
            if node.module == "weldcell.plugins":
                out += [f"weldcell.plugins.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names]
    return out


def test_no_plugin_imports_another_plugins_modules():
    crossing = []
    for f in sorted((ROOT / "plugins").rglob("*.py")):
        own = f.relative_to(ROOT / "plugins").parts[0]
        for m in _imports(f):
            parts = m.split(".")
            if parts[:2] == ["weldcell", "plugins"] and len(parts) > 2 and parts[2] != own:
                crossing.append(f"{f.relative_to(ROOT)} imports {m}")
    assert not crossing, "use a public sdk/hal module instead:\n" + "\n".join(crossing)


def test_sdk_and_hal_import_no_plugin():
    bad = [
        f"{f.relative_to(ROOT)} imports {m}"
        for layer in ("sdk", "hal")
        for f in sorted((ROOT / layer).rglob("*.py"))
        for m in _imports(f)
        if m.startswith("weldcell.plugins")
    ]
    assert not bad, "\n".join(bad)


def test_simulated_world_is_read_by_its_public_accessor():
    from weldcell.hal.sim import WORLD_KEY, true_camera_mount, world_of

    hardware = SimpleNamespace(shared={}, devices={"camera": object()})
    assert world_of(hardware) is None and true_camera_mount(hardware) is None

    class World:
        def T_world(self, frame):
            assert frame == "robot.base"
            T = np.eye(4)
            T[:3, 3] = (0.1, 0.0, 0.0)  # the robot base 10 cm along the world's x
            return T

    T_world_camera = np.eye(4)
    T_world_camera[:3, 3] = (0.2, -0.1, 0.9)
    cam = SimpleNamespace(T_world_camera=T_world_camera, T_parent_camera=np.eye(4))
    sim = SimpleNamespace(shared={WORLD_KEY: World()}, devices={"camera": cam})
    assert isinstance(world_of(sim), World)
    T_base_camera = true_camera_mount(sim)
    assert T_base_camera[:3, 3] == pytest.approx((0.1, -0.1, 0.9))
    assert true_camera_mount(sim, "eye-in-hand") == pytest.approx(np.eye(4))


def test_moved_modules_keep_their_old_import_paths():
    """Third-party code imported these from their old places; the old names are the same objects."""
    import weldcell.hal.kinematics as kin
    import weldcell.hal.sim.kinematics as old_kin
    import weldcell.plugins.handeye.pointfit as old_fit
    import weldcell.plugins.handeye.result as old_result
    import weldcell.plugins.handeye.samples_io as old_io
    import weldcell.sdk.handeye_files as files
    import weldcell.sdk.pointfit as fit

    assert old_kin.get_model is kin.get_model and old_kin.MODELS is kin.MODELS
    assert old_fit.scaled_svd_fit is fit.scaled_svd_fit
    assert old_result.HandEyeResult is files.HandEyeResult
    assert old_io.read_result is files.read_result and old_io.read_samples is files.read_samples
