"""A RealSense D415 stand-in built on pyrealsense2's ``software_device`` (librealsense's own test path):
depth (z16) + colour (rgb8) sensors with intrinsics, the depth sensor's options, and a feeder thread
pushing a known scene through ``on_video_frame``. ``record()`` writes a real librealsense recording."""

from __future__ import annotations

import threading
import time

import numpy as np
import pyrealsense2 as rs

SERIAL = "815412070123"


def _intr(w: int, h: int, f: float, cx: float, cy: float) -> rs.intrinsics:
    i = rs.intrinsics()
    i.width, i.height, i.fx, i.fy, i.ppx, i.ppy = w, h, f, f, cx, cy
    i.model = rs.distortion.brown_conrady
    i.coeffs = [0.0] * 5
    return i


def _range(lo: float, hi: float, step: float, default: float) -> rs.option_range:
    r = rs.option_range()  # set fields by name: the 4-argument constructor swaps step and default
    r.min, r.max, r.step, r.default = lo, hi, step, default
    return r


class SoftwareD415:
    """Depth ``w x h`` (f=``f``) and colour ``cw x ch`` (f=``cf``); the scene is ``depth_m(u, v)``."""

    def __init__(
        self,
        w: int = 64,
        h: int = 48,
        f: float = 50.0,
        cw: int = 80,
        ch: int = 60,
        cf: float = 60.0,
        depth_units: float = 1e-4,
        fps: int = 30,
    ) -> None:
        self.w, self.h, self.f, self.cw, self.ch, self.cf = w, h, f, cw, ch, cf
        self.depth_units = depth_units
        self.dev = rs.software_device()
        self.dev.register_info(rs.camera_info.serial_number, SERIAL)
        self.dev.register_info(rs.camera_info.name, "Intel RealSense D415 (software device)")
        self.depth_sensor = self.dev.add_sensor("Stereo Module")
        self.color_sensor = self.dev.add_sensor("RGB Camera")
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp = rs.stream.depth, 0, 0, w, h, fps, 2
        vs.fmt, vs.intrinsics = rs.format.z16, _intr(w, h, f, (w - 1) / 2, (h - 1) / 2)
        self.depth_profile = self.depth_sensor.add_video_stream(vs)
        cs = rs.video_stream()
        cs.type, cs.index, cs.uid, cs.width, cs.height, cs.fps, cs.bpp = rs.stream.color, 0, 1, cw, ch, fps, 3
        cs.fmt, cs.intrinsics = rs.format.rgb8, _intr(cw, ch, cf, (cw - 1) / 2, (ch - 1) / 2)
        self.color_profile = self.color_sensor.add_video_stream(cs)
        ext = rs.extrinsics()
        ext.rotation, ext.translation = [1, 0, 0, 0, 1, 0, 0, 0, 1], [0.0, 0.0, 0.0]
        self.depth_profile.register_extrinsics_to(self.color_profile, ext)
        self.dev.create_matcher(rs.matchers.dlr_c)  # depth + colour framesets, as a D400 pairs them
        self.depth_sensor.add_read_only_option(rs.option.depth_units, depth_units)
        self.depth_sensor.add_option(rs.option.laser_power, _range(0, 360, 30, 150), True)
        self.depth_sensor.add_option(rs.option.visual_preset, _range(0, 5, 1, 1), True)
        self.n = 0
        self.feeding = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(1.0 / fps,), daemon=True)
        self._thread.start()

    # -- the scene -----------------------------------------------------------------------------------
    def depth_m(self) -> np.ndarray:
        """A plane tilted about y (0.6 m at the centre, +0.1 m per unit of x/z) with a square hole."""
        u = np.arange(self.w)[None, :]
        x = (u - (self.w - 1) / 2) / self.f
        z = np.broadcast_to(0.6 / (1.0 - 0.1 * x), (self.h, self.w)).copy()
        z[5:10, 5:10] = 0.0
        return z

    def color_rgb(self) -> np.ndarray:
        v, u = np.mgrid[0 : self.ch, 0 : self.cw]
        return np.stack([u * 3 % 256, v * 4 % 256, np.full_like(u, 77)], axis=2).astype(np.uint8)

    def feed_one(self) -> None:
        self.n += 1
        t = self.n * 33.333
        d = np.round(self.depth_m() / self.depth_units).astype(np.uint16)
        for sensor, profile, pixels, bpp in (
            (self.depth_sensor, self.depth_profile, d, 2),
            (self.color_sensor, self.color_profile, self.color_rgb(), 3),
        ):
            fr = rs.software_video_frame()
            fr.pixels, fr.bpp, fr.stride = pixels, bpp, pixels.shape[1] * bpp
            fr.timestamp, fr.domain, fr.frame_number = t, rs.timestamp_domain.hardware_clock, self.n
            fr.profile = profile.as_video_stream_profile()
            if bpp == 2:
                fr.depth_units = self.depth_units
            sensor.on_video_frame(fr)

    def _run(self, period: float) -> None:
        while not self._stop.is_set():
            if self.feeding.is_set():
                try:
                    self.feed_one()
                except RuntimeError:
                    pass
            time.sleep(period / 2)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1)

    def record(self, path: str, frames: int = 12) -> None:
        """Record ``frames`` depth frames into a librealsense recording at ``path``."""
        rec = rs.recorder(path, self.dev)
        sensors = rec.query_sensors()
        depth = next(s for s in sensors if s.get_stream_profiles()[0].stream_type() == rs.stream.depth)
        got: list[int] = []
        depth.open(depth.get_stream_profiles()[0])
        depth.start(lambda f: got.append(f.get_frame_number()))
        for _ in range(frames):
            self.feed_one()
            time.sleep(0.005)
        deadline = time.time() + 2
        while len(got) < frames and time.time() < deadline:
            time.sleep(0.01)
        depth.stop()
        depth.close()
        del depth, sensors, rec
