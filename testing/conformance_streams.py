"""Conformance of the buffered reading stream (:mod:`weldcell.hal.stream`) for the streaming kinds.

Mixed into ``DisplacementSensorConformance``, ``ImuConformance`` and ``GnssConformance``, so every
adapter of those kinds runs it. It uses the suite's ``device`` and ``break_device`` fixtures.
Class attributes to tune for a slow device: ``stream_wait`` (longest wait for readings, s) and
``stream_min_readings`` (how many readings the tests wait for).
"""

from __future__ import annotations

import math
import time

import pytest
from weldcell.hal.lifecycle import State
from weldcell.sdk.errors import DeviceError


def collect(dev, n: int, wait: float) -> list:
    """Read the stream until ``n`` readings arrived or ``wait`` seconds passed."""
    out: list = []
    deadline = time.monotonic() + wait
    while len(out) < n and time.monotonic() < deadline:
        out += dev.read_available(timeout=0.05)
    return out


def wait_until(cond, wait: float) -> bool:
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.005)
    return cond()


class StreamingConformance:
    """Stream rules: lifecycle, order, counters, overruns, stop/close, and a failure mid-stream."""

    stream_wait: float = 5.0
    stream_min_readings: int = 5

    def test_stream_requires_active_device(self, device):
        device.configure()
        try:
            with pytest.raises(DeviceError):
                device.start_stream()
            with pytest.raises(DeviceError):
                device.read_available()  # nothing was started
            assert device.stop_stream() == []
        finally:
            device.close()

    def test_stream_delivers_readings_in_order_once(self, device):
        with device as d:
            d.start_stream()
            with pytest.raises(DeviceError):
                d.start_stream()  # one stream at a time
            with pytest.raises(DeviceError):
                d.read()  # read() would steal the stream's readings
            got = collect(d, self.stream_min_readings, self.stream_wait)
            rest = d.stop_stream()
            st = d.stream_status()
            readings = got + rest
            assert len(got) >= self.stream_min_readings, f"stream delivered {len(got)} readings"
            assert not st.running and st.errors == 0 and st.overruns == 0
            assert st.received == st.delivered == len(readings) and st.buffered == 0
            stamps = [r.stamp for r in readings]
            assert all(math.isfinite(s) for s in stamps), "every reading needs a finite stamp"
            assert all(b >= a for a, b in zip(stamps, stamps[1:], strict=False)), "stamps must not go back"
            assert all(getattr(r, "frame", None) for r in readings), "every reading names its frame"
            assert st.last_stamp == stamps[-1]
            assert d.health().last_reading_age is not None
            with pytest.raises(DeviceError):
                d.read_available()  # stopped and empty: say so instead of returning [] forever
            d.read()  # after stop_stream the device reads one value per call again

    def test_stream_restarts(self, device):
        with device as d:
            d.start_stream()
            assert collect(d, 1, self.stream_wait)
            d.stop_stream()
            d.start_stream()
            assert collect(d, 1, self.stream_wait), "a second stream must deliver too"
            d.stop_stream()

    def test_full_buffer_counts_overruns(self, device):
        with device as d:
            d.start_stream(capacity=2)
            assert wait_until(lambda: d.stream_status().received >= 5, self.stream_wait), (
                "the stream received fewer than 5 readings"
            )
            rest = d.stop_stream()
            st = d.stream_status()
            assert len(rest) <= 2
            assert st.overruns == st.received - st.delivered > 0, "dropped readings must be counted"

    def test_close_stops_the_stream_and_keeps_its_readings(self, device):
        d = device
        d.configure()
        d.activate()
        d.start_stream()
        assert wait_until(lambda: d.stream_status().received >= 1, self.stream_wait)
        d.close()
        st = d.stream_status()
        assert not st.running and d.lifecycle is State.FINALIZED
        rest = d.stop_stream()
        assert len(rest) == st.buffered and st.received == st.delivered + st.overruns + st.buffered

    def test_deactivate_stops_the_stream(self, device):
        with device as d:
            d.start_stream()
            d.deactivate()
            assert not d.stream_status().running
            d.stop_stream()

    def test_stream_failure_keeps_readings_then_raises(self, device, break_device):
        if break_device is None:
            pytest.skip("adapter provides no break_device fixture")
        with device as d:
            d.start_stream()
            assert wait_until(lambda: d.stream_status().received >= 1, self.stream_wait)
            break_device(d)
            assert wait_until(lambda: not d.stream_status().running, self.stream_wait + 3.0), (
                "a broken device must stop the stream"
            )
            st = d.stream_status()
            assert st.errors == 1 and st.last_error
            assert d.lifecycle is State.ERROR and not d.health().ok
            got = []
            with pytest.raises(DeviceError):
                for _ in range(3):
                    got += d.read_available()
            assert len(got) == st.buffered, "readings received before the failure must stay readable"
            d.recover()
            d.configure()
            d.activate()
            d.start_stream()
            assert collect(d, 1, self.stream_wait), "the stream must work again after recover()"
            d.stop_stream()
