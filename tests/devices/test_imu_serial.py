"""Serial IMU adapter against pseudo-terminal peers speaking the HFI-A9 and WitMotion protocols."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from weldcell.hal.lifecycle import State
from weldcell.plugins.imu_serial import protocol as p
from weldcell.plugins.imu_serial.adapter import SerialImu
from weldcell.plugins.imu_serial.settings import ImuSerialSettings
from weldcell.sdk.errors import DeviceError
from weldcell.testing.conformance import ImuConformance

from tests.devices.peers_imu_serial import G, ImuPeer


@pytest.fixture(params=["hfi-a9", "witmotion"])
def peer(request):
    pe = ImuPeer(protocol=request.param).start()
    yield pe
    pe.close()


def make(peer, **kw) -> SerialImu:
    base = dict(port=peer.path, protocol=peer.protocol, rate_hz=peer.rate, open_timeout=1.5)
    base["silence_timeout"] = 0.5
    s = ImuSerialSettings(**{**base, **kw})
    return SerialImu(s, name="imu")


def collect(dev, n, wait=3.0):
    out = []
    deadline = time.monotonic() + wait
    while len(out) < n and time.monotonic() < deadline:
        out += dev.read_available(timeout=0.05)
    return out


class TestSerialImuConformance(ImuConformance):
    @pytest.fixture
    def device(self, peer):
        return make(peer)

    @pytest.fixture
    def break_device(self, peer):
        return lambda dev: peer.mute()


def test_crc16_modbus_reference_value():
    assert p.crc16_modbus(b"123456789") == 0x4B37  # the CRC-16/MODBUS check value


def test_stream_has_every_sample_with_the_right_values(peer):
    with make(peer) as dev:
        dev.start_stream()
        got = collect(dev, 200)
        dev.stop_stream()
        assert dev.bad_checksum == 0
    assert len(got) >= 200
    acc = np.array([r.accel for r in got])
    gyr = np.array([r.gyro for r in got])
    np.testing.assert_allclose(acc, np.tile([0, 0, G], (len(got), 1)), atol=0.01)  # m/s^2, specific force
    np.testing.assert_allclose(gyr, np.tile([0, 0, 0.5], (len(got), 1)), atol=2e-3)  # rad/s
    yaw = np.array([Rotation.from_quat(r.orientation).as_euler("xyz")[2] for r in got[5:]])
    dyaw = np.diff(np.unwrap(yaw))
    assert np.median(dyaw) == pytest.approx(0.5 / peer.rate, rel=0.05), "one reading per sample, in order"
    t = np.array([r.stamp for r in got])
    assert np.all(np.diff(t) >= 0)
    if peer.protocol == "witmotion":
        assert got[0].device_stamp is not None and got[0].mag is not None


def test_corrupted_frames_are_skipped_counted_and_the_stream_resynchronises(peer):
    peer.corrupt_every = 7
    with make(peer) as dev:
        dev.start_stream()
        got = collect(dev, 150)
        dev.stop_stream()
        bad = dev.bad_checksum
    assert bad > 0 and bad <= peer.corrupted
    gyr = np.array([r.gyro for r in got])
    np.testing.assert_allclose(gyr[:, 2], 0.5, atol=2e-3)  # nothing corrupted got through
    assert len(got) >= 100


def test_pulled_cable_keeps_received_readings(peer):
    with make(peer) as dev:
        dev.start_stream()
        first = collect(dev, 100)
        peer.pull()
        deadline = time.monotonic() + 3
        while dev.stream_status().running and time.monotonic() < deadline:
            time.sleep(0.01)
        st = dev.stream_status()
        assert "cable" in st.last_error and dev.lifecycle is State.ERROR
        rest = []
        with pytest.raises(DeviceError):
            while True:
                rest += dev.read_available()
    assert len(first) + len(rest) == st.received


def test_wrong_baud_rate_is_reported(peer):
    peer.garbage = True
    with pytest.raises(DeviceError) as e:
        make(peer, open_timeout=0.3).configure()
    assert "without one valid" in e.value.message and "baud" in e.value.fix


def test_silent_imu_is_reported(peer):
    peer.silent = True
    with pytest.raises(DeviceError) as e:
        make(peer, open_timeout=0.3).configure()
    assert "silent" in e.value.message


def test_missing_port_is_reported(tmp_path):
    with pytest.raises(DeviceError) as e:
        SerialImu(ImuSerialSettings(port=str(tmp_path / "ttyIMU"))).configure()
    assert "ttyIMU" in e.value.message and e.value.fix


def test_registered_with_the_serial_extra():
    from weldcell.plugins import imu_serial

    specs = []
    imu_serial.weldcell_register_devices(specs.append)
    (spec,) = specs
    assert spec.name == "imu.serial" and spec.kind == "imu" and spec.requires == {"serial": "serial"}


def test_probe_measures_the_rate(peer):
    from weldcell.plugins.imu_serial import probe

    sent0, t0 = peer.samples, time.monotonic()
    text = probe(ImuSerialSettings(port=peer.path, protocol=peer.protocol, open_timeout=1.0))
    delivered = (peer.samples - sent0) / (time.monotonic() - t0)  # samples the peer managed (load)
    rate = float(text.split(":")[-1].split()[0])
    assert peer.protocol in text and 0.5 * delivered < rate < 1.5 * peer.rate


def test_busy_port_is_a_clear_error(peer):
    a = make(peer)
    a.configure()
    try:
        with pytest.raises(DeviceError) as e:
            make(peer).configure()
        assert "exclusively lock" in e.value.message and "no other program holds it" in e.value.fix
    finally:
        a.close()
