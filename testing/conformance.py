"""Device conformance suites: the behaviour every HAL adapter must show, as pytest test classes.

Use in an adapter's tests by subclassing the suite of its kind and providing a ``device``
fixture that returns a new, unopened device (talking to your protocol peer or fake)::

    from weldcell.testing.conformance import RobotConformance

    class TestMyArm(RobotConformance):
        @pytest.fixture
        def device(self, my_arm_peer):
            return MyArm(MyArmSettings(host=my_arm_peer.host), name="arm")

Optional fixtures: ``break_device(device)`` (a callable that makes the device's connection
fail, so the suite can check the error state and ``recover()``), ``unsafe_target`` for robots.

Robots also inherit a property-based fuzz of the safety gate (:mod:`weldcell.testing.safety_fuzz`):
``fuzz_examples`` random and adversarial commands through the public API, the driver methods spied on
(nothing moves), every accepted command re-checked by an independent dense checker. Set the class
attribute ``fuzz_examples`` (default 30) to run more, or 0 to skip it (say why in your test file).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from weldcell.hal.interfaces import (
    DepthCamera,
    DisplacementSensor,
    GestureSensor,
    Gnss,
    Imu,
    LaserProjector,
    TactileCamera,
)
from weldcell.hal.lifecycle import Device, State
from weldcell.hal.robot import Robot
from weldcell.sdk.errors import DeviceError, SafetyError
from weldcell.testing.conformance_streams import StreamingConformance


class DeviceConformance:
    """Lifecycle, health and reading rules common to every device kind."""

    interface: type[Device] = Device

    @pytest.fixture
    def device(self):  # pragma: no cover - subclasses override
        pytest.skip("provide a `device` fixture returning an unopened device")

    @pytest.fixture
    def break_device(self):
        """Return a callable(device) that breaks the connection; None when the adapter cannot."""
        return None

    def read_once(self, dev):
        """One reading of the device's kind."""
        raise NotImplementedError

    def test_is_the_right_interface(self, device):
        assert isinstance(device, self.interface), (
            f"{type(device).__name__} must subclass {self.interface.__name__}"
        )
        assert device.kind == self.interface.kind

    def test_lifecycle_order(self, device):
        assert device.lifecycle is State.UNCONFIGURED
        with pytest.raises(DeviceError):
            device.activate()  # not configured yet
        device.configure()
        assert device.lifecycle is State.INACTIVE and device.health().ok
        device.activate()
        assert device.lifecycle is State.ACTIVE
        device.deactivate()
        assert device.lifecycle is State.INACTIVE
        device.close()
        assert device.lifecycle is State.FINALIZED
        device.close()  # idempotent

    def test_no_reading_unless_active(self, device):
        device.configure()
        try:
            with pytest.raises(DeviceError):
                self.read_once(device)
        finally:
            device.close()

    def test_context_manager_opens_and_always_closes(self, device):
        with pytest.raises(RuntimeError):
            with device as d:
                assert d.lifecycle is State.ACTIVE
                raise RuntimeError("boom")
        assert device.lifecycle is State.FINALIZED

    def test_readings_carry_timestamp_and_frame(self, device):
        with device as d:
            t0 = time.time()
            r = self.read_once(d)
            stamp = getattr(r, "stamp", None)
            assert stamp is not None and np.isfinite(stamp), "every reading needs a timestamp"
            assert stamp <= time.time() + 1.0
            assert getattr(r, "frame", None), "every reading names its frame"
            h = d.health()
            assert h.ok and h.last_reading_age is not None and h.last_reading_age <= time.time() - t0 + 1.0

    def test_error_state_and_recovery(self, device, break_device):
        if break_device is None:
            pytest.skip("adapter provides no break_device fixture")
        with device as d:
            self.read_once(d)
            break_device(d)
            with pytest.raises(DeviceError):
                for _ in range(50):
                    self.read_once(d)
            assert d.lifecycle is State.ERROR and not d.health().ok and d.health().message
            d.recover()
            assert d.lifecycle is State.UNCONFIGURED
            d.configure()
            d.activate()
            self.read_once(d)


class RobotConformance(DeviceConformance):
    """Robots: state, moves, servo, stop, and the safety gate in front of the driver."""

    interface = Robot

    @pytest.fixture
    def unsafe_target(self, device):
        """A TCP pose outside the gate's workspace box (override when the default box does not apply)."""
        T = np.eye(4)
        T[:3, 3] = np.asarray(device.gate.hi) + 0.5
        return T

    def read_once(self, dev):
        return dev.state()

    def test_state_is_consistent(self, device):
        with device as d:
            st = d.state()
            assert st.T_base_flange.shape == (4, 4) and np.allclose(st.T_base_flange[3], [0, 0, 0, 1])
            assert np.allclose(st.T_base_tcp, st.T_base_flange @ d.T_flange_tcp)
            assert np.all(np.isfinite(st.q))

    def _spy(self, d, monkeypatch):
        calls = []
        for name in ("_move_linear", "_move_joint", "_follow_path", "_speed_linear"):
            orig = getattr(d, name)

            def spy(*a, _n=name, _o=orig, **k):
                calls.append(_n)
                return _o(*a, **k)

            monkeypatch.setattr(d, name, spy)
        return calls

    def test_unsafe_motion_never_reaches_the_driver(self, device, unsafe_target, monkeypatch):
        with device as d:
            calls = self._spy(d, monkeypatch)
            with pytest.raises(SafetyError):
                d.move_linear(unsafe_target)
            start = d.state().T_base_tcp
            with pytest.raises(SafetyError):
                d.follow_path(np.stack([start, unsafe_target]))
            with pytest.raises(SafetyError):
                d.speed_linear(np.array([10.0, 0, 0, 0, 0, 0]))
            with pytest.raises(SafetyError):
                d.move_linear(start, speed=d.gate.limits.max_linear_speed * 2)
            assert calls == [], f"refused commands reached the driver: {calls}"

    def test_small_safe_linear_move_reaches_target(self, device):
        with device as d:
            start = d.state().T_base_tcp
            target = start.copy()
            target[2, 3] += 0.01
            d.move_linear(target, speed=min(0.05, d.gate.limits.max_linear_speed))
            if not d.dry_run:
                got = d.state().T_base_tcp
                assert np.linalg.norm(got[:3, 3] - target[:3, 3]) < 2e-3

    fuzz_examples = 30
    """Commands the inherited safety fuzz sends (hypothesis, derandomized); more in the adapter's own CI."""

    def test_fuzzed_commands_never_reach_the_driver_unsafe(self, device):
        """Random and adversarial commands (malformed poses, NaN/inf, far targets, bad durations and blends,
        rotation-heavy twists, joint sweeps): nothing unsafe reaches the driver, nothing but SafetyError
        escapes the public methods."""
        if not self.fuzz_examples:
            pytest.skip("fuzz_examples = 0 in this adapter's suite")
        pytest.importorskip("hypothesis")
        from weldcell.testing.safety_fuzz import fuzz_robot

        with device as d:
            report = fuzz_robot(d, self.fuzz_examples)
        assert report.errors == [], f"non-gate exceptions escaped: {report.errors[:3]}"
        assert report.unsafe == [], f"unsafe commands reached the driver: {report.unsafe[:3]}"

    def test_stop_is_always_allowed(self, device):
        with device as d:
            d.stop()


class DepthCameraConformance(DeviceConformance):
    interface = DepthCamera

    def read_once(self, dev):
        return dev.capture()

    def test_frame_matches_intrinsics(self, device):
        with device as d:
            f = d.capture()
            k = d.intrinsics()
            assert f.depth.shape == (k.height, k.width)
            assert f.depth.dtype in (np.float32, np.float64)
            valid = f.depth[f.depth > 0]
            assert valid.size > 0 and np.all(np.isfinite(valid)) and valid.max() < 50.0, (
                "depth must be in metres"
            )
            cloud = f.to_cloud()
            assert len(cloud) == valid.size and cloud.frame == f.frame


class GestureSensorConformance(DeviceConformance):
    interface = GestureSensor

    def read_once(self, dev):
        return dev.read()

    def test_hands_are_in_metres(self, device):
        with device as d:
            for _ in range(20):
                f = d.read()
                for h in f.hands:
                    assert h.side in ("left", "right")
                    assert np.linalg.norm(h.palm_position) < 2.0, "positions must be metres"
                    assert abs(np.linalg.norm(h.palm_normal) - 1.0) < 1e-3


class DisplacementSensorConformance(StreamingConformance, DeviceConformance):
    interface = DisplacementSensor

    def read_once(self, dev):
        return dev.read()


class LaserProjectorConformance(DeviceConformance):
    interface = LaserProjector

    def read_once(self, dev):
        return dev.project(np.array([[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]]))


class TactileCameraConformance(DeviceConformance):
    interface = TactileCamera

    def read_once(self, dev):
        return dev.capture()


class ImuConformance(StreamingConformance, DeviceConformance):
    interface = Imu

    def read_once(self, dev):
        return dev.read()


class GnssConformance(StreamingConformance, DeviceConformance):
    interface = Gnss

    def read_once(self, dev):
        return dev.read()


SUITES = {
    "robot": RobotConformance,
    "depth_camera": DepthCameraConformance,
    "gesture_sensor": GestureSensorConformance,
    "displacement_sensor": DisplacementSensorConformance,
    "laser_projector": LaserProjectorConformance,
    "tactile_camera": TactileCameraConformance,
    "imu": ImuConformance,
    "gnss": GnssConformance,
}
"""Device kind -> conformance suite class."""
