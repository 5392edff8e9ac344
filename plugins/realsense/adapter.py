"""The RealSense adapter: a live camera or a recording through ``rs.pipeline``, or an injected
``rs.device`` (e.g. ``rs.software_device``) whose sensors stream into an ``rs.syncer``.

Frame path (both sources): [align depth to colour] -> decimation -> depth-to-disparity -> spatial ->
temporal -> disparity-to-depth -> ``z16 * depth_scale`` (metres, float32). Intrinsics come from the
processed depth frame's stream profile, so they follow alignment and decimation.
"""

from __future__ import annotations

import time
from datetime import timedelta
from pathlib import Path

import numpy as np
import pyrealsense2 as rs
from weldcell.hal.interfaces import DepthCamera
from weldcell.hal.readings import DepthFrame, Intrinsics
from weldcell.plugins.realsense.settings import RealSenseSettings
from weldcell.sdk.errors import DeviceError

_PRESETS = {"custom": 0, "default": 1, "hand": 2, "high_accuracy": 3, "high_density": 4, "medium_density": 5}
_USB_FIX = (
    "check the USB 3 cable and port (a USB 2 link cannot carry these streams), that no other program "
    "holds the camera, and the resolution/fps pair is supported"
)
_AGAIN = "; then recover() and configure() again"
_BAG_MAGIC = b"#ROSBAG V2.0"  # ROS1 bag: the RealSense Viewer / rs.recorder before librealsense 2.56
_DB3_MAGIC = b"SQLite format 3\x00"  # ROS2 bag (sqlite3): rs.recorder from librealsense 2.56 on
_DAMAGED_FIX = (
    "the file is truncated or damaged (a recording whose recorder was killed has no index): copy it "
    "again or record it again"
)


def _version() -> tuple[int, ...]:
    return tuple(int(p) for p in rs.__version__.split(".")[:2])


def check_recording(path: Path) -> None:
    """DeviceError unless ``path`` is a recording this librealsense can open by its name and contents.

    librealsense picks its reader by the suffix alone (``.bag``/``.BAG`` -> ROS1, else ROS2 ``.db3``).
    """
    if not path.is_file():
        raise DeviceError(f"recording {path} does not exist", "give the path of a .bag/.db3 recording")
    with path.open("rb") as f:
        head = f.read(16)
    named_bag = path.suffix in (".bag", ".BAG")
    if head.startswith(b"#ROSBAG V") and not head.startswith(_BAG_MAGIC):
        raise DeviceError(
            f"recording {path} is a ROS1 bag of format {head[9:12].decode(errors='replace')}, not 2.0",
            "librealsense reads bag format 2.0 only: give a recording of the RealSense Viewer or rs.recorder",
        )
    if head.startswith(_BAG_MAGIC) and not named_bag:
        raise DeviceError(
            f"recording {path} is a ROS1 .bag file but its name does not end in .bag",
            "rename it to end in .bag (librealsense chooses its reader by the file name)",
        )
    if head.startswith(_DB3_MAGIC) and named_bag:
        raise DeviceError(
            f"recording {path} is a ROS2 .db3 recording but its name ends in .bag",
            "rename it to end in .db3 (librealsense chooses its reader by the file name)",
        )
    if head.startswith(_DB3_MAGIC) and _version() < (2, 56):
        raise DeviceError(
            f"recording {path} is a .db3 (ROS2) recording; librealsense {rs.__version__} reads only .bag",
            "pip install 'pyrealsense2>=2.56' (reads .db3 and .bag), or record with this version (.bag)",
        )
    if not head.startswith((_BAG_MAGIC, _DB3_MAGIC)):
        what = "is empty" if not head else "is neither a ROS1 .bag nor a ROS2 .db3 file"
        raise DeviceError(
            f"recording {path} {what}", f"give a RealSense recording; if it was one, {_DAMAGED_FIX}"
        )


def unreadable(path: Path, e: RuntimeError) -> DeviceError:
    """librealsense's refusal to open a recording, reworded (its reason kept)."""
    reason = str(e).split("Reason: ", 1)[-1]
    return DeviceError(f"recording {path} cannot be read: {reason}", _DAMAGED_FIX)


def _stream_text(p) -> str:
    fmt = str(p.format()).split(".")[-1]
    size = ""
    if p.is_video_stream_profile():
        v = p.as_video_stream_profile()
        size = f" {v.width()}x{v.height()}"
    return f"{p.stream_name().lower()}{size} {fmt} @ {p.fps()} Hz"


def describe_recording(path: Path) -> str:
    """The recorded camera, duration and streams of a recording; DeviceError when it cannot be read."""
    check_recording(path)
    ctx = rs.context()
    try:
        dev = ctx.load_device(str(path))
    except RuntimeError as e:
        raise unreadable(path, e) from None
    try:
        info = [
            dev.get_info(i) for i in (rs.camera_info.name, rs.camera_info.serial_number) if dev.supports(i)
        ]
        streams = [_stream_text(p) for s in dev.query_sensors() for p in s.get_stream_profiles()]
        seconds = dev.as_playback().get_duration().total_seconds()
    finally:
        ctx.unload_device(str(path))
    return f"recording {path}: {' #'.join(info)}, {seconds:.3g} s; {', '.join(streams)}"


def connected_cameras(ctx) -> dict[str, str]:
    """Serial number -> product name of every connected RealSense."""
    out = {}
    for dev in ctx.query_devices():
        try:
            out[dev.get_info(rs.camera_info.serial_number)] = dev.get_info(rs.camera_info.name)
        except RuntimeError:
            continue
    return out


def to_intrinsics(i) -> Intrinsics:
    """weldcell intrinsics from ``rs.intrinsics`` (coefficients in the Brown-Conrady order k1 k2 p1 p2 k3)."""
    return Intrinsics(
        int(i.width),
        int(i.height),
        float(i.fx),
        float(i.fy),
        float(i.ppx),
        float(i.ppy),
        tuple(float(c) for c in i.coeffs),
    )


class RealSenseCamera(DepthCamera):
    """A RealSense depth camera (device ``camera.realsense``).

    ``context`` replaces the librealsense context (device enumeration); ``device`` streams an
    injected ``rs.device`` (e.g. an ``rs.software_device``) through an ``rs.syncer`` instead of a pipeline.
    """

    def __init__(
        self,
        settings: RealSenseSettings | None = None,
        name: str = "camera",
        frame: str | None = None,
        context=None,
        device=None,
    ) -> None:
        super().__init__(name, frame=frame or f"{name}.optical")
        self.settings = settings or RealSenseSettings()
        self._ctx = context
        self._device = device
        self._pipe = None
        self._cfg = None
        self._profile = None
        self._syncer = None
        self._open_sensors: list = []
        self._depth_profile = None
        self._scale = 0.001
        self._intr: Intrinsics | None = None
        self._align = None
        self._filters: list = []
        self._dev = None
        self._framesets = 0

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        s = self.settings
        if s.align_to_color and not s.color:
            raise DeviceError(
                "align_to_color needs the colour stream", "set color = true or align_to_color = false"
            )
        if self._device is not None:
            self._configure_injected()
        else:
            self._configure_pipeline()
        self._build_processing()

    def _configure_pipeline(self) -> None:
        s = self.settings
        ctx = self._ctx or rs.context()
        cfg = rs.config()
        if s.recording:
            check_recording(Path(s.recording))
            cfg.enable_device_from_file(s.recording, repeat_playback=s.playback_repeat)
        else:
            cams = connected_cameras(ctx)
            if s.serial and s.serial not in cams:
                listed = ", ".join(f"{k} ({v})" for k, v in cams.items()) or "none"
                raise DeviceError(
                    f"no RealSense with serial {s.serial} is connected (connected: {listed})",
                    "set serial to one of the connected cameras, or plug the camera in",
                )
            if not cams:
                raise DeviceError("no RealSense camera is connected", _USB_FIX)
            if not s.serial and len(cams) > 1:
                raise DeviceError(
                    f"{len(cams)} RealSense cameras are connected ({', '.join(cams)})",
                    "set serial to the one to use",
                )
            cfg.enable_device(s.serial or next(iter(cams)))
        if not s.recording:
            cfg.enable_stream(rs.stream.depth, s.depth_width, s.depth_height, rs.format.z16, s.depth_fps)
            if s.color:
                cfg.enable_stream(rs.stream.color, s.color_width, s.color_height, rs.format.rgb8, s.color_fps)
        pipe = rs.pipeline(ctx)
        try:
            profile = cfg.resolve(rs.pipeline_wrapper(pipe))
        except RuntimeError as e:
            if s.recording:
                raise unreadable(Path(s.recording), e) from None
            raise DeviceError(f"the camera cannot stream the requested configuration: {e}", _USB_FIX) from e
        self._pipe, self._cfg = pipe, cfg
        self._dev = profile.get_device()
        if s.recording:
            self._check_recorded_streams(profile)
            self._dev.as_playback().set_real_time(s.playback_realtime)  # before start: no frame dropped
        depth = profile.get_stream(rs.stream.depth).as_video_stream_profile()
        self._depth_profile = depth
        self._intr = to_intrinsics(depth.get_intrinsics())
        sensor = self._dev.first_depth_sensor()
        self._scale = float(sensor.get_depth_scale())
        if not s.recording:
            self._apply_options(sensor)

    def _check_recorded_streams(self, profile) -> None:
        s = self.settings
        streams = {p.stream_type() for p in profile.get_streams()}
        held = ", ".join(_stream_text(p) for p in profile.get_streams()) or "no streams"
        if rs.stream.depth not in streams:
            raise DeviceError(
                f"recording {s.recording} has no depth stream (it holds {held})",
                "record the camera with its depth stream enabled",
            )
        if s.color and rs.stream.color not in streams:
            raise DeviceError(
                f"recording {s.recording} has no colour stream (it holds {held})",
                "set color = false to play its depth alone",
            )

    def _configure_injected(self) -> None:
        s = self.settings
        dev = self._device
        self._dev = dev
        wanted = [(rs.stream.depth, s.depth_width, s.depth_height, s.depth_fps)]
        if s.color:
            wanted.append((rs.stream.color, s.color_width, s.color_height, s.color_fps))
        self._open_sensors = []
        for stream, w, h, fps in wanted:
            found = None
            for sensor in dev.query_sensors():
                for p in sensor.get_stream_profiles():
                    v = p.as_video_stream_profile()
                    if p.stream_type() == stream and (v.width(), v.height(), p.fps()) == (w, h, fps):
                        found = (sensor, p)
            if found is None:
                raise DeviceError(
                    f"the device has no {stream} stream {w}x{h} @ {fps} fps",
                    "choose a resolution/fps the device offers",
                )
            self._open_sensors.append(found)
        depth_sensor = self._open_sensors[0][0]
        self._depth_profile = self._open_sensors[0][1].as_video_stream_profile()
        self._intr = to_intrinsics(self._depth_profile.get_intrinsics())
        self._scale = float(depth_sensor.get_option(rs.option.depth_units))
        self._apply_options(depth_sensor)

    def _apply_options(self, sensor) -> None:
        s = self.settings
        opts = []
        if s.preset is not None:
            opts.append((rs.option.visual_preset, float(_PRESETS[s.preset]), f"preset {s.preset}"))
        if s.emitter_enabled is not None:
            opts.append((rs.option.emitter_enabled, float(s.emitter_enabled), "emitter_enabled"))
        if s.laser_power is not None:
            opts.append((rs.option.laser_power, float(s.laser_power), "laser_power"))
        for opt, value, what in opts:
            if not sensor.supports(opt):
                raise DeviceError(
                    f"this camera's depth sensor has no {what} option",
                    f"remove {what.split()[0]} from the camera settings",
                )
            r = sensor.get_option_range(opt)
            if not (r.min - 1e-9 <= value <= r.max + 1e-9):
                raise DeviceError(
                    f"{what} = {value:g} is outside the camera's range [{r.min:g}, {r.max:g}]",
                    "choose a value inside the range",
                )
            if r.step > 0 and abs((value - r.min) / r.step - round((value - r.min) / r.step)) > 1e-6:
                raise DeviceError(
                    f"{what} = {value:g} is not on the camera's grid ({r.min:g} + k * {r.step:g})",
                    f"use a multiple of {r.step:g} from {r.min:g}",
                )
            try:
                sensor.set_option(opt, value)
            except RuntimeError as e:
                raise DeviceError(
                    f"the camera refused {what} = {value:g}: {e}", "choose another value"
                ) from e

    def _build_processing(self) -> None:
        s = self.settings
        self._align = rs.align(rs.stream.color) if s.align_to_color else None
        f = []
        if s.decimation > 1:
            dec = rs.decimation_filter()
            dec.set_option(rs.option.filter_magnitude, float(s.decimation))
            f.append(dec)
        if s.spatial_filter or s.temporal_filter:
            f.append(rs.disparity_transform(True))
            if s.spatial_filter:
                f.append(rs.spatial_filter())
            if s.temporal_filter:
                f.append(rs.temporal_filter())
            f.append(rs.disparity_transform(False))
        self._filters = f

    def on_activate(self) -> None:
        s = self.settings
        self._framesets = 0
        if self._pipe is not None:
            try:
                self._profile = self._pipe.start(self._cfg)
            except RuntimeError as e:
                raise DeviceError(f"the camera did not start: {e}", _USB_FIX) from e
            if not s.recording:
                for _ in range(s.warmup_frames):
                    self._wait(s.start_timeout)
        else:
            self._syncer = rs.syncer(4)
            for sensor, p in self._open_sensors:
                sensor.open(p)
            for sensor, _ in self._open_sensors:
                sensor.start(self._syncer)

    def on_deactivate(self) -> None:
        self._stop_streaming()

    def _stop_streaming(self) -> None:
        if self._pipe is not None and self._profile is not None:
            try:
                self._pipe.stop()
            except RuntimeError:
                pass
            self._profile = None
        if self._syncer is not None:
            for sensor, _ in self._open_sensors:
                for fn in (sensor.stop, sensor.close):
                    try:
                        fn()
                    except RuntimeError:
                        pass
            self._syncer = None

    def on_close(self) -> None:
        self._stop_streaming()
        self._pipe = self._cfg = self._dev = None

    def on_recover(self) -> None:
        """Stop everything; ``configure()`` opens the camera again."""
        self.on_close()

    # -- frames ----------------------------------------------------------------------------------
    def _wait(self, timeout: float):
        src = self._pipe if self._syncer is None else self._syncer
        ok, fs = src.try_wait_for_frames(int(max(1.0, timeout * 1000)))
        if ok:
            return fs
        if not (self.settings.recording and self._profile is not None):
            raise self._fault(f"no frames from the camera within {timeout:.3g} s", _USB_FIX + _AGAIN)
        pb = self._profile.get_device().as_playback()
        if self.settings.playback_repeat and pb.current_status() == rs.playback_status.stopped:
            # librealsense's own repeat can stop at the end of the file when playback is not real-time and
            # the host is loaded (reproduced: 2 of 30 runs of 40 captures of a 6-frame recording with the
            # CPU saturated); a repeating recording is started again from its beginning here instead
            pb.seek(timedelta(0))
            pb.resume()
            ok, fs = src.try_wait_for_frames(int(max(1.0, timeout * 1000)))
            if ok:
                return fs
        rec, n = self.settings.recording, self._framesets
        length = f"{pb.get_duration().total_seconds():.3g} s recorded"
        if pb.current_status() == rs.playback_status.stopped:
            raise self._fault(
                f"the recording {rec} has ended after {n} framesets ({length})",
                "set playback_repeat = true to loop it; recover() and configure() to play it again",
            )
        raise self._fault(
            f"the recording {rec} delivered no frame within {timeout:.3g} s while playing, after {n} "
            f"framesets ({length}): a gap in the recording, or the file is damaged there",
            f"allow a longer timeout for a gap; otherwise {_DAMAGED_FIX}{_AGAIN}",
        )

    def _fault(self, message: str, fix: str) -> DeviceError:
        """Enter ERROR with ``message``; the error to raise carries ``fix``."""
        return DeviceError(self.fault(message).message, fix)

    def _in_step(self, depth, color) -> bool:
        """Depth and colour within half a frame period, librealsense's own matching rule (a repeating
        recording can pair its last depth with its first colour frame); different clock domains pass."""
        if depth.get_frame_timestamp_domain() != color.get_frame_timestamp_domain():
            return True
        period_ms = 1000.0 / max(1, min(depth.profile.fps(), color.profile.fps()))
        return abs(depth.get_timestamp() - color.get_timestamp()) < period_ms / 2

    def _next_frameset(self, timeout: float):
        """The next frameset holding depth (and, when streamed, colour of the same instant); others are
        skipped."""
        deadline = time.monotonic() + timeout
        while True:
            fs = self._wait(max(0.001, deadline - time.monotonic()))
            depth, color = fs.get_depth_frame(), fs.get_color_frame()
            if depth and (not self.settings.color or (color and self._in_step(depth, color))):
                self._framesets += 1
                return fs
            if time.monotonic() >= deadline:
                what = "depth and colour" if self.settings.color else "depth"
                raise self._fault(
                    f"no frameset with {what} of the same instant within {timeout:.3g} s", _USB_FIX + _AGAIN
                )

    def _capture(self, timeout: float) -> DepthFrame:
        fs = self._next_frameset(timeout)
        stamp = time.time()
        if self._align is not None:
            fs = self._align.process(fs)
        depth = fs.get_depth_frame()
        f = depth
        for flt in self._filters:
            f = flt.process(f)
        f = f.as_depth_frame()
        z = np.asanyarray(f.get_data()).astype(np.float32) * np.float32(self._scale)
        self._intr = to_intrinsics(f.profile.as_video_stream_profile().get_intrinsics())
        color = None
        c = fs.get_color_frame() if self.settings.color else None
        if c:
            color = np.asanyarray(c.get_data()).copy()
        meta = {
            "frame_number": int(depth.get_frame_number()),
            "device_timestamp_ms": float(depth.get_timestamp()),
            "depth_scale": self._scale,
            "aligned_to_color": self._align is not None,
        }
        return DepthFrame(
            stamp=stamp, depth=z, intrinsics=self._intr, frame=self.frame, color=color, meta=meta
        )

    def _intrinsics(self) -> Intrinsics:
        if self._intr is None:
            raise DeviceError(
                f"camera '{self.name}' has no intrinsics before configure()", "configure() it first"
            )
        return self._intr
