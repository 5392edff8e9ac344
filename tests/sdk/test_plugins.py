"""The plugin manager: fault isolation, strict mode, conflicts, clear errors for unknown names, disabling."""

from __future__ import annotations

import pytest
from weldcell.sdk.descriptors import DeviceSpec, StageSpec
from weldcell.sdk.errors import PluginError, UnknownPluginError
from weldcell.sdk.hookspecs import hookimpl
from weldcell.sdk.plugins import PluginManager
from weldcell.sdk.settings import NoSettings

GROUP = "weldcell_tests_plugins"

GOOD_SOURCE = """
from weldcell.sdk.descriptors import StageSpec
from weldcell.sdk.hookspecs import hookimpl

@hookimpl
def weldcell_register_stages(register):
    register(StageSpec(name="{name}", kind="seam", summary="a good stage"))
"""

BROKEN_IMPORT_SOURCE = 'raise RuntimeError("cannot import: the vendor SDK is missing")\n'

BROKEN_REGISTER_SOURCE = """
from weldcell.sdk.hookspecs import hookimpl

@hookimpl
def weldcell_register_stages(register):
    raise ValueError("registration exploded")
"""


class Provides:
    """A plugin object registering one stage under ``name``."""

    def __init__(self, name: str, kind: str = "seam") -> None:
        self.name, self.kind = name, kind

    @hookimpl
    def weldcell_register_stages(self, register):
        register(StageSpec(name=self.name, kind=self.kind, summary=f"{self.kind} stage {self.name}"))


class RaisesInRegister:
    @hookimpl
    def weldcell_register_stages(self, register):
        raise ValueError("registration exploded")


@pytest.fixture
def three_plugins(make_distribution):
    """A distribution with a good plugin, one that fails to import and one whose hook raises."""
    make_distribution(
        "weldcell-three",
        "2.5",
        modules={
            "wt_good": GOOD_SOURCE.format(name="seam.good-one"),
            "wt_broken": BROKEN_IMPORT_SOURCE,
            "wt_badhook": BROKEN_REGISTER_SOURCE,
        },
        entry_points={GROUP: {"good": "wt_good", "broken": "wt_broken", "badhook": "wt_badhook"}},
    )


# -- fault isolation -----------------------------------------------------------------------------
def test_plugin_failing_to_import_is_reported_and_the_others_load(three_plugins):
    pm = PluginManager(discover=False)
    pm.load_entrypoints(GROUP)
    reg = pm.registry
    assert reg.names("stage") == ["seam.good-one"]
    assert reg.entry("stage", "seam.good-one").provider.distribution == "weldcell-three"
    assert reg.entry("stage", "seam.good-one").provider.version == "2.5"
    load = [f for f in reg.failures if f.stage == "load"]
    assert len(load) == 1
    f = load[0]
    assert f.provider.plugin == "broken"
    assert f.provider.entry_point == "broken = wt_broken"
    assert f.provider.distribution == "weldcell-three" and f.provider.version == "2.5"
    assert f.error == "RuntimeError: cannot import: the vendor SDK is missing"
    assert "Traceback" in f.traceback
    text = str(f)
    for part in (
        "broken",
        "weldcell-three 2.5",
        "broken = wt_broken",
        "failed to load",
        "vendor SDK is missing",
    ):
        assert part in text


def test_plugin_whose_register_hook_raises_is_isolated(three_plugins):
    pm = PluginManager(discover=False)
    pm.load_entrypoints(GROUP)
    reg = pm.registry
    hook = [f for f in reg.failures if f.stage != "load"]
    assert len(hook) == 1
    assert hook[0].provider.plugin == "badhook"
    assert hook[0].provider.distribution == "weldcell-three"
    assert hook[0].stage == "register stages"
    assert hook[0].error == "ValueError: registration exploded"
    assert "badhook" in str(hook[0]) and "failed to register stages" in str(hook[0])
    assert reg.names("stage") == ["seam.good-one"]


def test_register_hook_failure_of_a_hand_registered_plugin_keeps_the_others(weldcell_pm):
    weldcell_pm.register(Provides("seam.fine"), "fine")
    weldcell_pm.register(RaisesInRegister(), "explodes")
    reg = weldcell_pm.registry
    assert reg.names("stage") == ["seam.fine"]
    assert [f.provider.plugin for f in reg.failures] == ["explodes"]


def test_strict_mode_makes_import_failures_fatal(three_plugins):
    pm = PluginManager(discover=False, strict=True)
    with pytest.raises(PluginError) as e:
        pm.load_entrypoints(GROUP)
    assert "broken" in e.value.message and "vendor SDK is missing" in e.value.message
    assert "strict" in e.value.fix


def test_strict_mode_makes_register_failures_fatal(weldcell_pm):
    pm = PluginManager(discover=False, strict=True)
    pm.register(Provides("seam.fine"), "fine")
    pm.register(RaisesInRegister(), "explodes")
    with pytest.raises(PluginError) as e:
        pm.registry  # noqa: B018 - collecting is what raises
    assert "explodes" in e.value.message and "registration exploded" in e.value.message


def test_strict_mode_from_the_environment(three_plugins, monkeypatch):
    monkeypatch.setenv("WELDCELL_STRICT_PLUGINS", "1")
    pm = PluginManager(discover=False)
    assert pm.strict
    with pytest.raises(PluginError, match="broken"):
        pm.load_entrypoints(GROUP)
    pm2 = PluginManager(discover=False)
    pm2.register(RaisesInRegister(), "explodes")
    with pytest.raises(PluginError, match="explodes"):
        pm2.registry  # noqa: B018
    monkeypatch.setenv("WELDCELL_STRICT_PLUGINS", "0")
    assert not PluginManager(discover=False).strict


def test_disable_plugins_skips_the_named_entry_points(three_plugins, monkeypatch):
    monkeypatch.setenv("WELDCELL_DISABLE_PLUGINS", "broken, badhook")
    pm = PluginManager(discover=False)
    pm.load_entrypoints(GROUP)
    assert pm.plugin_names() == ["good"]
    assert pm.registry.failures == []
    assert pm.registry.names("stage") == ["seam.good-one"]


def test_disabling_a_plugin_removes_what_it_registers(make_distribution, monkeypatch):
    make_distribution(
        "weldcell-two",
        "1.0",
        modules={
            "wt_one": GOOD_SOURCE.format(name="seam.one"),
            "wt_two": GOOD_SOURCE.format(name="seam.two"),
        },
        entry_points={GROUP: {"one": "wt_one", "two": "wt_two"}},
    )
    pm = PluginManager(discover=False)
    pm.load_entrypoints(GROUP)
    assert pm.registry.names("stage") == ["seam.one", "seam.two"]
    monkeypatch.setenv("WELDCELL_DISABLE_PLUGINS", "two")
    pm = PluginManager(discover=False)
    pm.load_entrypoints(GROUP)
    assert pm.registry.names("stage") == ["seam.one"]
    with pytest.raises(UnknownPluginError):
        pm.registry.get("stage", "seam.two")


# -- names -------------------------------------------------------------------------------------
@pytest.mark.parametrize("order", [("alpha", "beta"), ("beta", "alpha")])
def test_conflict_names_both_providers_whatever_the_order(weldcell_pm, order):
    for plugin in order:
        weldcell_pm.register(Provides("seam.shared"), plugin, distribution=f"{plugin}-dist")
    weldcell_pm.register(Provides("seam.unique"), "gamma")
    reg = weldcell_pm.registry
    assert ("stage", "seam.shared") in reg.conflicts
    assert "seam.shared" not in reg.names("stage")
    assert reg.names("stage") == ["seam.unique"]  # the conflict does not hide the others
    with pytest.raises(PluginError) as e:
        reg.get("stage", "seam.shared")
    msg = e.value.message
    assert "seam.shared" in msg
    assert "plugin 'alpha'" in msg and "plugin 'beta'" in msg
    assert "WELDCELL_DISABLE_PLUGINS" in e.value.fix


def test_unknown_name_lists_available_and_suggests_close_match(weldcell_pm):
    weldcell_pm.register(Provides("seam.edge-intensity"), "edges")
    weldcell_pm.register(Provides("path.torch-frames", kind="path"), "paths")
    with pytest.raises(UnknownPluginError) as e:
        weldcell_pm.registry.get("stage", "seam.edge-intensty")
    msg = e.value.message
    assert "no stage named 'seam.edge-intensty'" in msg
    assert "did you mean 'seam.edge-intensity'" in msg
    assert "available stages: path.torch-frames, seam.edge-intensity" in msg
    assert "weldcell plugins" in e.value.fix


def test_unknown_name_without_close_match_still_lists_names(weldcell_pm):
    weldcell_pm.register(Provides("seam.edge-intensity"), "edges")
    with pytest.raises(UnknownPluginError) as e:
        weldcell_pm.registry.get("stage", "zzz.qqq")
    assert "did you mean" not in e.value.message
    assert "seam.edge-intensity" in e.value.message


def test_unknown_name_points_at_plugins_that_failed_to_load(three_plugins):
    pm = PluginManager(discover=False)
    pm.load_entrypoints(GROUP)
    with pytest.raises(UnknownPluginError) as e:
        pm.registry.get("stage", "seam.from-broken")
    assert "broken" in e.value.fix and "failed to load" in e.value.fix


def test_wrong_kind_says_what_kind_it_is(weldcell_pm):
    weldcell_pm.register(Provides("seam.edge-intensity"), "edges")
    weldcell_pm.register(Provides("path.torch-frames", kind="path"), "paths")
    with pytest.raises(PluginError) as e:
        weldcell_pm.registry.get("stage", "seam.edge-intensity", kind="path")
    assert "stage 'seam.edge-intensity' is a seam, not a path" in e.value.message
    assert "path.torch-frames" in e.value.fix


def test_register_plugin_leaves_nothing_behind(weldcell_pm, register_plugin):
    with register_plugin(Provides("seam.temporary"), "temporary") as name:
        assert name == "temporary"
        assert "temporary" in weldcell_pm.plugin_names()
        assert weldcell_pm.registry.get("stage", "seam.temporary").kind == "seam"
    assert "temporary" not in weldcell_pm.plugin_names()
    assert "temporary" not in weldcell_pm.providers
    assert weldcell_pm.registry.names("stage") == []
    with pytest.raises(UnknownPluginError):
        weldcell_pm.registry.get("stage", "seam.temporary")
    # the same name can be registered again afterwards
    with register_plugin(Provides("seam.temporary"), "temporary"):
        assert weldcell_pm.registry.names("stage") == ["seam.temporary"]


def test_register_plugin_unregisters_even_when_the_block_raises(weldcell_pm, register_plugin):
    with pytest.raises(KeyError):
        with register_plugin(Provides("seam.temporary"), "temporary"):
            raise KeyError("boom")
    assert weldcell_pm.plugin_names() == []


# -- descriptors -------------------------------------------------------------------------------
def test_registering_the_wrong_descriptor_type_is_a_failure_of_that_plugin(weldcell_pm):
    class WrongType:
        @hookimpl
        def weldcell_register_stages(self, register):
            register(DeviceSpec(name="robot.oops", kind="robot", summary="not a stage"))

    weldcell_pm.register(WrongType(), "wrongtype")
    weldcell_pm.register(Provides("seam.fine"), "fine")
    reg = weldcell_pm.registry
    assert reg.names("stage") == ["seam.fine"]
    assert "expected StageSpec" in reg.failures[0].error and reg.failures[0].provider.plugin == "wrongtype"


@pytest.mark.parametrize("bad", ["EdgeSeam", "seam", "seam.Edge", "seam..x", "1seam.x"])
def test_descriptor_names_must_be_dotted_lower_case(bad):
    with pytest.raises(PluginError, match="dotted lower-case"):
        StageSpec(name=bad, kind="seam", summary="")


def test_descriptor_settings_must_be_a_settings_model():
    with pytest.raises(PluginError, match="Settings subclass"):
        StageSpec(name="seam.x", kind="seam", summary="", settings=dict)  # type: ignore[arg-type]


def test_device_kind_must_be_a_hal_kind():
    with pytest.raises(PluginError) as e:
        DeviceSpec(name="robot.x", kind="robto", summary="")
    assert "robto" in e.value.message and "robot" in e.value.fix


def test_missing_extra_names_the_extra():
    spec = DeviceSpec(
        name="robot.needs-extra",
        kind="robot",
        summary="",
        settings=NoSettings,
        requires={"not_a_real_module_xyz": "foo", "json": "stdlib"},
    )
    assert spec.missing_extras() == [("not_a_real_module_xyz", "foo")]
    with pytest.raises(PluginError) as e:
        spec.check_available()
    assert "not_a_real_module_xyz" in e.value.message and e.value.fix == "pip install 'weldcell[foo]'"


def test_installed_first_party_plugins_load_without_failures():
    """Every entry point of the weldcell distribution itself loads (a broken first-party plugin is a bug)."""
    pm = PluginManager(discover=True)
    ours = [f for f in pm.registry.failures if f.provider.distribution == "weldcell"]
    assert ours == [], "\n".join(str(f) for f in ours)
    assert {"robot.sim", "camera.sim", "gesture.sim"} <= set(pm.registry.names("device"))
    assert pm.providers["sim"].distribution == "weldcell"
