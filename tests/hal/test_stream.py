"""The HAL's buffered reading stream (weldcell.hal.stream) on scripted devices."""

from __future__ import annotations

import queue
import threading
import time

import numpy as np
import pytest
from weldcell.hal.interfaces import DisplacementSensor, Gnss, Imu
from weldcell.hal.lifecycle import State
from weldcell.hal.readings import Displacement, ImuReading
from weldcell.hal.stream import backdate
from weldcell.sdk.errors import DeviceError, UsageError
from weldcell.testing.conformance import DisplacementSensorConformance, ImuConformance


class ScriptedLaser(DisplacementSensor):
    """Delivers values put into ``feed`` (a burst per item); an Exception item is a failure."""

    stream_read_timeout = 0.05

    def __init__(self) -> None:
        super().__init__("laser")
        self.feed: queue.Queue = queue.Queue()
        self.n = 0

    def _read_burst(self, timeout: float) -> list:
        try:
            item = self.feed.get(timeout=timeout)
        except queue.Empty:
            return []
        if isinstance(item, Exception):
            raise item
        out = []
        t = time.time()
        for k, v in enumerate(item):
            out.append(Displacement(t, v, "laser", device_stamp=float(self.n + k)))
        self.n += len(item)
        return out

    def _read(self, timeout: float) -> Displacement:
        b = self._read_burst(timeout)
        if not b:
            raise self.fault("silent")
        return b[0]


class CountingImu(Imu):
    """An IMU whose ``_read`` returns at once (like a simulated one); paced by ``stream_rate_hz``."""

    def __init__(self, rate: float | None = None) -> None:
        super().__init__("imu")
        self.stream_rate_hz = rate
        self.i = 0
        self.broken = False

    def on_recover(self) -> None:
        self.broken = False

    def _read(self, timeout: float) -> ImuReading:
        if self.broken:
            raise self.fault("device reports readiness to read but returned no data")
        self.i += 1
        return ImuReading(time.time(), np.zeros(3), np.zeros(3), frame="imu", device_stamp=float(self.i))


def collect(dev, n: int, wait: float = 3.0) -> list:
    out: list = []
    deadline = time.monotonic() + wait
    while len(out) < n and time.monotonic() < deadline:
        out += dev.read_available(timeout=0.05)
    return out


def test_bursts_arrive_in_order_exactly_once():
    with ScriptedLaser() as d:
        d.start_stream()
        for k in range(50):
            d.feed.put([k * 0.001 + 0.001 * j / 10 for j in range(10)])
        got = collect(d, 500)
        assert [r.device_stamp for r in got] == [float(i) for i in range(500)]
        assert d.stop_stream() == []
        st = d.stream_status()
        assert (st.received, st.delivered, st.overruns, st.errors, st.running) == (500, 500, 0, 0, False)
        assert st.last_stamp == got[-1].stamp


def test_out_of_range_values_stay_none_in_the_stream():
    with ScriptedLaser() as d:
        d.start_stream()
        d.feed.put([0.1, None, 0.2])
        got = collect(d, 3)
        assert [r.distance for r in got] == [0.1, None, 0.2]
        d.stop_stream()


def test_overrun_drops_the_oldest_and_counts():
    with ScriptedLaser() as d:
        d.start_stream(capacity=100)
        d.feed.put(list(range(250)))
        assert_until(lambda: d.stream_status().received == 250)
        got = d.read_available()
        st = d.stream_status()
        assert [r.distance for r in got] == list(range(150, 250))
        assert st.overruns == 150 and st.delivered == 100
        d.stop_stream()
    with pytest.raises(UsageError):
        ScriptedLaser().start_stream(capacity=0)


def assert_until(cond, wait: float = 3.0) -> None:
    deadline = time.monotonic() + wait
    while not cond():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.002)


def test_failure_keeps_readings_then_raises_and_faults():
    d = ScriptedLaser()
    d.configure()
    d.activate()
    d.start_stream()
    d.feed.put([0.1, 0.2, 0.3])
    d.feed.put(DeviceError("serial port failed; the device may have been unplugged", "plug it in"))
    assert_until(lambda: not d.stream_status().running)
    assert d.lifecycle is State.ERROR and "unplugged" in d.health().message
    st = d.stream_status()
    assert st.errors == 1 and "unplugged" in st.last_error and st.buffered == 3
    assert [r.distance for r in d.read_available()] == [0.1, 0.2, 0.3]
    with pytest.raises(DeviceError) as e:
        d.read_available()
    assert "unplugged" in e.value.message and e.value.fix == "plug it in"
    with pytest.raises(DeviceError):
        d.read_available()  # keeps saying so
    assert d.stop_stream() == []
    d.recover()
    d.configure()
    d.activate()
    d.start_stream()
    d.feed.put([0.4])
    assert [r.distance for r in collect(d, 1)] == [0.4]
    d.close()


def test_stop_stream_returns_rest_even_after_failure_and_start_refuses_to_drop_it():
    d = ScriptedLaser()
    d.configure()
    d.activate()
    d.start_stream()
    d.feed.put([1.0, 2.0])
    d.feed.put(RuntimeError("boom"))
    assert_until(lambda: not d.stream_status().running)
    d.recover()
    d.configure()
    d.activate()
    with pytest.raises(DeviceError, match="holds 2 readings"):
        d.start_stream()  # would drop what the failed stream captured
    assert [r.distance for r in d.stop_stream()] == [1.0, 2.0]
    d.start_stream()
    d.close()


def test_close_stops_reader_and_keeps_buffer():
    d = ScriptedLaser()
    d.configure()
    d.activate()
    d.start_stream()
    d.feed.put([0.5, 0.6])
    assert_until(lambda: d.stream_status().received == 2)
    d.close()
    assert d.lifecycle is State.FINALIZED and not d.stream_status().running
    assert [r.distance for r in d.read_available()] == [0.5, 0.6]
    with pytest.raises(DeviceError, match="stopped"):
        d.read_available()


def test_rate_pacing_and_concurrent_consumers_never_duplicate():
    d = CountingImu(rate=400.0)
    with d:
        d.start_stream()
        seen: list = []
        lock = threading.Lock()

        def consume():
            end = time.monotonic() + 0.5
            while time.monotonic() < end:
                got = d.read_available(timeout=0.01)
                with lock:
                    seen.extend(r.device_stamp for r in got)

        threads = [threading.Thread(target=consume) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        rest = d.stop_stream()
        all_ = sorted(seen + [r.device_stamp for r in rest])
        assert all_ == [float(i) for i in range(1, len(all_) + 1)], "each reading once, none lost"
        # paced at 400 Hz for ~0.5 s: far fewer than an unpaced loop would make, near 200
        assert 100 <= len(all_) <= 260


def test_health_and_read_refusal_while_streaming():
    with CountingImu(rate=200.0) as d:
        d.start_stream()
        assert collect(d, 3)
        assert d.health().last_reading_age < 1.0
        with pytest.raises(DeviceError, match="streaming"):
            d.read()
        d.stop_stream()
        assert d.read().device_stamp is not None


def test_gnss_uses_a_longer_reader_timeout():
    assert Gnss.stream_read_timeout >= 1.0 > Imu.stream_read_timeout - 0.5


def test_backdate_spreads_a_burst_over_the_sample_period():
    t = backdate(4, 10.0, 0.001)
    np.testing.assert_allclose(t, [9.997, 9.998, 9.999, 10.0])
    assert backdate(0, 1.0, 0.1).size == 0
    # a burst arriving early after the previous one never goes back in time
    np.testing.assert_allclose(backdate(3, 10.0015, 0.001, after=9.9995), [10.0005, 10.0015, 10.0015])


class TestScriptedImuConformance(ImuConformance):
    """The stream conformance mixin run on a paced device that can be broken."""

    @pytest.fixture
    def device(self):
        return CountingImu(rate=500.0)

    @pytest.fixture
    def break_device(self):
        def brk(dev):
            dev.broken = True

        return brk


class TestScriptedLaserConformance(DisplacementSensorConformance):
    """The suite on a burst device fed continuously from a thread."""

    @pytest.fixture
    def device(self):
        d = ScriptedLaser()
        stop = threading.Event()

        def feeder():
            while not stop.is_set():
                d.feed.put([0.1] * 5)
                time.sleep(0.002)

        t = threading.Thread(target=feeder, daemon=True)
        t.start()
        yield d
        stop.set()
        t.join()
