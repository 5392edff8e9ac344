"""RobotConformance as it is meant to run, for robots.

``hal.robot.Robot.state()`` (the robot-state reading) shadows ``Device.state`` (the lifecycle property), so
``RobotConformance``'s lifecycle checks (``device.lifecycle is State.X``) cannot pass for any robot. Until that is
resolved in the shared files, this subclass runs the same three checks against the lifecycle state
(``device._state``); every other check is the suite's own.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from weldcell.hal.lifecycle import State
from weldcell.sdk.errors import DeviceError
from weldcell.testing.conformance import RobotConformance


def lifecycle(dev) -> State:
    s = dev.state
    return s if isinstance(s, State) else dev._state  # noqa: SLF001


class RobotConformanceFixed(RobotConformance):
    def test_lifecycle_order(self, device):
        assert lifecycle(device) is State.UNCONFIGURED
        with pytest.raises(DeviceError):
            device.activate()
        device.configure()
        assert lifecycle(device) is State.INACTIVE and device.health().ok
        device.activate()
        assert lifecycle(device) is State.ACTIVE
        device.deactivate()
        assert lifecycle(device) is State.INACTIVE
        device.close()
        assert lifecycle(device) is State.FINALIZED
        device.close()

    def test_context_manager_opens_and_always_closes(self, device):
        with pytest.raises(RuntimeError):
            with device as d:
                assert lifecycle(d) is State.ACTIVE
                raise RuntimeError("boom")
        assert lifecycle(device) is State.FINALIZED

    def test_error_state_and_recovery(self, device, break_device):
        if break_device is None:
            pytest.skip("adapter provides no break_device fixture")
        with device as d:
            self.read_once(d)
            break_device(d)
            with pytest.raises(DeviceError):
                for _ in range(50):
                    self.read_once(d)
            assert lifecycle(d) is State.ERROR and not d.health().ok and d.health().message
            d.recover()
            assert lifecycle(d) is State.UNCONFIGURED
            d.configure()
            d.activate()
            st = self.read_once(d)
            assert np.all(np.isfinite(st.q)) and st.stamp <= time.time() + 1
