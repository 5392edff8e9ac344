"""The RealSense adapter (camera.realsense) on pyrealsense2's software device and on a real librealsense
recording made from it: depth in metres via the device's scale, intrinsics from the stream profile,
alignment, filters, options, timeouts and recovery."""

from __future__ import annotations

import numpy as np
import pytest

rs = pytest.importorskip(
    "pyrealsense2", reason="pyrealsense2 is not installed (pip install 'weldcell[realsense]')"
)

from peers_realsense import SERIAL, SoftwareD415  # noqa: E402
from weldcell.hal.lifecycle import State  # noqa: E402
from weldcell.plugins import realsense as rs_plugin  # noqa: E402
from weldcell.plugins.realsense.adapter import RealSenseCamera  # noqa: E402
from weldcell.plugins.realsense.settings import RealSenseSettings  # noqa: E402
from weldcell.sdk.errors import DeviceError  # noqa: E402
from weldcell.testing.conformance import DepthCameraConformance  # noqa: E402


@pytest.fixture(scope="module")
def d415():
    cam = SoftwareD415()
    yield cam
    cam.close()


@pytest.fixture
def feed(d415):
    d415.feeding.set()
    yield d415
    d415.feeding.clear()


def settings(**kw) -> RealSenseSettings:
    base = dict(depth_width=64, depth_height=48, color_width=80, color_height=60)
    base.update(kw)
    return RealSenseSettings(**base)


class TestRealSenseConformance(DepthCameraConformance):
    @pytest.fixture
    def device(self, feed):
        return RealSenseCamera(settings(), name="cam", device=feed.dev)

    @pytest.fixture
    def break_device(self, feed):
        def brk(dev):
            feed.feeding.clear()  # the camera stops delivering frames ...
            original = dev.on_recover

            def recover_and_replug():  # ... until the operator recovers it (re-plugged)
                original()
                feed.feeding.set()

            dev.on_recover = recover_and_replug

        return brk


def test_depth_is_metres_through_the_device_depth_scale(feed):
    with RealSenseCamera(settings(), device=feed.dev) as cam:
        f = cam.capture()
    truth = feed.depth_m()
    assert f.meta["depth_scale"] == pytest.approx(1e-4)  # the device's units, not an assumed 1 mm
    assert f.depth.dtype == np.float32 and f.depth.shape == truth.shape
    np.testing.assert_allclose(f.depth, truth, atol=0.5e-4 + 1e-6)
    assert np.all(f.depth[5:10, 5:10] == 0.0)
    k = f.intrinsics
    assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (64, 48, 50.0, 50.0, 31.5, 23.5)
    np.testing.assert_array_equal(f.color, feed.color_rgb())
    pts = f.to_cloud().points  # every back-projected point lies on the plane Z - 0.1 X = 0.6
    np.testing.assert_allclose(pts[:, 2] - 0.1 * pts[:, 0], 0.6, atol=1e-4)


def test_intrinsics_are_known_once_configured(d415):
    cam = RealSenseCamera(settings(), device=d415.dev)
    with pytest.raises(DeviceError):
        cam.intrinsics()
    cam.configure()
    assert cam.intrinsics().K[0, 0] == 50.0 and cam.intrinsics().width == 64
    cam.close()


def test_align_depth_to_colour_uses_the_colour_intrinsics(feed):
    with RealSenseCamera(settings(align_to_color=True), device=feed.dev) as cam:
        f = cam.capture()
    assert f.depth.shape == (60, 80) and f.intrinsics.fx == 60.0 and f.meta["aligned_to_color"]
    v, u = np.mgrid[0:60, 0:80]
    truth = 0.6 / (1.0 - 0.1 * (u - 39.5) / 60.0)
    inner = (f.depth > 0) & (u > 20) & (u < 70) & (v > 15) & (v < 50)
    assert inner.sum() > 800
    np.testing.assert_allclose(f.depth[inner], truth[inner], atol=3e-3)


def test_decimation_and_edge_preserving_filters(feed):
    s = settings(decimation=2, spatial_filter=True, temporal_filter=True, color=False)
    with RealSenseCamera(s, device=feed.dev) as cam:
        for _ in range(3):
            f = cam.capture()
        k = cam.intrinsics()
    assert f.depth.shape == (24, 32) == (k.height, k.width) and k.fx == pytest.approx(25.0)
    u = np.arange(32)[None, :]
    truth = 0.6 / (1.0 - 0.1 * (u - k.cx) / k.fx)
    inner = f.depth[8:20, 6:28]
    np.testing.assert_allclose(inner, np.broadcast_to(truth, f.depth.shape)[8:20, 6:28], atol=5e-3)


def test_sensor_options(d415):
    cam = RealSenseCamera(settings(laser_power="210", preset="high_accuracy"), device=d415.dev)
    cam.configure()
    assert d415.depth_sensor.get_option(rs.option.laser_power) == 210
    assert d415.depth_sensor.get_option(rs.option.visual_preset) == 3
    cam.close()
    for kw, words in (
        ({"laser_power": 200}, "grid"),
        ({"laser_power": 400}, "range"),
        ({"emitter_enabled": True}, "no emitter_enabled option"),
    ):
        cam = RealSenseCamera(settings(**kw), device=d415.dev)
        with pytest.raises(DeviceError) as e:
            cam.configure()
        assert words in e.value.message and cam.lifecycle is State.ERROR


def test_a_camera_that_stops_sending_is_an_error_then_recovers(feed):
    cam = RealSenseCamera(settings(), device=feed.dev)
    cam.configure()
    cam.activate()
    cam.capture()
    feed.feeding.clear()
    with pytest.raises(DeviceError) as e:
        for _ in range(10):
            cam.capture(timeout=0.2)
    assert "within 0.2 s" in e.value.message and "USB 3" in e.value.fix
    assert cam.lifecycle is State.ERROR
    cam.recover()
    feed.feeding.set()
    cam.configure()
    cam.activate()
    assert cam.capture().depth.shape == (48, 64)
    cam.close()


def test_recording_playback_through_the_pipeline(d415, tmp_path):
    path = tmp_path / "d415.db3"
    d415.record(str(path), frames=8)
    s = RealSenseSettings(recording=str(path), playback_realtime=False, color=False)
    assert "d415.db3" in rs_plugin.probe(s)
    cam = RealSenseCamera(s)
    cam.configure()
    assert cam.intrinsics().width == 64  # from the recorded stream profile
    cam.activate()
    f = cam.capture()
    np.testing.assert_allclose(f.depth, d415.depth_m(), atol=0.5e-4 + 1e-6)
    with pytest.raises(DeviceError) as e:
        for _ in range(20):
            cam.capture(timeout=0.3)
    assert "ended" in e.value.message or "no frames" in e.value.message
    cam.close()


def test_missing_recording_and_absent_serial_are_clear_errors(tmp_path):
    cam = RealSenseCamera(RealSenseSettings(recording=str(tmp_path / "nope.bag")))
    with pytest.raises(DeviceError) as e:
        cam.configure()
    assert "nope.bag" in e.value.message
    ctx = rs.context()
    connected = [d.get_info(rs.camera_info.serial_number) for d in ctx.query_devices()]
    if connected:
        pytest.skip("a real RealSense is connected; the absent-serial case needs none")
    cam = RealSenseCamera(RealSenseSettings(serial="000000000001"), context=ctx)
    with pytest.raises(DeviceError) as e:
        cam.configure()
    assert "000000000001" in e.value.message and "connected: none" in e.value.message
    with pytest.raises(DeviceError):
        rs_plugin.probe(RealSenseSettings(serial="000000000001"))


def test_align_without_colour_is_refused(d415):
    cam = RealSenseCamera(settings(align_to_color=True, color=False), device=d415.dev)
    with pytest.raises(DeviceError) as e:
        cam.configure()
    assert "align_to_color" in e.value.message


def test_registration(weldcell_pm):
    weldcell_pm.register(rs_plugin, "realsense")
    spec = weldcell_pm.registry.get("device", "camera.realsense")
    assert (
        spec.kind == "depth_camera" and spec.settings is RealSenseSettings and spec.probe is rs_plugin.probe
    )

    class Ctx:
        role = "camera"

    dev = spec.factory(RealSenseSettings(serial=SERIAL), Ctx())
    assert isinstance(dev, RealSenseCamera) and dev.name == "camera" and dev.frame == "camera.optical"
