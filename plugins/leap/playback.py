"""Read Leap recordings: plain JSON frame lists and leapjs-playback files (.json / .json.lz).

leapjs-playback stores ``{"metadata": {...}, "frames": [...]}``. With ``formatVersion`` 2 the frames are
*packed*: ``frames[0]`` is the packing structure and every later frame is a list of values in that order.
A structure entry is a key (the value at the same position), ``{key: [subkeys]}`` (one packed object) or
``{key: [[subkeys]]}`` (a list of packed objects). ``.lz`` files are LZ-String ``compressToBase64`` of
that JSON (needs the ``lzstring`` package).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from weldcell.sdk.errors import DataError, MissingExtraError


def _unpack(structure: list, values: list) -> dict:
    out: dict[str, Any] = {}
    for key, val in zip(structure, values, strict=False):
        if isinstance(key, str):
            out[key] = val
        elif isinstance(key, dict):
            ((name, sub),) = key.items()
            if sub and isinstance(sub[0], list):
                out[name] = [_unpack(sub[0], v) for v in (val or [])]
            else:
                out[name] = _unpack(sub, val or [])
    return out


def unpack_frames(data: Any) -> list[dict]:
    """Frames as v6 JSON dicts from any of the recording layouts."""
    if isinstance(data, dict) and "frames" in data:
        meta = data.get("metadata") or {}
        frames = data["frames"]
        if meta.get("formatVersion") == 2:
            if not frames or not isinstance(frames[0], list):
                raise DataError(
                    "packed Leap recording without a packing structure", "re-export the recording"
                )
            structure = frames[0]
            return [_unpack(structure, f) for f in frames[1:]]
    elif isinstance(data, list):
        frames = data
    else:
        raise DataError(
            "not a Leap recording (expected a list of frames or {'frames': [...]})",
            "give a leapjs-playback recording or a list of v6 JSON frames",
        )
    out = []
    for f in frames:
        if isinstance(f, list) and len(f) == 1 and isinstance(f[0], dict):
            f = f[0]  # some recorders wrap each frame in a list
        if isinstance(f, dict):
            out.append(f)
    return out


def load_recording(path: str | Path) -> list[dict]:
    """Frames of a recording file (.json or LZ-String-compressed .lz)."""
    p = Path(path)
    text = p.read_text()
    if p.suffix == ".lz":
        try:
            import lzstring
        except ImportError:
            raise MissingExtraError("reading .lz Leap recordings", "lzstring", "leap") from None
        text = lzstring.LZString().decompressFromBase64(text.strip())
        if not text:
            raise DataError(f"{p} is not LZ-String base64 data", "give a leapjs-playback .json.lz file")
    try:
        return unpack_frames(json.loads(text))
    except json.JSONDecodeError as e:
        raise DataError(f"{p} is not JSON: {e}", "give a Leap recording in JSON") from e
