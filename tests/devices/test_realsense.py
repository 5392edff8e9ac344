"""The RealSense adapter (camera.realsense) on pyrealsense2's software device, on a real librealsense
recording made from it (.db3) and on ROS1 .bag recordings in the RealSense Viewer's layout: depth in
metres via the device's scale, intrinsics from the stream profile, alignment, filters, options, end of
recording, repeat, damaged files, timeouts and recovery."""

from __future__ import annotations

import numpy as np
import pytest

rs = pytest.importorskip(
    "pyrealsense2", reason="pyrealsense2 is not installed (pip install 'weldcell[realsense]')"
)

from peers_realsense import SERIAL, SoftwareD415  # noqa: E402
from peers_realsense_bag import SERIAL as BAG_SERIAL  # noqa: E402
from peers_realsense_bag import write_d415_bag  # noqa: E402
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
    assert "d415.db3" in rs_plugin.probe(s) and "depth 64x48 z16 @ 30 Hz" in rs_plugin.probe(s)
    cam = RealSenseCamera(s)
    cam.configure()
    assert cam.intrinsics().width == 64  # from the recorded stream profile
    cam.activate()
    f = cam.capture()
    np.testing.assert_allclose(f.depth, d415.depth_m(), atol=0.5e-4 + 1e-6)
    with pytest.raises(DeviceError) as e:
        for _ in range(20):
            cam.capture(timeout=0.3)
    assert "ended" in e.value.message or "delivered no frame" in e.value.message
    cam.close()


# -- ROS1 .bag recordings (RealSense Viewer / rs.recorder before librealsense 2.56) -------------------------


def play(path, **kw) -> RealSenseCamera:
    return RealSenseCamera(RealSenseSettings(recording=str(path), playback_realtime=False, **kw))


def assert_frame_of_scene(f, scene, color: bool = True) -> int:
    """The frame's depth (and colour) are those the recording holds under its frame number."""
    n = f.meta["frame_number"]
    np.testing.assert_allclose(f.depth, scene.depth_m(n), atol=0.5e-4 + 1e-6)
    if color:
        np.testing.assert_array_equal(f.color, scene.color_rgb(n))
    return n


def play_out(cam, scene, limit: int = 30) -> tuple[list[int], DeviceError]:
    """Capture until the recording's error; the frame numbers read (librealsense's pipeline may drop a
    frameset under CPU load, so numbers only have to rise) and the error."""
    numbers = []
    with pytest.raises(DeviceError) as e:
        for _ in range(limit):
            numbers.append(assert_frame_of_scene(cam.capture(timeout=0.5), scene))
    assert numbers == sorted(set(numbers))
    return numbers, e.value


@pytest.mark.parametrize(
    "layout",
    [{}, {"units_in_frames": False, "file_version": 3}],
    ids=["units-in-frames", "older-units-in-option"],
)
def test_bag_recording_plays_depth_colour_and_intrinsics(tmp_path, layout):
    path = tmp_path / "d415.bag"
    scene = write_d415_bag(path, frames=10, chunk_threshold=40_000, **layout)
    assert path.read_bytes().count(b"compression=none") > 3  # several chunks, as any real recording
    cam = play(path)
    cam.configure()
    k = cam.intrinsics()
    assert (k.width, k.height, k.fx, k.fy, k.cx, k.cy) == (64, 48, 50.0, 50.0, 31.5, 23.5)
    cam.activate()
    f = cam.capture()
    assert_frame_of_scene(f, scene)  # depth in metres to half a depth unit, colour bytes, frame pairing
    assert f.meta["depth_scale"] == pytest.approx(1e-4)  # the recorded Depth Units, not an assumed 1 mm
    assert f.depth.dtype == np.float32 and np.all(f.depth[5:10, 5:10] == 0.0)
    numbers, _ = play_out(cam, scene)
    assert len(numbers) >= 7 and numbers[-1] == 10  # read to the end, in order
    cam.close()


def test_bag_alignment_uses_the_recorded_colour_intrinsics_and_extrinsics(tmp_path):
    scene = write_d415_bag(tmp_path / "d415.bag", frames=3)
    with play(tmp_path / "d415.bag", align_to_color=True) as cam:
        f = cam.capture()
    assert f.depth.shape == (60, 80) and f.intrinsics.fx == 60.0 and f.meta["aligned_to_color"]
    v, u = np.mgrid[0:60, 0:80]
    inner = (f.depth > 0) & (u > 10) & (u < 70) & (v > 15) & (v < 50)
    assert inner.sum() > 1000
    # the colour camera sits 50 mm along x: ignoring the recorded extrinsics would be off by >= 5 mm
    truth = scene.depth_in_color_m(f.meta["frame_number"])
    np.testing.assert_allclose(f.depth[inner], truth[inner], atol=2e-3)


def test_bag_end_of_recording_then_replay_and_repeat(tmp_path):
    path = tmp_path / "d415.bag"
    scene = write_d415_bag(path, frames=6)
    cam = play(path)
    cam.configure()
    cam.activate()
    numbers, e = play_out(cam, scene)
    assert numbers[-1] == 6 and f"has ended after {len(numbers)} framesets" in e.message
    assert "playback_repeat" in e.fix and cam.lifecycle is State.ERROR
    cam.recover()
    cam.configure()
    cam.activate()
    assert cam.capture().meta["frame_number"] <= 2  # played again from the start
    cam.close()
    with play(path, playback_repeat=True) as cam:
        numbers = [assert_frame_of_scene(cam.capture(timeout=1.0), scene) for _ in range(14)]
    # looped at least once, and the last depth was never paired with the first colour frame
    assert any(b < a for a, b in zip(numbers, numbers[1:], strict=False)) and max(numbers) == 6


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        (lambda b: b[: len(b) // 2], "cannot be read"),  # copy cut short: the index is lost
        (lambda b: b[:-10], "cannot be read"),
        (lambda b: b"", "is empty"),
        (lambda b: b"<html>not found</html>\n" * 40, "neither a ROS1 .bag nor a ROS2 .db3"),
    ],
    ids=["half", "last-bytes-missing", "empty", "not-a-bag"],
)
def test_a_truncated_or_corrupt_bag_is_one_clear_error(tmp_path, damage, words):
    write_d415_bag(tmp_path / "good.bag", frames=4)
    bad = tmp_path / "bad.bag"
    bad.write_bytes(damage((tmp_path / "good.bag").read_bytes()))
    cam = play(bad)
    with pytest.raises(DeviceError) as e:
        cam.configure()
    assert words in e.value.message and "bad.bag" in e.value.message and "copy it again" in e.value.fix
    assert cam.lifecycle is State.ERROR
    with pytest.raises(DeviceError) as e:
        rs_plugin.probe(RealSenseSettings(recording=str(bad)))
    assert words in e.value.message


@pytest.mark.parametrize(
    ("field", "words"),
    [(-4, "has ended after {n} framesets"), (11, "delivered no frame within 0.5 s while playing, after {n}")],
    ids=["encoding-length", "data-length"],
)
def test_a_bag_damaged_inside_a_frame_stops_there_with_a_clear_error(tmp_path, field, words):
    path = tmp_path / "d415.bag"
    scene = write_d415_bag(path, frames=6)
    b = bytearray(path.read_bytes())
    at = [i for i in range(len(b)) if b[i : i + 6] == b"mono16"][3]  # [0] is the stream info; frame 3
    b[at + field : at + field + 4] = b"\xff\xff\xff\x7f"  # a length field of frame 3's depth image
    path.write_bytes(bytes(b))
    cam = play(path)
    cam.configure()
    cam.activate()
    numbers, e = play_out(cam, scene)  # within the timeout: no hang
    assert numbers in ([1, 2], [2]) and words.format(n=len(numbers)) in e.message
    assert cam.lifecycle is State.ERROR
    cam.recover()


def test_a_bag_without_colour_needs_color_false(tmp_path):
    path = tmp_path / "depth_only.bag"
    scene = write_d415_bag(path, frames=3, color=False)
    cam = play(path)
    with pytest.raises(DeviceError) as e:
        cam.configure()
    assert "no colour stream (it holds depth 64x48 z16 @ 30 Hz)" in e.value.message
    assert "color = false" in e.value.fix
    with play(path, color=False) as cam:
        f = cam.capture()
    assert f.color is None
    assert_frame_of_scene(f, scene, color=False)


def test_probe_reports_the_recorded_camera_and_streams(tmp_path):
    write_d415_bag(tmp_path / "d415.bag", frames=10)
    text = rs_plugin.probe(RealSenseSettings(recording=str(tmp_path / "d415.bag")))
    assert f"Intel RealSense D415 #{BAG_SERIAL}, 0.3 s" in text
    assert "depth 64x48 z16 @ 30 Hz" in text and "color 80x60 rgb8 @ 30 Hz" in text


def test_misnamed_or_unreadable_format_recordings_say_what_to_do(tmp_path, monkeypatch):
    write_d415_bag(tmp_path / "d415.bag", frames=2)
    renamed = tmp_path / "d415.rosbag"
    renamed.write_bytes((tmp_path / "d415.bag").read_bytes())
    sqlite = tmp_path / "d415_db3.bag"
    sqlite.write_bytes(b"SQLite format 3\x00" + bytes(100))
    old_bag = tmp_path / "old.bag"
    old_bag.write_bytes(b"#ROSBAG V1.2\n" + bytes(100))
    for path, words, fix in (
        (renamed, "ROS1 .bag file but its name does not end in .bag", "rename it to end in .bag"),
        (sqlite, "ROS2 .db3 recording but its name ends in .bag", "rename it to end in .db3"),
        (old_bag, "ROS1 bag of format 1.2, not 2.0", "RealSense Viewer"),
    ):
        with pytest.raises(DeviceError) as e:
            play(path).configure()
        assert words in e.value.message and fix in e.value.fix
    db3 = tmp_path / "d415.db3"
    db3.write_bytes(b"SQLite format 3\x00" + bytes(100))
    monkeypatch.setattr(rs, "__version__", "2.54.2")
    with pytest.raises(DeviceError) as e:
        play(db3).configure()
    assert "librealsense 2.54.2 reads only .bag" in e.value.message and "pyrealsense2>=2.56" in e.value.fix


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
