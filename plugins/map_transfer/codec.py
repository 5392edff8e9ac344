"""Segment encodings: ``quantised`` (the default: a <= 1 mm grid, delta-coded and deflated, see
:mod:`~weldcell.plugins.map_transfer.quantised` for why it replaced Draco as default), plain binary PLY
(lossless) and Draco (quantised, made for point clouds).

Draco quantises each coordinate on a grid of ``2**bits - 1`` steps over the segment's largest extent
(``range``), so the error of one coordinate is at most half a step and the 3-D error at most
``sqrt(3) / 2 * step``. :func:`draco_bits` picks the fewest bits that keep this bound within the
tolerance (1 mm by default); :func:`encode_draco` then *measures* the error of the decoded points
against the originals (order preserved, so point i is compared with point i) and adds a bit when the
measurement exceeds the tolerance. The error is reported per segment in the manifest.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from weldcell.sdk.errors import DataError, MissingExtraError

ENCODINGS = ("quantised", "draco", "ply")
SUFFIX = {"quantised": "qpc", "draco": "drc", "ply": "ply"}


@dataclass
class Quantisation:
    """What the quantisation (Draco's or ours) did to one segment (all lengths in metres); ``bits`` per
    coordinate over the segment's largest extent."""

    bits: int
    step: float
    bound: float
    max_error: float
    rms_error: float

    def to_json(self) -> dict:
        return {
            "bits": self.bits,
            "step_m": self.step,
            "bound_m": self.bound,
            "max_error_m": self.max_error,
            "rms_error_m": self.rms_error,
        }


def _dracopy():
    try:
        import DracoPy
    except ImportError as e:  # pragma: no cover - DracoPy is a dependency of the plugin
        raise MissingExtraError("Draco segment encoding", "DracoPy", "map") from e
    return DracoPy


def draco_bits(extent: float, tolerance: float) -> int:
    """The fewest quantisation bits whose worst-case 3-D error over ``extent`` is ≤ ``tolerance``."""
    if tolerance <= 0:
        raise DataError(f"compression tolerance must be > 0, got {tolerance}", "give e.g. 0.001 m")
    if extent <= 0:
        return 1
    levels = math.sqrt(3.0) * extent / (2.0 * tolerance)  # (2**b - 1) steps must be at least this many
    return int(min(30, max(1, math.ceil(math.log2(levels + 1.0)))))


def encode_draco(
    points: np.ndarray, colors: np.ndarray | None, tolerance: float, level: int = 1
) -> tuple[bytes, Quantisation]:
    """Draco bytes of a cloud with an error ≤ ``tolerance`` (measured), and the quantisation used."""
    dp = _dracopy()
    pts = np.ascontiguousarray(points, dtype=np.float32)
    col = None if colors is None else np.ascontiguousarray(np.clip(colors * 255.0 + 0.5, 0, 255), np.uint8)
    extent = float(np.max(pts.max(axis=0) - pts.min(axis=0))) if len(pts) else 0.0
    bits = draco_bits(extent, tolerance)
    while True:
        # preserve_order: Draco's k-d tree reordering is ~200x slower to encode here and would hide the
        # point-to-point correspondence that the error measurement needs.
        data = dp.encode(
            pts, quantization_bits=bits, compression_level=level, preserve_order=True, colors=col
        )
        back = np.asarray(dp.decode(data).points, dtype=np.float64).reshape(-1, 3)
        if len(back) != len(points):
            raise DataError(f"Draco returned {len(back)} points for {len(points)}", "encode as PLY instead")
        err = np.linalg.norm(back - points, axis=1) if len(points) else np.zeros(1)
        step = extent / (2**bits - 1) if extent > 0 else 0.0
        q = Quantisation(
            bits, step, math.sqrt(3.0) / 2.0 * step, float(err.max()), float(np.sqrt(np.mean(err**2)))
        )
        if q.max_error <= tolerance or bits >= 30:
            return data, q
        bits += 1


def decode_draco(data: bytes) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (N, 3) float64 and colours (N, 3, 0..1) or None of Draco bytes."""
    dp = _dracopy()
    try:
        pc = dp.decode(data)
    except Exception as e:  # DracoPy raises its own exception types for damaged buffers
        raise DataError(f"not a readable Draco buffer ({e})", "fetch the segment again") from e
    pts = np.asarray(pc.points, dtype=np.float64).reshape(-1, 3)
    col = getattr(pc, "colors", None)
    col = None if col is None or len(col) != len(pts) else np.asarray(col, dtype=np.float64)[:, :3] / 255.0
    return pts, col


def _ply_header(n: int, colors: bool) -> bytes:
    props = ["property float x", "property float y", "property float z"]
    if colors:
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {n}", *props, "end_header"]
    return ("\n".join(lines) + "\n").encode("ascii")


def encode_ply(points: np.ndarray, colors: np.ndarray | None) -> bytes:
    """Binary little-endian PLY bytes: x, y, z float32 (+ red, green, blue uchar)."""
    dtype = np.dtype([("p", "<f4", 3)] + ([("c", "u1", 3)] if colors is not None else []))
    rec = np.empty(len(points), dtype=dtype)
    rec["p"] = points
    if colors is not None:
        rec["c"] = np.clip(colors * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return _ply_header(len(points), colors is not None) + rec.tobytes()


def _decode_own_ply(data: bytes) -> tuple[np.ndarray, np.ndarray | None] | None:
    """Points and colours of a PLY written by :func:`encode_ply` (a numpy view of the body), or None
    when the file has another layout (then the SDK's checked reader takes it)."""
    end = data.find(b"end_header\n", 0, 1024)
    first = data.find(b"element vertex ", 0, end)
    if end < 0 or first < 0:
        return None
    try:
        n = int(data[first:end].split(b"\n")[0].split()[2])
    except (ValueError, IndexError):
        return None
    body = data[end + len(b"end_header\n") :]
    for colors in (False, True):
        if _ply_header(n, colors) == data[: end + len(b"end_header\n")]:
            dtype = np.dtype([("p", "<f4", 3)] + ([("c", "u1", 3)] if colors else []))
            if len(body) != n * dtype.itemsize:
                return None  # truncated or padded: the checked reader gives the clear error
            rec = np.frombuffer(body, dtype=dtype)
            return rec["p"].astype(np.float64), (rec["c"].astype(np.float64) / 255.0 if colors else None)
    return None


def encode_quantised(points: np.ndarray, colors: np.ndarray | None, tolerance: float):
    """``quantised`` bytes of a cloud and the quantisation, its error measured on the decoded points."""
    from weldcell.plugins.map_transfer.quantised import decode_quantised
    from weldcell.plugins.map_transfer.quantised import encode_quantised as enc

    data, order, step = enc(points, colors, tolerance)
    back, _ = decode_quantised(data)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    err = np.linalg.norm(back - pts[order], axis=1) if len(pts) else np.zeros(1)
    extent = float(np.max(pts.max(axis=0) - pts.min(axis=0))) if len(pts) else 0.0
    bits = max(1, math.ceil(math.log2(extent / step + 1.0))) if extent > 0 else 1
    rms = float(np.sqrt(np.mean(err**2)))
    q = Quantisation(bits, step, math.sqrt(3.0) / 2.0 * step, float(err.max()), rms)
    if q.max_error > tolerance * (1.0 + 1e-9):  # the grid bounds it; a failure here is a bug, not data
        raise DataError(f"quantisation error {q.max_error} m exceeds {tolerance} m", "encode as PLY instead")
    return data, q


def decode_file(path: Path, encoding: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Points and colours of one segment file in its own frame (``quantised``: sorted by grid cell)."""
    if encoding == "quantised":
        from weldcell.plugins.map_transfer.quantised import decode_quantised

        return decode_quantised(Path(path).read_bytes())
    if encoding == "draco":
        return decode_draco(Path(path).read_bytes())
    if encoding == "ply":
        fast = _decode_own_ply(Path(path).read_bytes())
        if fast is not None:
            return fast
        from weldcell.sdk.cloud import load_cloud_file

        cloud = load_cloud_file(path, frame="segment")  # any other PLY layout: the SDK's checked reader
        return cloud.points, cloud.colors
    raise DataError(f"unknown segment encoding {encoding!r}", f"use one of {', '.join(ENCODINGS)}")


def encode(points: np.ndarray, colors: np.ndarray | None, encoding: str, tolerance: float):
    """(bytes, Quantisation or None) of a segment in ``encoding``."""
    if encoding == "quantised":
        return encode_quantised(points, colors, tolerance)
    if encoding == "draco":
        return encode_draco(points, colors, tolerance)
    if encoding == "ply":
        return encode_ply(points, colors), None
    raise DataError(f"unknown segment encoding {encoding!r}", f"use one of {', '.join(ENCODINGS)}")
