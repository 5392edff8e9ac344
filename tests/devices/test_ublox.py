"""u-blox adapter against a pseudo-terminal receiver: real captures replayed and pyubx2-generated UBX."""

from __future__ import annotations

import math
import re
import time

import numpy as np
import pytest
from weldcell.hal.lifecycle import State
from weldcell.plugins.ublox.adapter import UbloxGnss
from weldcell.plugins.ublox.convert import geodetic_to_enu
from weldcell.plugins.ublox.settings import UbloxSettings
from weldcell.sdk.errors import DeviceError
from weldcell.testing.conformance import GnssConformance

from tests.devices.peers_ublox import LOGS, UbloxPeer

needs_logs = pytest.mark.skipif(not LOGS.is_dir(), reason=f"receiver captures not found at {LOGS}")


@pytest.fixture
def peer():
    pe = UbloxPeer().start()
    pe.period = 0.05
    yield pe
    pe.close()


@pytest.fixture
def replay_peer():
    pe = UbloxPeer(live=False).start()
    yield pe
    pe.close()


def make(peer, **kw) -> UbloxGnss:
    base = dict(port=peer.path, rate_hz=20, ack_timeout=1.0, open_timeout=1.0, silence_timeout=1.0)
    base.update(kw)
    return UbloxGnss(UbloxSettings(**base), name="gnss")


def nmea(body: str) -> bytes:
    ck = 0
    for c in body.encode():
        ck ^= c
    return f"${body}*{ck:02X}\r\n".encode()


def replay(pe, name: str, **kw) -> tuple[UbloxGnss, list]:
    """Replay one capture into an active, streaming adapter; return the adapter and its fixes."""
    dev = make(pe, configure_receiver=False, silence_timeout=2.0, **kw)
    dev.configure()
    dev.activate()
    dev.start_stream()
    pe.replay(name)
    fixes: list = []
    quiet_since = None
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:  # until the capture is sent and nothing new came for 0.5 s
        got = dev.read_available(timeout=0.1)
        fixes += got
        if got or pe.queued:
            quiet_since = None
        elif quiet_since is None:
            quiet_since = time.monotonic()
        elif time.monotonic() - quiet_since > 0.5:
            break
    fixes += dev.stop_stream()
    return dev, fixes


class TestUbloxConformance(GnssConformance):
    @pytest.fixture
    def device(self, peer):
        return make(peer)

    @pytest.fixture
    def break_device(self, peer):
        return lambda dev: peer.mute()


def test_configuration_by_ubx_cfg_and_nav_pvt_fixes(peer):
    with make(peer, rate_hz=20, origin=(45.0, 7.0, 250.0)) as dev:
        sent = [m.identity for m in peer.configured]
        assert sent == ["CFG-RATE", "CFG-MSG"]
        rate, msg = peer.configured
        assert rate.measRate == 50 and msg.msgClass == 1 and msg.msgID == 7 and msg.rateUART1 == 1
        fix = dev.read()
    assert fix.fix_type == "3d" and fix.valid and fix.num_sv == 9
    assert fix.h_acc == pytest.approx(1.5) and fix.v_acc == pytest.approx(2.5)
    assert fix.altitude == pytest.approx(250.0)
    k = round((fix.latitude - 45.0) / 1e-6)
    np.testing.assert_allclose(fix.enu, geodetic_to_enu(45.0 + 1e-6 * k, 7.0, 250.0, (45.0, 7.0, 250.0)))
    assert fix.enu[1] == pytest.approx(k * 0.1111, rel=0.01)  # 1e-6 deg of latitude is ~0.111 m north
    np.testing.assert_allclose(fix.velocity_enu, [-0.02, 0.1, -0.005])
    np.testing.assert_allclose(np.diag(fix.covariance), [1.125, 1.125, 6.25])
    assert fix.device_stamp == pytest.approx(1732442400.0 + k % 60)  # 2024-11-24 10:00:ss UTC


def test_valset_configuration_for_gen9(peer):
    with make(peer, config_messages="valset"):
        (m,) = peer.configured
        assert m.identity == "CFG-VALSET" and m.CFG_MSGOUT_UBX_NAV_PVT_UART1 == 1 and m.CFG_RATE_MEAS == 50


def test_nak_is_a_clear_error(peer):
    peer.nak = {"CFG-MSG"}
    with pytest.raises(DeviceError) as e:
        make(peer).configure()
    assert "refused CFG-MSG" in e.value.message and "valset" in e.value.fix


def test_no_fix_is_a_reading_not_an_error(peer):
    peer.fix = False
    with make(peer) as dev:
        fix = dev.read()
    assert fix.fix_type == "none" and not fix.valid and math.isnan(fix.latitude)
    assert fix.enu is None and fix.num_sv == 0


@needs_logs
def test_replay_mixed_capture_gives_every_nav_pvt_fix(replay_peer):
    dev, fixes = replay(replay_peer, "pygpsdata-MIXED.log")
    assert len(fixes) == 39, "39 NAV-PVT epochs in the capture (GGA repeats them and is not counted)"
    assert all(f.fix_type == "3d" and f.valid for f in fixes)
    lat = np.array([f.latitude for f in fixes])
    assert np.all(np.abs(lat - 53.4507) < 1e-3)
    assert 3.0 < np.median([f.h_acc for f in fixes]) < 10.0  # the capture's ~6 m accuracy
    assert all(f.num_sv >= 4 for f in fixes)
    assert dev.parse_errors == 0 and dev.skipped_bytes == 0
    dev.close()


@needs_logs
def test_replay_no_fix_capture_reports_fix_none(replay_peer):
    dev, fixes = replay(replay_peer, "2023-4-17_82912_serial-COM3.ubx")
    assert len(fixes) >= 80  # one per GGA epoch
    assert all(f.fix_type == "none" and not f.valid for f in fixes)
    assert all(f.device_stamp is not None for f in fixes[2:])  # RMC's date + GGA's time
    dev.close()


@needs_logs
@pytest.mark.parametrize(
    "name, fixes_expected",
    [("pygpsdata-BADCK2.log", 1), ("pygpsdata-MIXED3BADCK.log", 1), ("pygpsdata-BADEOF1.log", 1)],
)
def test_corrupted_captures_are_skipped_counted_and_resynchronised(replay_peer, name, fixes_expected):
    replay_peer.queue(b"\x00\xff\x13garbage")
    dev, fixes = replay(replay_peer, name)
    pvt_fixes = [f for f in fixes if f.device_stamp is not None and f.h_acc is not None]
    assert len(pvt_fixes) >= fixes_expected
    if name != "pygpsdata-BADEOF1.log":
        assert dev.parse_errors >= 1, dev.last_parse_error  # the capture's corrupt message
    # after the corruption the stream still parses: a good fix sent afterwards arrives
    replay_peer.queue(replay_peer.pvt(7))
    dev.start_stream()
    extra = []
    deadline = time.monotonic() + 2
    while not extra and time.monotonic() < deadline:
        extra += dev.read_available(timeout=0.1)
    dev.stop_stream()
    assert extra and extra[-1].latitude == pytest.approx(45.000007), "resynchronised after corruption"
    dev.close()


@needs_logs
def test_nmea_only_receiver_falls_back_to_gga(replay_peer):
    dev, fixes = replay(replay_peer, "pygpsdata-MIXED3BADCK.log")
    # the NAV-PVT comes first, so the GGAs of the same stream are not doubled
    assert len(fixes) == 1
    dev.close()
    pe = UbloxPeer(live=False).start()
    try:
        data = (LOGS / "pygpsdata-MIXED3BADCK.log").read_bytes()
        gga = b"".join(re.findall(rb"\$GPGGA[^\n]*\n", data))
        assert len(gga.splitlines()) == 2
        dev = make(pe, configure_receiver=False, silence_timeout=2.0)
        pe.queue(gga)
        dev.configure()
        dev.activate()
        pe.queue(gga)
        fix = dev.read()
        assert fix.fix_type == "3d" and fix.num_sv == 7
        assert fix.latitude == pytest.approx(53.45072, abs=1e-4)
        assert fix.altitude == pytest.approx(36.7 + 48.5, abs=0.2)  # MSL + geoid separation
        dev.close()
    finally:
        pe.close()


def test_pulled_cable_keeps_fixes(peer):
    with make(peer) as dev:
        dev.start_stream()
        first = []
        deadline = time.monotonic() + 3
        while len(first) < 5 and time.monotonic() < deadline:
            first += dev.read_available(timeout=0.1)
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
    assert len(first) + len(rest) == st.received >= 5


def test_wrong_baud_and_silent_receiver(peer):
    peer.garbage = True
    with pytest.raises(DeviceError) as e:
        make(peer, ack_timeout=0.3).configure()
    assert "without one valid message" in e.value.message and "baud" in e.value.fix
    peer.garbage = False
    peer.silent = True
    with pytest.raises(DeviceError) as e:
        make(peer, ack_timeout=0.3).configure()
    assert "silent" in e.value.message


def test_registered_with_its_extras():
    from weldcell.plugins import ublox

    specs = []
    ublox.weldcell_register_devices(specs.append)
    (spec,) = specs
    assert spec.name == "gnss.ublox" and spec.kind == "gnss"
    assert spec.requires == {"pyubx2": "ublox", "serial": "serial"}


def test_probe_reads_without_configuring(peer):
    from weldcell.plugins.ublox import probe

    text = probe(UbloxSettings(port=peer.path, open_timeout=5.0))
    assert "fix 3d" in text and "9 satellites" in text and peer.configured == []


def test_busy_port_is_a_clear_error(peer):
    a = make(peer)
    a.configure()
    try:
        with pytest.raises(DeviceError) as e:
            make(peer).configure()
        assert "exclusively lock" in e.value.message and "no other program holds it" in e.value.fix
    finally:
        a.close()
