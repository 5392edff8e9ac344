"""The HAL device lifecycle: transitions and refusals, the error state, recovery, closing, health."""

from __future__ import annotations

import time

import pytest
from weldcell.hal.interfaces import DisplacementSensor
from weldcell.hal.lifecycle import Device, State
from weldcell.hal.readings import Displacement
from weldcell.sdk.errors import DeviceError, WeldcellError


class Recorder(DisplacementSensor):
    """A displacement sensor that records its hook calls and can be told to fail in any hook."""

    def __init__(self, fail: dict[str, Exception] | None = None) -> None:
        super().__init__("laser1")
        self.calls: list[str] = []
        self.fail = dict(fail or {})
        self.link_ok = True

    def _hook(self, name: str) -> None:
        self.calls.append(name)
        if name in self.fail:
            raise self.fail.pop(name)

    def on_configure(self) -> None:
        self._hook("configure")

    def on_activate(self) -> None:
        self._hook("activate")

    def on_deactivate(self) -> None:
        self._hook("deactivate")

    def on_close(self) -> None:
        self._hook("close")

    def on_recover(self) -> None:
        self._hook("recover")
        self.link_ok = True

    def _read(self, timeout: float) -> Displacement:
        if not self.link_ok:
            raise self.fault("serial link lost")
        return Displacement(time.time(), 0.1, self.frame)


def test_full_lifecycle_calls_each_hook_once():
    d = Recorder()
    assert d.lifecycle is State.UNCONFIGURED
    d.configure()
    assert d.lifecycle is State.INACTIVE
    d.activate()
    assert d.lifecycle is State.ACTIVE
    assert d.read().distance == 0.1
    d.deactivate()
    assert d.lifecycle is State.INACTIVE
    d.close()
    assert d.lifecycle is State.FINALIZED
    d.close()
    assert d.calls == ["configure", "activate", "deactivate", "close"]


def test_activate_before_configure_is_refused_and_changes_nothing():
    d = Recorder()
    with pytest.raises(DeviceError) as e:
        d.activate()
    assert e.value.message == "displacement_sensor 'laser1' cannot activate while unconfigured"
    assert "configure() -> activate()" in e.value.fix
    assert d.lifecycle is State.UNCONFIGURED and d.calls == []


@pytest.mark.parametrize("verb", ["configure", "activate", "deactivate"])
def test_transitions_from_the_wrong_state_are_refused(verb):
    d = Recorder()
    d.configure()
    d.activate()
    if verb == "deactivate":
        d.deactivate()  # now INACTIVE: deactivating again is wrong
    with pytest.raises(DeviceError, match=f"cannot {verb} while"):
        getattr(d, verb)()


def test_no_reading_unless_active():
    d = Recorder()
    with pytest.raises(DeviceError) as e:
        d.read()
    assert e.value.message == "displacement_sensor 'laser1' is unconfigured, not active"
    d.configure()
    with pytest.raises(DeviceError, match="is inactive, not active"):
        d.read()
    d.activate()
    d.read()
    d.deactivate()
    with pytest.raises(DeviceError, match="is inactive, not active"):
        d.read()


def test_failing_hook_puts_the_device_in_error_with_the_reason():
    d = Recorder(fail={"configure": OSError("no route to host 10.0.0.5")})
    with pytest.raises(DeviceError) as e:
        d.configure()
    assert isinstance(e.value.__cause__, OSError)
    assert "configure failed: no route to host 10.0.0.5" in e.value.message
    assert d.lifecycle is State.ERROR
    h = d.health()
    assert not h.ok and h.state is State.ERROR and "no route to host" in h.message
    with pytest.raises(DeviceError) as e2:
        d.activate()
    assert "cannot activate while error" in e2.value.message and "recover()" in e2.value.fix


def test_weldcell_error_from_a_hook_is_kept_as_is():
    err = DeviceError("controller in protective stop", "release it on the pendant")
    d = Recorder(fail={"activate": err})
    d.configure()
    with pytest.raises(DeviceError) as e:
        d.activate()
    assert e.value is err
    assert (
        d.lifecycle is State.ERROR and d.health().message == "activate failed: controller in protective stop"
    )


def test_fault_and_recover():
    d = Recorder()
    d.configure()
    d.activate()
    d.read()
    d.link_ok = False
    with pytest.raises(DeviceError) as e:
        d.read()
    assert e.value.message == "displacement_sensor 'laser1': serial link lost"
    assert "recover()" in e.value.fix
    assert d.lifecycle is State.ERROR and d.health().message == "serial link lost" and not d.health().ok
    with pytest.raises(DeviceError) as e:
        d.read()  # every reading now says why
    assert "is error, not active (serial link lost)" in e.value.message
    d.recover()
    assert d.lifecycle is State.UNCONFIGURED and d.health().message == "" and "recover" in d.calls
    d.configure()
    d.activate()
    assert d.read().valid


def test_fault_returns_the_error_to_raise():
    d = Device("thing")
    err = d.fault("overheated")
    assert isinstance(err, DeviceError) and isinstance(err, WeldcellError)
    assert err.message == "device 'thing': overheated" and d.lifecycle is State.ERROR


def test_recover_outside_error_does_nothing():
    d = Recorder()
    d.recover()
    assert d.lifecycle is State.UNCONFIGURED and d.calls == []
    d.configure()
    d.recover()
    assert d.lifecycle is State.INACTIVE and d.calls == ["configure"]


def test_failed_recover_stays_in_error():
    d = Recorder(fail={"recover": OSError("still unplugged")})
    d.configure()
    d.fault("cable pulled")
    with pytest.raises(DeviceError, match="recover failed: still unplugged"):
        d.recover()
    assert d.lifecycle is State.ERROR and "still unplugged" in d.health().message
    d.recover()  # works once the cable is back
    assert d.lifecycle is State.UNCONFIGURED


def test_default_recover_closes_the_connection():
    class Plain(Recorder):
        on_recover = Device.on_recover

    d = Plain()
    d.configure()
    d.fault("x")
    d.recover()
    assert d.calls == ["configure", "close"]


def test_close_from_active_deactivates_first_and_is_final():
    d = Recorder()
    d.configure()
    d.activate()
    d.close()
    assert d.calls == ["configure", "activate", "deactivate", "close"]
    with pytest.raises(DeviceError) as e:
        d.configure()
    assert "cannot configure while finalized" in e.value.message and "create a new one" in e.value.fix


def test_close_still_closes_when_deactivate_raises():
    d = Recorder(fail={"deactivate": OSError("socket reset")})
    d.configure()
    d.activate()
    with pytest.raises(OSError):
        d.close()
    assert d.calls[-1] == "close" and d.lifecycle is State.FINALIZED


def test_close_from_error_state():
    d = Recorder()
    d.configure()
    d.fault("x")
    d.close()
    assert d.lifecycle is State.FINALIZED and d.calls == ["configure", "close"]


def test_context_manager_opens_and_closes_on_exception():
    d = Recorder()
    with pytest.raises(ZeroDivisionError):
        with d as opened:
            assert opened is d and d.lifecycle is State.ACTIVE
            1 / 0  # noqa: B018
    assert d.lifecycle is State.FINALIZED
    assert d.calls == ["configure", "activate", "deactivate", "close"]


def test_context_manager_releases_the_connection_when_activation_fails():
    """A device whose activate() fails inside ``with`` was already connected: it must still be closed."""
    d = Recorder(fail={"activate": OSError("robot in protective stop")})
    with pytest.raises(DeviceError, match="protective stop"):
        with d:
            pytest.fail("the body must not run")
    assert d.calls == ["configure", "activate", "close"]
    assert d.lifecycle is State.FINALIZED
    assert "activate failed" in d.health().message  # the reason is kept for the operator


def test_health_reports_the_age_of_the_last_reading():
    d = Recorder()
    assert d.health().last_reading_age is None
    d.configure()
    d.activate()
    h = d.health()
    assert h.ok and h.state is State.ACTIVE and h.last_reading_age is None
    d.read()
    assert 0.0 <= d.health().last_reading_age < 1.0
    d.mark_reading(time.time() - 5.0)
    assert d.health().last_reading_age == pytest.approx(5.0, abs=0.5)
    d.mark_reading(time.time() + 10.0)  # a device clock ahead of ours never gives a negative age
    assert d.health().last_reading_age == 0.0


def test_reading_stamps_health():
    d = Recorder()
    with d:
        before = time.time()
        r = d.read()
        assert r.stamp >= before - 1e-3 and r.frame == "laser1"
        assert d.health().last_reading_age <= time.time() - before + 1e-3


def test_repr_names_kind_and_state():
    d = Recorder()
    assert repr(d) == "<Recorder 'laser1' unconfigured>"
