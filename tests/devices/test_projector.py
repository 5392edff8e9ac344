"""The window projector (projector.window): a real pygame fullscreen window on an Xvfb X server, checked
by screenshots of that server against images rendered independently here (pinhole maths + cv2 lines)."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

pytest.importorskip("pygame", reason="pygame is not installed (pip install 'weldcell[projector]')")
ImageGrab = pytest.importorskip("PIL.ImageGrab", reason="Pillow is needed for screenshots")

from weldcell.hal.lifecycle import State  # noqa: E402
from weldcell.plugins.projector import render, world_pose  # noqa: E402
from weldcell.plugins.projector.adapter import WindowProjector  # noqa: E402
from weldcell.plugins.projector.settings import WindowProjectorSettings  # noqa: E402
from weldcell.sdk.errors import DeviceError  # noqa: E402
from weldcell.sdk.geometry import T_from_rpy  # noqa: E402
from weldcell.testing.conformance import LaserProjectorConformance  # noqa: E402

W, H = 848, 480
# looking straight down at the table from 1 m: optical z = -world z, x = world x, y = -world y
T_WP = T_from_rpy((np.pi, 0.0, 0.0), (0.3, 0.1, 1.0))


@pytest.fixture(scope="module")
def xvfb():
    exe = shutil.which("Xvfb")
    if exe is None:
        pytest.skip("Xvfb is not installed (bootstrap.sh installs it; apt-get install xvfb)")
    r, w = os.pipe()  # -displayfd: Xvfb picks a free display number itself and writes it here
    proc = subprocess.Popen(
        [exe, "-displayfd", str(w), "-screen", "0", f"{W}x{H}x24", "-nolisten", "tcp", "-noreset"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        pass_fds=(w,),
    )
    os.close(w)
    with os.fdopen(r) as f:
        number = f.readline().strip()
    if not number or proc.poll() is not None:
        proc.kill()
        pytest.skip("Xvfb did not start")
    old = {k: os.environ.get(k) for k in ("DISPLAY", "SDL_VIDEODRIVER")}
    os.environ["DISPLAY"], os.environ["SDL_VIDEODRIVER"] = f":{number}", "x11"
    yield f":{number}"
    for k, v in old.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    proc.terminate()
    proc.wait(5)


def make(settings=None, pose=T_WP) -> WindowProjector:
    return WindowProjector(settings or WindowProjectorSettings(), name="proj", T_world_projector=lambda: pose)


def screenshot(display: str) -> np.ndarray:
    for _ in range(20):  # the X server composes asynchronously: wait until the frame shows
        img = np.asarray(ImageGrab.grab(xdisplay=display).convert("RGB"))
        if img.any():
            return img
        time.sleep(0.02)
    return img


def expected(
    segments: np.ndarray, T: np.ndarray, fx=1000.0, fy=1000.0, cx=W / 2, cy=H / 2, width=2, dist=None
):
    """The image a pinhole projector at T must show: written out here, independent of the adapter."""
    img = np.zeros((H, W, 3), np.uint8)
    R, t = T[:3, :3], T[:3, 3]
    for a, b in segments:
        pts = a + np.linspace(0, 1, 200)[:, None] * (b - a)
        pc = (pts - t) @ R  # world -> projector
        pc = pc[pc[:, 2] > 0.05]
        if dist is None:
            uv = np.column_stack([fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy])
        else:
            K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
            uv = cv2.projectPoints(pc, np.zeros(3), np.zeros(3), K, np.asarray(dist))[0].reshape(-1, 2)
        cv2.polylines(img, [np.round(uv * 16).astype(np.int32)], False, (0, 255, 0), width, cv2.LINE_AA, 4)
    return img


def overlap(shot: np.ndarray, want: np.ndarray) -> tuple[float, float]:
    """(share of expected line pixels that are lit, share of lit pixels that are expected)."""
    s = shot.max(axis=2) > 80
    e = want.max(axis=2) > 80
    s_d = cv2.dilate(s.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    e_d = cv2.dilate(e.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    return float((e & s_d).sum() / max(e.sum(), 1)), float((s & e_d).sum() / max(s.sum(), 1))


SQUARE = np.array(
    [
        [[0.2, 0.0, 0.0], [0.4, 0.0, 0.0]],
        [[0.4, 0.0, 0.0], [0.4, 0.2, 0.0]],
        [[0.4, 0.2, 0.0], [0.2, 0.2, 0.0]],
        [[0.2, 0.2, 0.0], [0.2, 0.0, 0.0]],
        [[0.2, 0.0, 0.0], [0.4, 0.2, 0.0]],
        [[0.3, 0.1, 0.0], [0.3, 0.1, 0.9]],  # towards the lens: clipped at the near plane
    ]
)


class TestWindowProjectorConformance(LaserProjectorConformance):
    @pytest.fixture
    def device(self, xvfb):
        return make()

    @pytest.fixture
    def break_device(self):
        def brk(dev):
            import pygame

            pygame.display.quit()  # the display output went away

        return brk


def test_projected_lines_land_where_the_pinhole_model_says(xvfb):
    with make() as p:
        p.project(SQUARE, label="member m1")
        shot = screenshot(xvfb)
    want = expected(SQUARE, T_WP)
    recall, precision = overlap(shot, want)
    assert recall >= 0.9 and precision >= 0.9, (recall, precision)
    lit = shot[shot.max(axis=2) > 200]
    assert len(lit) > 500 and np.all(lit[:, 1] > 200) and np.all(lit[:, 0] < 60), "green lines on black"
    assert shot[0:40, 0:40].max() == 0


def test_clear_and_deactivate_go_dark(xvfb):
    with make() as p:
        p.project(SQUARE)
        assert screenshot(xvfb).any()
        p.clear()
        time.sleep(0.05)
        assert np.asarray(ImageGrab.grab(xdisplay=xvfb)).max() == 0


BIG = np.array(  # reaches the image corners, where distortion moves pixels by tens of pixels
    [
        [[-0.03, -0.08, 0.0], [0.63, -0.08, 0.0]],
        [[0.63, -0.08, 0.0], [0.63, 0.28, 0.0]],
        [[0.63, 0.28, 0.0], [-0.03, 0.28, 0.0]],
        [[-0.03, 0.28, 0.0], [-0.03, -0.08, 0.0]],
    ]
)


def test_distortion_and_offset_principal_point(xvfb):
    dist = (-0.25, 0.08, 0.0, 0.0)
    s = WindowProjectorSettings(fx=900.0, fy=920.0, cx=400.0, cy=260.0, dist=dist, line_width=3)
    with make(s) as p:
        p.project(BIG)
        shot = screenshot(xvfb)
    recall, precision = overlap(shot, expected(BIG, T_WP, 900.0, 920.0, 400.0, 260.0, 3, dist))
    assert recall >= 0.9 and precision >= 0.9, (recall, precision)
    r_nodist, _ = overlap(shot, expected(BIG, T_WP, 900.0, 920.0, 400.0, 260.0, 3, None))
    assert r_nodist < 0.6, "the undistorted model would not match"


def test_clip_segments_to_the_frustum():
    from weldcell.hal.readings import Intrinsics

    k = Intrinsics(W, H, 1000.0, 1000.0, W / 2, H / 2)
    planes = render.frustum_planes(k, 0.05)
    seg = np.array(
        [
            [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]],  # through the lens: front half kept
            [[0.0, 0.0, 1.0], [5.0, 0.0, 1.0]],  # leaves the image on the right at u = W
            [[0.0, 0.0, -2.0], [0.1, 0.0, -1.0]],
        ]
    )  # behind: dropped
    out = render.clip_segments(seg, planes)
    assert len(out) == 2
    np.testing.assert_allclose(out[0], [[0, 0, 0.05], [0, 0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(out[1][1], [W / 2 / 1000.0, 0.0, 1.0], atol=1e-12)


def test_flange_mounted_projector_follows_the_robot(xvfb):
    class Arm:
        T_world_base = T_from_rpy((0, 0, 0), (0.0, 0.0, 0.0))

        def __init__(self):
            self.T = T_from_rpy((np.pi, 0, 0), (0.3, 0.1, 1.0))

        def state(self):
            return SimpleNamespace(T_base_flange=self.T)

    arm = Arm()
    mount = SimpleNamespace(parent="world", xyz=(0, 0, 0), rpy=(0, 0, 0))
    ctx = SimpleNamespace(
        role="proj",
        profile=SimpleNamespace(profile=SimpleNamespace(devices={"robot": SimpleNamespace(mount=mount)})),
        device=lambda role: arm,
    )
    T_fp = T_from_rpy((0, 0, 0), (0.0, 0.05, 0.0))
    pose = world_pose(ctx, "robot.flange")
    with WindowProjector(WindowProjectorSettings(), "proj", lambda: pose() @ T_fp) as p:
        p.project(SQUARE)
        a = screenshot(xvfb)
        arm.T = T_from_rpy((np.pi, 0, 0), (0.35, 0.1, 1.0))
        p.project(SQUARE)
        time.sleep(0.05)
        b = screenshot(xvfb)
    for shot, T in (
        (a, T_from_rpy((np.pi, 0, 0), (0.3, 0.1, 1.0)) @ T_fp),
        (b, T_from_rpy((np.pi, 0, 0), (0.35, 0.1, 1.0)) @ T_fp),
    ):
        recall, precision = overlap(shot, expected(SQUARE, T))
        assert recall >= 0.9 and precision >= 0.9


def test_missing_display_output_is_named(xvfb):
    p = make(WindowProjectorSettings(display=3))
    with pytest.raises(DeviceError) as e:
        p.configure()
    assert "display 3 does not exist" in e.value.message and "848x480" in e.value.message
    assert p.lifecycle is State.ERROR
    p.close()


def test_check_devices_run_with_an_abb_arm_carrying_the_projector(xvfb, weldcell_pm, tmp_path, monkeypatch):
    """A real run (profile -> plugins -> factories): the ABB adapter against its RWS/EGM peers, its
    password from the environment, and the projector mounted on its flange."""
    pytest.importorskip("abb_robot_client", reason="abb-robot-client is not installed")
    from peers_abb import AbbPeer, free_udp_port
    from weldcell.plugins import abb as abb_plugin
    from weldcell.plugins import device_check
    from weldcell.plugins import projector as projector_plugin
    from weldcell.sdk.jobs import run_job

    for mod, name in ((abb_plugin, "abb"), (projector_plugin, "projector"), (device_check, "device_check")):
        weldcell_pm.register(mod, name, distribution="weldcell")
    port = free_udp_port()
    peer = AbbPeer(port, password="pw-from-env-123")
    monkeypatch.setenv("WELDCELL_TEST_ABB_PW", "pw-from-env-123")
    profile = tmp_path / "abb-projector.toml"
    profile.write_text(
        f"""schema = "weldcell/profile@1"
name = "abb-projector"
[job]
name = "check-devices"
[devices.arm]
plugin = "robot.abb-rws"
[devices.arm.settings]
url = "{peer.url}"
password = "${{env:WELDCELL_TEST_ABB_PW}}"
egm_host = "127.0.0.1"
egm_port = {port}
[devices.proj]
plugin = "projector.window"
[devices.proj.mount]
parent = "arm.flange"
xyz = [0.0, 0.05, 0.0]
"""
    )
    try:
        run, result = run_job(profile, weldcell_pm, runs_dir=tmp_path / "runs")
    finally:
        peer.close()
    import json

    devices = json.loads((run / "devices.json").read_text())
    assert devices["arm"]["ok"] and devices["proj"]["ok"], devices
    for f in run.rglob("*"):
        if f.is_file() and f.suffix in (".json", ".txt", ".toml", ".log"):
            assert "pw-from-env-123" not in f.read_text(errors="ignore"), f
