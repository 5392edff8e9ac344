"""A plugin's lazily imported adapter: a missing vendor package names the extra to install."""

from __future__ import annotations

import pytest
from weldcell.sdk.descriptors import import_adapter
from weldcell.sdk.errors import MissingExtraError


def test_missing_vendor_package_names_the_extra(tmp_path, monkeypatch):
    (tmp_path / "demo_adapter_mod.py").write_text("import not_a_vendor_lib_xyz\n")
    (tmp_path / "demo_broken_mod.py").write_text("import not_listed_lib_abc\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(MissingExtraError) as e:
        import_adapter("demo_adapter_mod", {"not_a_vendor_lib_xyz": "demo"}, "device 'robot.demo'")
    assert "device 'robot.demo' needs the Python package 'not_a_vendor_lib_xyz'" in e.value.message
    assert e.value.fix == "pip install 'weldcell[demo]'"
    with pytest.raises(ModuleNotFoundError, match="not_listed_lib_abc"):  # not a vendor package: a real bug
        import_adapter("demo_broken_mod", {"not_a_vendor_lib_xyz": "demo"}, "device 'robot.demo'")
    with pytest.raises(MissingExtraError) as e:
        import_adapter("demo_adapter_mod", {"not_a_vendor_lib_xyz": "hw"}, "device 'robot.demo'", "my-dist")
    assert e.value.fix == "pip install 'my-dist[hw]'"
    assert import_adapter("json", {}, "x").dumps([1]) == "[1]"
