"""tactile.aruco-camera with OpenCV's real ArUco photos and a video of rendered markers."""

from __future__ import annotations

import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
from weldcell.hal.lifecycle import State
from weldcell.plugins import aruco_camera as aruco_plugin
from weldcell.plugins.aruco_camera.adapter import ArucoCamera, open_capture, probe_camera
from weldcell.plugins.aruco_camera.intrinsics_io import read_opencv_intrinsics, scaled
from weldcell.plugins.aruco_camera.settings import ArucoCameraSettings, IntrinsicsBlock
from weldcell.sdk.errors import DeviceError
from weldcell.testing.conformance import TactileCameraConformance

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "opencv-aruco-charuco-images"
ARUCO = DATA / "modules" / "aruco"
IMAGES = ARUCO / "tutorials" / "aruco_calibration" / "images"
YML = ARUCO / "samples" / "tutorial_camera_charuco.yml"
needs_data = pytest.mark.skipif(not IMAGES.is_dir(), reason=f"OpenCV ArUco photos not found at {DATA}")


def _photos(**kw) -> ArucoCameraSettings:
    return ArucoCameraSettings(
        source=str(IMAGES / "img_%02d.jpg"), backend="images", intrinsics_file=str(YML), **kw
    )


@needs_data
class TestArucoCameraOnRealPhotos(TactileCameraConformance):
    @pytest.fixture
    def device(self):
        return ArucoCamera(_photos(loop=True), name="finger")

    @pytest.fixture
    def break_device(self):
        return lambda dev: dev._cap.release()  # noqa: SLF001 - the camera goes away under the adapter


@needs_data
def test_intrinsics_yml_is_read_exactly():
    k = read_opencv_intrinsics(YML)
    assert (k.width, k.height) == (640, 480)
    assert (k.fx, k.fy, k.cx, k.cy) == pytest.approx(
        (452.51072219637672, 456.76707935146891, 317.70297317353277, 277.75155919135995)
    )
    assert k.dist == pytest.approx(
        (
            0.12136925618707872,
            -1.0854664722560681,
            1.1786843796668460e-04,
            -4.6240686046485508e-04,
            2.9542589406810080,
        )
    )


@needs_data
def test_frames_are_the_photos_in_order_with_intrinsics():
    with ArucoCamera(_photos(), name="finger") as cam:
        frames = [cam.capture() for _ in range(4)]
        with pytest.raises(DeviceError, match="no frame"):
            cam.capture()  # a 4-photo sequence ends; without loop that is the camera going silent
        assert cam._state is State.ERROR  # noqa: SLF001
    for i, f in enumerate(frames):
        ref = cv2.imread(str(IMAGES / f"img_{i:02d}.jpg"))
        assert f.image.shape == (480, 640, 3) and f.image.dtype == np.uint8
        np.testing.assert_array_equal(f.image, ref)
        assert f.intrinsics.fx == pytest.approx(452.5107, abs=1e-3) and f.frame == "finger"
    # the photos show a real ArUco board: the frames are usable by the marker detector
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250))
    _, ids, _ = det.detectMarkers(cv2.cvtColor(frames[0].image, cv2.COLOR_BGR2GRAY))
    assert ids is not None and len(ids) >= 10


def _marker_video(path: Path, ids=(7, 23, 7), size=(320, 240)) -> Path:
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, size)
    assert vw.isOpened()
    for i in ids:
        img = np.full((size[1], size[0]), 255, np.uint8)
        m = cv2.aruco.generateImageMarker(d, i, 120)
        img[60:180, 100:220] = m
        vw.write(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    vw.release()
    return path


def test_video_file_of_rendered_markers(tmp_path):
    video = _marker_video(tmp_path / "finger.avi")
    block = IntrinsicsBlock(width=640, height=480, fx=452.5, fy=456.8, cx=317.7, cy=277.75, dist=(0.1, -1.0))
    with ArucoCamera(ArucoCameraSettings(source=str(video), intrinsics=block, loop=True)) as cam:
        got = []
        det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50))
        for _ in range(4):
            f = cam.capture()
            _, ids, _ = det.detectMarkers(cv2.cvtColor(f.image, cv2.COLOR_BGR2GRAY))
            got.append(int(ids.ravel()[0]))
        k = cam.intrinsics()
    assert got == [7, 23, 7, 7], "frames in order, looping at the end"
    # the calibration was made at 640x480; the camera delivers 320x240 -> intrinsics rescaled
    assert (k.width, k.height) == (320, 240)
    assert k.fx == pytest.approx(452.5 / 2) and k.cx == pytest.approx((317.7 + 0.5) / 2 - 0.5)
    assert k.dist == (0.1, -1.0)


class _StalledCapture:
    """A camera that opens, delivers one frame, then hangs in read() (a stalled USB camera)."""

    def __init__(self) -> None:
        self.reads = 0
        self.released = threading.Event()

    def isOpened(self) -> bool:  # noqa: N802 - cv2 API
        return True

    def get(self, prop) -> float:
        return {cv2.CAP_PROP_FRAME_WIDTH: 64.0, cv2.CAP_PROP_FRAME_HEIGHT: 48.0}.get(prop, 0.0)

    def set(self, prop, value) -> bool:
        return True

    def read(self):
        self.reads += 1
        if self.reads > 1:
            self.released.wait(2.0)
            return False, None
        return True, np.zeros((48, 64, 3), np.uint8)

    def release(self) -> None:
        self.released.set()


def test_a_stalled_camera_times_out_and_recover_reopens():
    caps: list[_StalledCapture] = []

    def factory(settings):
        caps.append(_StalledCapture())
        return caps[-1]

    cam = ArucoCamera(ArucoCameraSettings(source="0"), capture_factory=factory)
    with cam:
        cam.capture(timeout=0.5)
        with pytest.raises(DeviceError, match="within 0.20 s"):
            cam.capture(timeout=0.2)
        assert cam._state is State.ERROR and "no frame" in cam.health().message  # noqa: SLF001
        cam.recover()
        assert caps[0].released.is_set(), "recover releases the stalled camera"
        cam.configure()
        cam.activate()
        assert cam.capture(timeout=0.5).image.shape == (48, 64, 3)
        assert len(caps) == 2


def test_bad_sources_and_intrinsics(tmp_path):
    with pytest.raises(DeviceError, match="cannot open"):
        ArucoCamera(ArucoCameraSettings(source=str(tmp_path / "missing.avi"))).configure()
    bad = tmp_path / "k.yml"
    bad.write_text("%YAML:1.0\n---\nimage_width: 640\n")
    with pytest.raises(DeviceError, match="camera_matrix"):
        ArucoCamera(ArucoCameraSettings(source="0", intrinsics_file=str(bad))).configure()
    with pytest.raises(DeviceError, match="backend"):
        open_capture(ArucoCameraSettings(source="0", backend="nope"))


def test_probe_and_registration(tmp_path, weldcell_pm):
    video = _marker_video(tmp_path / "v.avi")
    assert "320x240" in probe_camera(ArucoCameraSettings(source=str(video)))
    with pytest.raises(DeviceError):
        probe_camera(ArucoCameraSettings(source=str(tmp_path / "none.avi")))
    weldcell_pm.register(aruco_plugin, "aruco_camera")
    spec = weldcell_pm.registry.get("device", "tactile.aruco-camera")
    assert spec.kind == "tactile_camera" and spec.settings is ArucoCameraSettings
    cam = spec.factory(ArucoCameraSettings(source=str(video)), None)
    assert isinstance(cam, ArucoCamera)


def test_scaled_is_identity_at_calibration_size():
    from weldcell.hal.readings import Intrinsics

    k = Intrinsics(640, 480, 450.0, 451.0, 320.0, 240.0)
    assert scaled(k, 640, 480) is k
    k2 = scaled(scaled(k, 1280, 960), 640, 480)
    assert (k2.fx, k2.cx, k2.cy) == pytest.approx((k.fx, k.cx, k.cy))
