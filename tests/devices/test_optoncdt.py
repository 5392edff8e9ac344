"""optoNCDT 1402 adapter against a pseudo-terminal peer speaking the ILD1402 protocol."""

from __future__ import annotations

import time

import numpy as np
import pytest
from weldcell.hal.lifecycle import State
from weldcell.plugins.optoncdt import protocol as p
from weldcell.plugins.optoncdt.adapter import OptoNcdt
from weldcell.plugins.optoncdt.settings import OptoNcdtSettings
from weldcell.sdk.errors import DeviceError
from weldcell.testing.conformance import DisplacementSensorConformance

from tests.devices.peers_optoncdt import OptoNcdt1420Peer, OptoNcdtPeer


@pytest.fixture
def peer():
    pe = OptoNcdtPeer().start()
    yield pe
    pe.close()


def make(peer, **kw) -> OptoNcdt:
    s = OptoNcdtSettings(port=peer.path, reply_timeout=0.5, reboot_timeout=1.0, silence_timeout=0.5, **kw)
    return OptoNcdt(s, name="laser")


def collect(dev, n, wait=3.0):
    out = []
    deadline = time.monotonic() + wait
    while len(out) < n and time.monotonic() < deadline:
        out += dev.read_available(timeout=0.05)
    return out


class TestOptoNcdtConformance(DisplacementSensorConformance):
    @pytest.fixture
    def device(self, peer):
        return make(peer)

    @pytest.fixture
    def break_device(self, peer):
        return lambda dev: peer.mute()


# -- protocol ------------------------------------------------------------------------------------


def test_value_encoding_round_trip_and_scaling():
    for dvo in (0, 1, 127, 128, 8184, 16368, 16383):
        assert p.Decoder().feed(p.encode_value(dvo)) == [dvo]
    mr, smr = 0.05, 0.045
    assert p.distance_from_dvo(161, mr, smr) == pytest.approx(smr + 0.0, abs=2e-6)  # SMR
    assert p.distance_from_dvo(16207, mr, smr) == pytest.approx(smr + mr, abs=5e-6)  # end of range
    assert p.distance_from_dvo(16374, mr, smr) is None
    d = np.linspace(0.0, mr, 7)
    back = [p.distance_from_dvo(p.dvo_from_distance(x, mr), mr, smr) - smr for x in d]
    np.testing.assert_allclose(back, d, atol=mr * 1.02 / 16368)  # one digit of resolution


def test_decoder_resynchronises_after_lost_bytes_and_cuts_out_replies():
    values = [100, 200, 300, 400, 500]
    stream = b"".join(p.encode_value(v) for v in values)
    dec = p.Decoder()
    # lose the L-byte of 200 and the H-byte of 400; a reply arrives in the middle
    damaged = stream[:3] + stream[4:6] + p.reply(p.GET_INFO, b"MR: 50\r\n") + stream[7:]
    got = []
    for k in range(0, len(damaged), 3):  # arriving in pieces
        got += dec.feed(damaged[k : k + 3])
    assert got == [100, 300, 500]
    assert dec.lost_bytes == 2 and [r.code for r in dec.replies] == [p.GET_INFO]


def test_command_frames_match_the_manual():
    assert p.command(p.DAT_OUT_ON) == bytes.fromhex("2B2B2B0D494C443120770002")
    assert p.command(p.SET_SCANRATE, 0) == bytes.fromhex("2B2B2B0D494C44312085000300000000")
    assert p.reply(p.LASER_ON) == bytes.fromhex("494C4431A087000220200D0A")


# -- adapter -------------------------------------------------------------------------------------


def test_configure_applies_rate_averaging_and_output(peer):
    peer.rate = 1000
    dev = make(peer, rate_hz=750, averaging="median", averaging_number=5)
    dev.configure()
    assert peer.rate == 750 and peer.average == (1, 5) and peer.channel == 1 and not peer.ascii
    assert dev.info["MR"] == "50" and dev.info["Scanrate"] == "750Hz"
    dev.activate()
    assert peer.output_on
    dev.close()
    assert not peer.output_on


def test_stream_delivers_every_value_at_the_rate_with_gaps_as_none(peer):
    peer.error_every = 10
    with make(peer) as dev:
        dev.start_stream()
        got = collect(dev, 600)
        dev.stop_stream()
    assert len(got) >= 600
    sent = [p.distance_from_dvo(v, 0.05, 0.045) for v in peer.sent_values[: len(got)]]
    assert [r.distance for r in got] == sent, "every value, in order, none lost, none invented"
    gaps = [r for r in got if r.distance is None]
    assert len(gaps) == len(got) // 10 and all(r.error == "too far from the sensor" for r in gaps)
    assert all(r.distance is None or r.distance > 0 for r in got), "out of range is None, never 0"
    dt = np.diff([r.stamp for r in got])
    assert np.all(dt >= 0) and np.median(dt) == pytest.approx(1 / 1500, rel=0.2)


def test_lost_bytes_are_counted_and_the_stream_resynchronises(peer):
    peer.drop_byte_every = 101  # an odd period hits both H- and L-bytes
    with make(peer) as dev:
        dev.start_stream()
        got = collect(dev, 800)
        dev.stop_stream()
        lost = dev.lost_bytes
    sent = [p.distance_from_dvo(v, 0.05, 0.045) for v in peer.sent_values]
    assert lost > 0
    # every value that arrived is one the sensor sent, in order (a subsequence), and the decoder
    # lost exactly one value per dropped byte
    it = iter(sent)
    assert all(any(r.distance == s for s in it) for r in got)
    assert len(got) >= 700


def test_cable_pulled_mid_scan_keeps_the_captured_values(peer):
    with make(peer) as dev:
        dev.start_stream()
        first = collect(dev, 300)
        time.sleep(0.05)
        peer.pull()
        deadline = time.monotonic() + 3
        while dev.stream_status().running and time.monotonic() < deadline:
            time.sleep(0.01)
        st = dev.stream_status()
        assert not st.running and st.errors == 1 and "cable" in st.last_error
        assert dev.lifecycle is State.ERROR
        rest = []
        with pytest.raises(DeviceError) as e:
            while True:
                rest += dev.read_available()
        assert "cable" in e.value.message
    n = len(first) + len(rest)
    assert n == st.received >= 300, "every value received before the pull stays readable"
    sent = [p.distance_from_dvo(v, 0.05, 0.045) for v in peer.sent_values[:n]]
    assert [r.distance for r in first + rest] == sent


def test_laser_off_setting_gives_no_distance(peer):
    with make(peer, laser=False) as dev:
        r = dev.read()
    assert r.distance is None and r.error == "laser off"


def test_missing_port_is_a_clear_error(tmp_path):
    dev = OptoNcdt(OptoNcdtSettings(port=str(tmp_path / "ttyUSB9")))
    with pytest.raises(DeviceError) as e:
        dev.configure()
    assert "ttyUSB9" in e.value.message and "plugged in" in e.value.fix
    assert dev.lifecycle is State.ERROR


def test_busy_port_is_a_clear_error(peer):
    a = make(peer)
    a.configure()
    try:
        b = make(peer)
        with pytest.raises(DeviceError) as e:
            b.configure()
        assert "no other program holds it" in e.value.fix
    finally:
        a.close()


def test_wrong_baud_rate_is_reported(peer):
    peer.mode = "garbage"
    with pytest.raises(DeviceError) as e:
        make(peer).configure()
    assert "garbage" in e.value.message and "baud" in e.value.fix


def test_silent_sensor_is_reported(peer):
    peer.mode = "silent"
    with pytest.raises(DeviceError) as e:
        make(peer).configure()
    assert "silent" in e.value.message and "power" in e.value.fix


def test_measuring_range_mismatch_is_reported(peer):
    with pytest.raises(DeviceError) as e:
        make(peer, measuring_range="100 mm").configure()
    assert "50 mm" in e.value.message and "measuring_range" in e.value.fix


def test_silence_while_measuring_is_a_fault(peer):
    with make(peer) as dev:
        dev.read()
        peer.mute()
        with pytest.raises(DeviceError, match="silent"):
            for _ in range(20):
                dev.read(timeout=0.2)
        assert dev.lifecycle is State.ERROR


def test_registered_through_the_plugin_manager():
    from weldcell.plugins import optoncdt

    specs = []
    optoncdt.weldcell_register_devices(specs.append)
    (spec,) = specs
    assert spec.name == "displacement.optoncdt" and spec.kind == "displacement_sensor"
    assert spec.requires == {"serial": "serial"}


def test_probe_reports_the_sensor(peer):
    from weldcell.plugins.optoncdt import probe

    text = probe(OptoNcdtSettings(port=peer.path, reply_timeout=0.5))
    assert "1234570" in text and "MR 50 mm" in text


# -- optoNCDT 1420 / 1320 family -------------------------------------------------------------------


@pytest.fixture
def peer1420():
    pe = OptoNcdt1420Peer().start()
    yield pe
    pe.close()


def make1420(pe, **kw):
    from weldcell.plugins.optoncdt import _factory

    base = dict(family="1420", port=pe.path, measuring_range="10 mm", start_of_range="20 mm", rate_hz=1000)
    base.update(reply_timeout=0.5, silence_timeout=0.5, **kw)
    return _factory(OptoNcdtSettings(**base), type("C", (), {"role": "laser"})())


class TestOptoNcdt1420Conformance(DisplacementSensorConformance):
    @pytest.fixture
    def device(self, peer1420):
        return make1420(peer1420)

    @pytest.fixture
    def break_device(self, peer1420):
        return lambda dev: peer1420.mute()


def test_1420_values_and_replies_are_separated(peer1420):
    from weldcell.plugins.optoncdt import protocol_1420 as q

    peer1420.error_every = 7
    with make1420(peer1420) as dev:
        assert dev.info["Name"] == "ILD1420-10" and dev.info["Measuring range"] == "10.00mm"
        assert peer1420.commands == ["GETINFO", "OUTPUT RS422"]
        dev.start_stream()
        got = collect(dev, 300)
        dev.stop_stream()
    assert peer1420.commands[-1] == "OUTPUT NONE" and peer1420.output == "NONE"
    sent = [q.distance_from_dvo(v, 0.01, 0.02) for v in peer1420.sent_values]
    k = sent.index(got[0].distance)  # the stream starts wherever the sensor was
    assert [r.distance for r in got] == sent[k : k + len(got)]
    gaps = [r for r in got if r.distance is None]
    assert gaps and all(r.error == "too far from the sensor" for r in gaps)
    d = [r.distance for r in got if r.distance is not None]
    assert 0.02 <= min(d) and max(d) <= 0.03


def test_1420_scaling_and_encoding():
    from weldcell.plugins.optoncdt import protocol_1420 as q

    assert q.distance_from_dvo(643, 0.01, 0.02) == pytest.approx(0.02, abs=1e-6)
    assert q.distance_from_dvo(64877, 0.01, 0.02) == pytest.approx(0.03, abs=1e-6)
    assert q.distance_from_dvo(262076, 0.01, 0.02) is None
    for x in (0, 643, 65520, 262082):
        dec = q.Decoder()
        assert dec.feed(q.encode_value(x)) == [x]
    dec = q.Decoder()
    assert dec.feed(q.encode_value(5, additional=True) + q.encode_value(6)) == [6] and dec.additional == 1


def test_1420_lost_bytes_resynchronise(peer1420):
    from weldcell.plugins.optoncdt import protocol_1420 as q

    peer1420.drop_byte_every = 50
    with make1420(peer1420) as dev:
        dev.start_stream()
        got = collect(dev, 300)
        dev.stop_stream()
    sent = [q.distance_from_dvo(v, 0.01, 0.02) for v in peer1420.sent_values]
    it = iter(sent)
    assert all(any(r.distance == s for s in it) for r in got), "only values the sensor sent, in order"


def test_1420_wrong_range_and_garbage(peer1420):
    with pytest.raises(DeviceError, match="10.00 mm"):
        make1420(peer1420, measuring_range="25 mm").configure()
    peer1420.mode = "garbage"
    with pytest.raises(DeviceError) as e:
        make1420(peer1420).configure()
    assert "baud" in e.value.fix
