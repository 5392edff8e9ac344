"""A RealSense ``.bag`` recording written the way librealsense's ``ros_writer`` (≤ 2.55, the RealSense
Viewer's format and that of Intel's sample recordings) wrote it, with rosbag's record structure and
librealsense's topics, types and md5sums (message definitions abbreviated): a ROS1 bag v2.0 (``#ROSBAG V2.0``,
file header record padded to 4096 bytes, chunks of connection + message-data records each followed by its
index-data records, then the connection and chunk-info records) holding the RealSense topic layout of
``src/media/ros/ros_file_format.h``: ``/file_version``, ``/device_0/info``, ``/device_0/sensor_N/info``,
``.../option/<Name>/value|description``, ``.../post_processing``, ``.../<Stream>_0/info`` (+ ``camera_info``),
``.../<Stream>_0/tf/0`` and the frames ``.../<Stream>_0/image/data`` + ``.../image/metadata``.

The scene is known: a D415-like "Stereo Module" (depth z16, depth units 0.1 mm) looking at a plane tilted
about y whose distance grows by ``STEP_M`` each frame (so the frame index can be read back from the
depth), with a square hole; an "RGB Camera" (rgb8) offset ``COLOR_OFFSET_X`` m along x with a colour
gradient. ``tf/0`` holds the extrinsics from the reference (depth) stream to each stream. No librealsense
is used to write the file.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SERIAL = "725112060411"
STEP_M = 0.01
COLOR_OFFSET_X = 0.05  # depth -> colour extrinsics: X_colour = X_depth + this (a D415 has ~0.015)

# type -> (md5sum, message definition); md5sums as compiled into librealsense (third-party/realsense-file)
_TYPES = {
    "std_msgs/UInt32": ("304a39449588c7f8ce2df6e8001c5fce", "uint32 data\n"),
    "std_msgs/Float32": ("73fcbf46b49191e672908e50842a83d4", "float32 data\n"),
    "std_msgs/String": ("992ce8a1687cec8c8bd883ec73ca41d1", "string data\n"),
    "diagnostic_msgs/KeyValue": ("cf57fdc6617a881a88c16e768132149c", "string key\nstring value\n"),
    "realsense_msgs/StreamInfo": (
        "311d7e24eac31bb87271d041bf70ff7d",
        "uint32 fps\nstring encoding\nbool is_recommended\n",
    ),
    "geometry_msgs/Transform": (
        "ac9eff44abf714214112b05d54a3cf9b",
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    ),
    "sensor_msgs/CameraInfo": (
        "c9a58c1b0b154e0e6da7578cb991d214",
        "Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] D\nfloat64[9] K\n"
        "float64[9] R\nfloat64[12] P\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n",
    ),
    "sensor_msgs/Image": (
        "060021388200f6f0f447d0fcd9c64743",
        "Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\n"
        "uint8[] data\n",
    ),
}
STATIC = (0, 1)  # ros::TIME_MIN: the stamp of everything that describes the device (not a frame)

# -- ROS1 serialisation (little endian) -----------------------------------------------------------------


def _u32(v: int) -> bytes:
    return struct.pack("<I", v)


def _str(s: str | bytes) -> bytes:
    b = s.encode() if isinstance(s, str) else s
    return _u32(len(b)) + b


def _time(t: tuple[int, int]) -> bytes:
    return struct.pack("<II", *t)


def _header(seq: int, stamp: tuple[int, int], frame_id: str) -> bytes:
    return _u32(seq) + _time(stamp) + _str(frame_id)


def _fields(**f: bytes) -> bytes:
    """A rosbag record/connection header: ``len name=value`` fields, sorted by name (a std::map)."""
    out = b""
    for name in sorted(f):
        item = name.encode() + b"=" + f[name]
        out += _u32(len(item)) + item
    return out


def _record(header: bytes, data: bytes) -> bytes:
    return _u32(len(header)) + header + _u32(len(data)) + data


def ros_time(ns: int) -> tuple[int, int]:
    return divmod(ns, 1_000_000_000)


# -- messages ---------------------------------------------------------------------------------------------


def key_value(key: str, value: str) -> bytes:
    return _str(key) + _str(value)


def transform(t: tuple[float, float, float], q: tuple[float, float, float, float]) -> bytes:
    return struct.pack("<7d", *t, *q)


def camera_info(w: int, h: int, f: float, cx: float, cy: float) -> bytes:
    k = (f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0)
    return (
        _header(0, (0, 0), "")
        + _u32(h)
        + _u32(w)
        + _str("Brown Conrady")
        + _u32(5)
        + struct.pack("<5d", *[0.0] * 5)
        + struct.pack("<9d", *k)
        + struct.pack("<9d", *[0.0] * 9)
        + struct.pack("<12d", *[0.0] * 12)
        + _u32(0)
        + _u32(0)
        + struct.pack("<4IB", 0, 0, 0, 0, 0)
    )


def image(seq: int, stamp_ms: float, pixels: np.ndarray, encoding: str, units: float | None) -> bytes:
    """``sensor_msgs/Image``; ``units`` set = the last ros_writer layout (frame_id "1" + trailing float32
    depth_units), None = older recorders (depth units only in the Depth_Units option)."""
    sec = int(stamp_ms // 1000)
    nsec = int(round((stamp_ms / 1000 - sec) * 1e9))
    h, w = pixels.shape[:2]
    step = pixels.strides[0]
    msg = _header(seq, (sec, nsec), "" if units is None else "1") + _u32(h) + _u32(w) + _str(encoding)
    msg += b"\x00" + _u32(step) + _str(np.ascontiguousarray(pixels).tobytes())
    return msg if units is None else msg + struct.pack("<f", units)


# -- the bag -------------------------------------------------------------------------------------------


class Bag1Writer:
    """Writes a ROS1 bag v2.0 (uncompressed chunks) as ``rosbag::Bag`` does; call ``close()`` to finish."""

    def __init__(self, path: str | Path, chunk_threshold: int = 768 * 1024) -> None:
        self.path = Path(path)
        self.chunk_threshold = chunk_threshold
        self._conns: dict[str, tuple[int, str]] = {}  # topic -> (id, type)
        self._chunks: list[bytes] = []  # finished chunk + index records
        self._chunk_infos: list[tuple[int, tuple, tuple, dict[int, int]]] = []
        self._pos = 13 + 4104  # after the version line and the padded file header record
        self._new_chunk()

    def _new_chunk(self) -> None:
        self._data = b""
        self._index: dict[int, list[tuple[tuple[int, int], int]]] = {}
        self._in_chunk: set[int] = set()

    def _conn_record(self, topic: str) -> bytes:
        cid, typ = self._conns[topic]
        md5, definition = _TYPES[typ]
        data = _fields(
            topic=topic.encode(),
            type=typ.encode(),
            md5sum=md5.encode(),
            message_definition=definition.encode(),
        )
        return _record(_fields(op=b"\x07", conn=_u32(cid), topic=topic.encode()), data)

    def write(self, topic: str, typ: str, t: tuple[int, int], msg: bytes) -> None:
        """One message on ``topic`` (ROS type ``typ``) at bag time ``t`` = (sec, nsec)."""
        if topic not in self._conns:
            self._conns[topic] = (len(self._conns), typ)
        cid = self._conns[topic][0]
        if cid not in self._in_chunk:  # rosbag repeats the connection record in every chunk using it
            self._data += self._conn_record(topic)
            self._in_chunk.add(cid)
        self._index.setdefault(cid, []).append((t, len(self._data)))
        self._data += _record(_fields(op=b"\x02", conn=_u32(cid), time=_time(t)), msg)
        if len(self._data) > self.chunk_threshold:
            self._flush_chunk()

    def _flush_chunk(self) -> None:
        if not self._index:
            return
        head = _fields(op=b"\x05", compression=b"none", size=_u32(len(self._data)))
        out = _record(head, self._data)
        times = [t for entries in self._index.values() for t, _ in entries]
        for cid, entries in sorted(self._index.items()):
            entries.sort()
            body = b"".join(_time(t) + _u32(off) for t, off in entries)
            head = _fields(op=b"\x04", ver=_u32(1), conn=_u32(cid), count=_u32(len(entries)))
            out += _record(head, body)
        counts = {cid: len(e) for cid, e in self._index.items()}
        self._chunk_infos.append((self._pos, min(times), max(times), counts))
        self._chunks.append(out)
        self._pos += len(out)
        self._new_chunk()

    def close(self) -> None:
        self._flush_chunk()
        index_pos = self._pos
        tail = b"".join(self._conn_record(topic) for topic in self._conns)
        for pos, start, end, counts in self._chunk_infos:
            head = _fields(
                op=b"\x06",
                ver=_u32(1),
                chunk_pos=struct.pack("<Q", pos),
                start_time=_time(start),
                end_time=_time(end),
                count=_u32(len(counts)),
            )
            tail += _record(head, b"".join(_u32(c) + _u32(n) for c, n in sorted(counts.items())))
        head = _fields(
            op=b"\x03",
            index_pos=struct.pack("<Q", index_pos),
            conn_count=_u32(len(self._conns)),
            chunk_count=_u32(len(self._chunk_infos)),
        )
        file_header = _u32(len(head)) + head + _u32(4096 - len(head)) + b" " * (4096 - len(head))
        self.path.write_bytes(b"#ROSBAG V2.0\n" + file_header + b"".join(self._chunks) + tail)


# -- the RealSense recording -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Scene:
    """Depth ``w x h`` (focal ``f``), colour ``cw x ch`` (focal ``cf``), depth units, rate."""

    w: int = 64
    h: int = 48
    f: float = 50.0
    cw: int = 80
    ch: int = 60
    cf: float = 60.0
    depth_units: float = 1e-4
    fps: int = 30

    def distance(self, k: int) -> float:
        """Plane distance on the optical axis in frame ``k`` (1-based) [m]."""
        return 0.6 + STEP_M * (k - 1)

    def depth_m(self, k: int) -> np.ndarray:
        """Frame ``k``: Z = d_k + 0.1 X (a plane tilted about y), 0 in the hole [5:10, 5:10]."""
        x = (np.arange(self.w)[None, :] - (self.w - 1) / 2) / self.f
        z = np.broadcast_to(self.distance(k) / (1.0 - 0.1 * x), (self.h, self.w)).copy()
        z[5:10, 5:10] = 0.0
        return z

    def depth_in_color_m(self, k: int) -> np.ndarray:
        """The same plane seen from the colour camera (X_c = X + COLOR_OFFSET_X): ground truth for align."""
        x = (np.arange(self.cw)[None, :] - (self.cw - 1) / 2) / self.cf
        z0 = self.distance(k) - 0.1 * COLOR_OFFSET_X
        return np.broadcast_to(z0 / (1.0 - 0.1 * x), (self.ch, self.cw)).copy()

    def color_rgb(self, k: int) -> np.ndarray:
        v, u = np.mgrid[0 : self.ch, 0 : self.cw]
        return np.stack([u * 3 % 256, v * 4 % 256, np.full_like(u, 10 * k % 256)], axis=2).astype(np.uint8)


_SENSORS = (("Stereo Module", "Depth", "mono16"), ("RGB Camera", "Color", "rgb8"))
_PP_BLOCKS = (
    ("Decimation Filter", "Threshold Filter", "Disparity Filter", "Spatial Filter", "Temporal Filter")
    + ("Hole Filling Filter", "Disparity Filter"),
    ("Decimation Filter",),
)


def _write_description(bag: Bag1Writer, s: Scene, file_version: int, sensors: int) -> None:
    bag.write("/file_version", "std_msgs/UInt32", STATIC, _u32(file_version))
    for key, value in (
        ("Name", "Intel RealSense D415"),
        ("Serial Number", SERIAL),
        ("Firmware Version", "05.12.07.100"),
        ("Product Id", "0AD3"),
        ("Product Line", "D400"),
    ):
        bag.write("/device_0/info", "diagnostic_msgs/KeyValue", STATIC, key_value(key, value))
    opts = (
        {"Depth Units": s.depth_units, "Stereo Baseline": 55.0, "Laser Power": 150.0},
        {"Exposure": 166.0},
    )
    intr = ((s.w, s.h, s.f), (s.cw, s.ch, s.cf))
    ext = (transform((0, 0, 0), (0, 0, 0, 1)), transform((COLOR_OFFSET_X, 0, 0), (0, 0, 0, 1)))
    for i, (name, stream, enc) in enumerate(_SENSORS[:sensors]):
        pre = f"/device_0/sensor_{i}"
        bag.write(f"{pre}/info", "diagnostic_msgs/KeyValue", STATIC, key_value("Name", name))
        for opt, value in opts[i].items():
            topic = f"{pre}/option/{opt.replace(' ', '_')}"
            bag.write(f"{topic}/value", "std_msgs/Float32", STATIC, struct.pack("<f", value))
            bag.write(f"{topic}/description", "std_msgs/String", STATIC, _str(f"{opt} of the {name}"))
        if file_version >= 4:
            for block in _PP_BLOCKS[i]:
                bag.write(f"{pre}/post_processing", "std_msgs/String", STATIC, _str(block))
        w, h, f = intr[i]
        info = _u32(s.fps) + _str(enc) + b"\x01"
        bag.write(f"{pre}/{stream}_0/info", "realsense_msgs/StreamInfo", STATIC, info)
        cam = camera_info(w, h, f, (w - 1) / 2, (h - 1) / 2)
        bag.write(f"{pre}/{stream}_0/info/camera_info", "sensor_msgs/CameraInfo", STATIC, cam)
        bag.write(f"{pre}/{stream}_0/tf/0", "geometry_msgs/Transform", STATIC, ext[i])


def write_d415_bag(
    path: str | Path,
    frames: int = 10,
    scene: Scene | None = None,
    units_in_frames: bool = True,
    file_version: int = 4,
    chunk_threshold: int = 768 * 1024,
    color: bool = True,
) -> Scene:
    """Record ``frames`` depth + colour framesets of the scene into ``path`` (``.bag``); returns the scene.

    ``units_in_frames=False`` and ``file_version=3`` give the layout of older recorders
    (depth units only in the Depth Units option);
    ``color=False`` records the depth sensor alone.
    """
    s = scene or Scene()
    bag = Bag1Writer(path, chunk_threshold)
    _write_description(bag, s, file_version, 2 if color else 1)
    for k in range(1, frames + 1):
        t = ros_time(1_000_000 + (k - 1) * 1_000_000_000 // s.fps)  # since the start of the recording
        stamp_ms = 1000.0 + (k - 1) * 1000.0 / s.fps  # the camera's hardware clock
        depth = np.round(s.depth_m(k) / s.depth_units).astype("<u2")
        for i, (pixels, units) in enumerate(
            ((depth, s.depth_units), (s.color_rgb(k), 0.0))[: 2 if color else 1]
        ):
            _, stream, enc = _SENSORS[i]
            pre = f"/device_0/sensor_{i}/{stream}_0/image"
            msg = image(k, stamp_ms, pixels, enc, units if units_in_frames else None)
            bag.write(f"{pre}/data", "sensor_msgs/Image", t, msg)
            for key, value in (
                ("system_time", f"{1.7e12 + stamp_ms:.6f}"),
                ("timestamp_domain", "Hardware Clock"),
                ("Frame Counter", str(k)),
                ("Frame Timestamp", str(int(stamp_ms * 1000))),
            ):
                bag.write(f"{pre}/metadata", "diagnostic_msgs/KeyValue", t, key_value(key, value))
    bag.close()
    return s
