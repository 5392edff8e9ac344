"""The Leap Motion adapter (gesture.leap) against a local WebSocket server replaying real Leap recordings."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("websockets", reason="websockets is not installed (pip install 'weldcell[leap]')")

from peers_leap import LeapReplayServer  # noqa: E402
from weldcell.hal.lifecycle import State  # noqa: E402
from weldcell.plugins import leap as leap_plugin  # noqa: E402
from weldcell.plugins.leap.adapter import LeapMotion  # noqa: E402
from weldcell.plugins.leap.playback import load_recording  # noqa: E402
from weldcell.plugins.leap.protocol import FINGERS, frame_from_json  # noqa: E402
from weldcell.plugins.leap.settings import LeapSettings  # noqa: E402
from weldcell.sdk.errors import DataError, DeviceError  # noqa: E402
from weldcell.testing.conformance import GestureSensorConformance  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "leap-motion-recordings"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason=f"Leap recordings not found at {DATA}")


@pytest.fixture(scope="module")
def brian():
    return load_recording(DATA / "recordings" / "brian.json")


@pytest.fixture
def service(brian):
    srv = LeapReplayServer(brian, fps=200)
    yield srv
    srv.close()


def make(url: str, **kw) -> LeapMotion:
    s = dict(url=url, frame_timeout=0.5, reconnect_attempts=4, reconnect_delay=0.02)
    s.update(kw)
    return LeapMotion(LeapSettings(**s), name="leap")


class TestLeapConformance(GestureSensorConformance):
    @pytest.fixture
    def device(self, service):
        return make(service.url)

    @pytest.fixture
    def break_device(self, service):
        def brk(dev):
            service.accepting = False  # the service goes down ...
            service.drop_after(0)
            original = dev.on_recover

            def recover_and_restart():  # ... and is back when the operator recovers
                original()
                service.accepting = True

            dev.on_recover = recover_and_restart

        return brk


def test_palms_in_metres_match_the_recording(service):
    with make(service.url) as leap:
        frames = [leap.read() for _ in range(40)]
    assert service.received[:3] == [{"enableGestures": False}, {"background": True}, {"focused": True}]
    assert leap.service_version == {"serviceVersion": "2.3.1+31549", "version": 6}
    ids = [f.frame_id for f in frames]
    assert len(set(ids)) == len(ids), "each read returns a new frame"
    for f in frames:
        rec = service.frame_by_id(f.frame_id)
        assert len(f.hands) == len(rec["hands"]) >= 1
        for h, rh in zip(f.hands, rec["hands"], strict=True):
            assert h.side == rh["type"]
            np.testing.assert_allclose(h.palm_position, np.array(rh["palmPosition"]) / 1000.0, atol=1e-12)
            assert abs(np.linalg.norm(h.palm_normal) - 1) < 1e-9
            tips = {p["type"]: p for p in rec["pointables"] if p["handId"] == rh["id"]}
            for k, name in enumerate(FINGERS):
                np.testing.assert_allclose(h.fingertips[name], np.array(tips[k]["tipPosition"]) / 1000.0)
                assert h.extended[name] == tips[k]["extended"]
        box = f.interaction_box
        np.testing.assert_allclose(box.center, [0.0, 0.2, 0.0])
        assert f.frame == "leap" and f.stamp <= time.time()


def test_dropped_connection_mid_stream_reconnects_and_keeps_going(service):
    with make(service.url) as leap:
        first = [leap.read().frame_id for _ in range(10)]
        service.drop_after(5)
        later = [leap.read().frame_id for _ in range(60)]
        assert leap.reconnects == 1 and service.connections == 2
        assert leap.lifecycle is State.ACTIVE
    assert len(service.received) == 6  # the configuration was sent again after the reconnect
    order = [service.sent_ids.index(i) for i in first + later]
    assert order == sorted(order), "frames keep arriving in recording order across the reconnect"
    assert later[-1] != first[-1]


def test_service_gone_for_good_is_an_error_with_a_fix(service):
    leap = make(service.url)
    leap.configure()
    leap.activate()
    leap.read()
    service.accepting = False
    service.drop_after(0)
    with pytest.raises(DeviceError) as e:
        for _ in range(200):
            leap.read()
    assert "not regained" in e.value.message and leap.lifecycle is State.ERROR
    service.accepting = True
    leap.recover()
    leap.configure()
    leap.activate()
    assert leap.read().hands
    leap.close()


def test_silent_service_is_an_error(service):
    with make(service.url, frame_timeout=0.2) as leap:
        leap.read()
        service.paused = True
        with pytest.raises(DeviceError) as e:
            for _ in range(100):
                leap.read()
        assert "no frame" in e.value.message and "Leap service" in e.value.fix
        assert leap.lifecycle is State.ERROR


def test_unreachable_service(service):
    url = service.url
    service.close()
    leap = make(url, open_timeout=0.3)
    with pytest.raises(DeviceError) as e:
        leap.configure()
    assert url in e.value.message and "Allow Web Apps" in e.value.fix
    with pytest.raises(DeviceError):
        leap_plugin.probe(LeapSettings(url=url, open_timeout=0.3))


def test_probe_reports_the_service_version(service):
    assert "2.3.1+31549" in leap_plugin.probe(LeapSettings(url=service.url))


def test_gun_recording_has_frames_without_hands():
    frames = load_recording(DATA / "recordings" / "gun.json")
    assert len(frames) == 50
    hf = [frame_from_json(f, 0.0) for f in frames]
    assert all(f.hands == () for f in hf) and hf[0].interaction_box.size[0] == pytest.approx(0.235247)


@pytest.mark.parametrize("name, n", [("pinch-57fps", 133), ("grab", 374), ("HandSplay-110fps", 288)])
def test_packed_lz_recordings_replay(name, n):
    pytest.importorskip("lzstring")
    frames = load_recording(DATA / "recorder" / "recordings" / f"{name}.json.lz")
    assert len(frames) == n
    srv = LeapReplayServer(frames, fps=300)
    try:
        with make(srv.url) as leap:
            got = [leap.read() for _ in range(10)]
    finally:
        srv.close()
    for f in got:
        rec = srv.frame_by_id(f.frame_id)
        h, rh = f.hands[0], rec["hands"][0]
        np.testing.assert_allclose(h.palm_position * 1000.0, rh["palmPosition"])
        assert set(h.fingertips) == set(FINGERS)  # finger types from id = handId * 10 + type when packed
        assert np.all(np.abs(h.palm_position) < 0.6)


def test_bad_frames_are_clear_errors():
    with pytest.raises(DataError):
        frame_from_json({"hands": [{"type": "middle", "id": 1}], "id": 3}, 0.0)
    with pytest.raises(DataError):
        frame_from_json({"serviceVersion": "2", "version": 6}, 0.0)
    with pytest.raises(DataError):
        frame_from_json(
            {
                "id": 1,
                "hands": [
                    {
                        "type": "left",
                        "id": 1,
                        "palmPosition": [1, 2],
                        "palmNormal": [0, 1, 0],
                        "direction": [0, 0, 1],
                    }
                ],
            },
            0.0,
        )


def test_registration(weldcell_pm):
    weldcell_pm.register(leap_plugin, "leap")
    spec = weldcell_pm.registry.get("device", "gesture.leap")
    assert spec.kind == "gesture_sensor" and spec.settings is LeapSettings

    class Ctx:
        role = "gesture"

    assert isinstance(spec.factory(LeapSettings(), Ctx()), LeapMotion)
