"""The cross-plugin rules of docs/architecture.md that test_plugin_boundaries.py does not cover by itself:
relative and dynamic imports stay inside their own plugin, the simulated world is reached by its public
key, and what real robots' safety gates use does not live in the simulation."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PLUGINS = ROOT / "plugins"
#: plugins that drive real hardware (they register devices that are not simulated)
HARDWARE_PLUGINS = (
    "abb", "aruco_camera", "aubo", "franka", "imu_serial", "leap", "optoncdt",
    "phoxi", "projector", "realsense", "ublox", "ur", "zed",
)  # fmt: skip


def _tree(path: Path) -> ast.AST:
    return ast.parse(path.read_text(encoding="utf-8"))


def _absolute(path: Path, node: ast.ImportFrom) -> str:
    """The module a (possibly relative) ``from ... import`` names, as ``weldcell.plugins.<...>``."""
    if node.level == 0:
        return node.module or ""
    package = ["weldcell", "plugins", *path.relative_to(PLUGINS).parent.parts]
    base = package[: len(package) - (node.level - 1)]
    return ".".join([*base, *([node.module] if node.module else [])])


def _imported(path: Path) -> list[str]:
    """Every module imported by ``path``: static imports (relative ones resolved, ``from pkg import mod``
    counted as ``pkg.mod``) and ``importlib.import_module("...")`` / ``__import__("...")`` with a literal."""
    out: list[str] = []
    for node in ast.walk(_tree(path)):
        if isinstance(node, ast.ImportFrom):
            module = _absolute(path, node)
            out += [module, *(f"{module}.{a.name}" for a in node.names)]
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name in ("import_module", "__import__") and isinstance(node.args[0].value, str):
                out.append(node.args[0].value)
    return out


def _other_plugin(module: str, own: str) -> bool:
    parts = module.split(".")
    return parts[:2] == ["weldcell", "plugins"] and len(parts) > 2 and parts[2] not in (own, "__init__")


def test_relative_and_dynamic_imports_stay_inside_their_plugin():
    crossing = [
        f"{f.relative_to(ROOT)} imports {m}"
        for f in sorted(PLUGINS.rglob("*.py"))
        if len(f.relative_to(PLUGINS).parts) > 1
        for m in _imported(f)
        if _other_plugin(m, f.relative_to(PLUGINS).parts[0])
    ]
    assert not crossing, "use a public sdk/hal module instead:\n" + "\n".join(crossing)


def test_the_resolver_sees_a_relative_import_of_another_plugin(tmp_path):
    """The rule above can fail: ``from ..handeye import job`` inside plugins/tactile is caught."""
    node = ast.parse("from ..handeye import job").body[0]
    assert _absolute(PLUGINS / "tactile" / "x.py", node) == "weldcell.plugins.handeye"
    assert _other_plugin("weldcell.plugins.handeye.job", "tactile")
    assert not _other_plugin("weldcell.plugins.tactile.servo", "tactile")
    assert _absolute(
        PLUGINS / "scan_plan" / "seams" / "x.py", ast.parse("from ..cloud_numerics import a").body[0]
    ) == ("weldcell.plugins.scan_plan.cloud_numerics")


def test_the_simulated_world_key_is_written_once():
    """Jobs reach the run's SimWorld through ``weldcell.hal.sim.WORLD_KEY`` / ``world_of``, never a copy of
    the key's text."""
    owner = ROOT / "hal" / "sim" / "__init__.py"
    copies = [
        f"{f.relative_to(ROOT)}:{node.lineno}"
        for layer in ("sdk", "hal", "plugins")
        for f in sorted((ROOT / layer).rglob("*.py"))
        if f != owner
        for node in ast.walk(_tree(f))
        if isinstance(node, ast.Constant) and node.value == "sim.world"
    ]
    assert not copies, "use weldcell.hal.sim.WORLD_KEY:\n" + "\n".join(copies)


def test_real_hardware_does_not_depend_on_the_simulation():
    """The kinematics and robot tables that real robots' safety gates use are hal modules
    (hal.kinematics, hal.robot_models), not simulation: hal outside hal/sim and the hardware plugins
    import nothing from weldcell.hal.sim."""
    files = [
        f for f in sorted((ROOT / "hal").rglob("*.py")) if "sim" not in f.relative_to(ROOT / "hal").parts
    ]
    files += [f for p in HARDWARE_PLUGINS for f in sorted((PLUGINS / p).rglob("*.py"))]
    assert len(files) > len(HARDWARE_PLUGINS)
    bad = [
        f"{f.relative_to(ROOT)} imports {m}"
        for f in files
        for m in _imported(f)
        if m == "weldcell.hal.sim" or m.startswith("weldcell.hal.sim.")
    ]
    assert not bad, "\n".join(bad)
    from weldcell.hal.kinematics import get_model

    assert get_model("ur10e").__module__.startswith("weldcell.hal.kinematics")
