"""Checking point-cloud files (PLY, PCD) before a library reads them, and silencing native readers.

Open3D (and RPly inside it) reads a truncated or inconsistent file without failing: it prints a
complaint (sometimes raw binary) and returns whatever it got, or nothing. So weldcell parses the
header itself and checks the body against it first: the declared point count against the bytes or
rows present, the property types, the fields x/y/z. A file declaring 50 M points with a short body
is refused by its size, never read. :func:`quiet_native_output` keeps native libraries' prints off
the terminal so the user sees one error line. See docs/file-formats.md.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import re
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from weldcell.sdk.errors import DataError

HEADER_LIMIT = 1 << 16  # a header longer than 64 KiB is not a point-cloud header

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
PLY_FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
PCD_TYPES = {("F", 4), ("F", 8)} | {(t, n) for t in "IU" for n in (1, 2, 4, 8)}
PCD_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
_REEXPORT = "the file is damaged or was cut short; export or copy it again"


@dataclass
class PlyElement:
    """One ``element`` of a PLY header: name, declared count and ``(type, name)`` properties; a list
    property has type ``"list"`` and its count and item types in ``lists[name]``."""

    name: str
    count: int
    props: list[tuple[str, str]] = field(default_factory=list)
    lists: dict[str, tuple[str, str]] = field(default_factory=dict)

    @property
    def has_lists(self) -> bool:
        return bool(self.lists)

    def row_bytes(self) -> int:
        """Bytes of one row in a binary file (list properties: their count field only)."""
        n = 0
        for t, name in self.props:
            n += int(self.lists[name][0][1]) if t == "list" else int(t[1])
        return n


@dataclass
class PlyHeader:
    """A parsed PLY header: format, elements in file order, header lines, where the body starts."""

    fmt: str
    elements: list[PlyElement]
    lines: list[str]
    body_start: int

    def element(self, name: str) -> PlyElement | None:
        return next((e for e in self.elements if e.name == name), None)


@dataclass
class CloudFileInfo:
    """What a checked cloud file declares: format, encoding, point count, point fields, and the text of
    its header comments (PLY ``comment`` lines, PCD ``#`` lines; see
    :func:`weldcell.sdk.cloud.write_cloud`)."""

    path: Path
    format: str
    encoding: str
    points: int
    fields: list[str]
    comments: list[str] = field(default_factory=list)


def _fail(path: Path, what: str, fix: str = _REEXPORT) -> DataError:
    return DataError(f"{path}: {what}", fix)


def _int(tok: str, path: Path, what: str) -> int:
    try:
        v = int(tok)
    except ValueError:
        raise _fail(path, f"{what} {tok!r} is not a whole number") from None
    if v < 0:
        raise _fail(path, f"{what} {v} is negative")
    return v


def _head_text(path: Path, head: bytes, end: int, kind: str = "PLY") -> list[str]:
    try:
        return head[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise _fail(
            path, f"the {kind} header holds bytes that are not text (binary data, another format)"
        ) from None


def parse_ply_header(path: Path, head: bytes) -> PlyHeader:
    """Parse the PLY header at the start of ``head`` (the first bytes of the file); DataError when
    it is missing, not text, or malformed (unknown keywords, types, formats, counts)."""
    if not (head.startswith(b"ply\n") or head.startswith(b"ply\r\n")):
        raise _fail(path, "not a PLY file (it does not start with 'ply')", "export the scan as PLY or PCD")
    end = head.find(b"end_header")
    if end < 0:
        where = f"in its first {HEADER_LIMIT} bytes" if len(head) >= HEADER_LIMIT else "(file cut short?)"
        raise _fail(path, f"PLY header has no 'end_header' {where}")
    nl = head.find(b"\n", end)
    if nl < 0:
        raise _fail(path, "the file ends right after 'end_header' with no data")
    lines = _head_text(path, head, end)
    fmt = None
    elements: list[PlyElement] = []
    for k, line in enumerate(lines[1:], start=2):
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            if fmt is not None or len(tok) != 3:
                raise _fail(path, f"header line {k}: bad or repeated 'format' line {line!r}")
            if tok[1] not in PLY_FORMATS:
                raise _fail(path, f"unsupported PLY format {tok[1]!r}", f"use {', '.join(PLY_FORMATS)}")
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3:
                raise _fail(path, f"header line {k}: {line!r} is not 'element NAME COUNT'")
            elements.append(PlyElement(tok[1], _int(tok[2], path, f"element '{tok[1]}' count")))
        elif tok[0] == "property":
            _ply_property(path, k, line, tok, elements)
        else:
            raise _fail(path, f"header line {k}: unknown PLY keyword {tok[0]!r}")
    if fmt is None:
        raise _fail(path, "PLY header has no 'format' line")
    return PlyHeader(fmt, elements, lines, nl + 1)


def _ply_property(path: Path, k: int, line: str, tok: list[str], elements: list[PlyElement]) -> None:
    if not elements:
        raise _fail(path, f"header line {k}: property before any element")
    el = elements[-1]
    if len(tok) == 5 and tok[1] == "list":
        ct, it, name = tok[2], tok[3], tok[4]
        if ct not in PLY_TYPES or it not in PLY_TYPES or PLY_TYPES[ct][0] == "f":
            raise _fail(path, f"header line {k}: bad list property {line!r}")
        el.lists[name] = (PLY_TYPES[ct], PLY_TYPES[it])
        typ = "list"
    elif len(tok) == 3 and tok[1] in PLY_TYPES:
        typ, name = PLY_TYPES[tok[1]], tok[2]
    else:
        raise _fail(path, f"header line {k}: {line!r} is not 'property TYPE NAME' with a PLY type")
    if any(n == name for _, n in el.props):
        raise _fail(path, f"element '{el.name}' declares property '{name}' twice")
    el.props.append((typ, name))


def _check_ply_binary(path: Path, h: PlyHeader, size: int) -> None:
    body = size - h.body_start
    need, exact = 0, True
    for el in h.elements:
        need += el.count * el.row_bytes()
        exact = exact and not el.has_lists
    if body < need:
        v = h.element("vertex")
        raise _fail(
            path,
            f"declares {v.count if v else 0} points ({need} bytes of data{'' if exact else ' at least'}) but "
            f"holds {body} bytes: the data is cut short",
        )
    if exact and body > need + 2:
        raise _fail(
            path, f"holds {body - need} bytes more data than its header declares (wrong point count?)"
        )


def _check_ascii_rows(path: Path, rows: list[bytes], elements, what: str) -> None:
    """Rows of an ascii body against (name, count, values per row or None) elements; the vertex rows
    must hold numbers."""
    import numpy as np

    i = 0
    for name, count, width in elements:
        block = rows[i : i + count]
        if len(block) < count:
            raise _fail(path, f"declares {count} {name} rows but the file ends after {len(block)}: cut short")
        if width is not None:
            tokens = b" ".join(block).split()
            if len(tokens) != count * width:
                bad = next((j for j, r in enumerate(block) if len(r.split()) != width), 0)
                raise _fail(
                    path, f"{name} row {bad + 1} has {len(block[bad].split())} values, header: {width}"
                )
            if name == what:
                try:
                    np.array(tokens, dtype=np.float64)
                except ValueError:
                    raise _fail(path, f"a {name} row holds a value that is not a number") from None
        i += count
    extra = sum(1 for r in rows[i:] if r.strip())
    if extra:
        raise _fail(path, f"holds {extra} more rows than its header declares (wrong point count?)")


def _ascii_rows(path: Path, body_start: int, size: int, min_bytes: int) -> list[bytes]:
    if size - body_start < min_bytes:
        raise _fail(
            path,
            f"its header needs at least {min_bytes} bytes of text data, the file holds "
            f"{size - body_start}: cut short",
        )
    with open(path, "rb") as f:
        f.seek(body_start)
        return [r for r in f.read().splitlines() if r.strip()]


def check_ply(path: Path, head: bytes, size: int) -> CloudFileInfo:
    """Check a PLY file's header and the size of its body; return what it declares."""
    h = parse_ply_header(path, head)
    v = h.element("vertex")
    if v is None:
        raise _fail(path, "PLY file has no 'vertex' element", "export the point cloud, not only a mesh")
    scalars = {n: t for t, n in v.props if t != "list"}
    missing = [c for c in "xyz" if c not in scalars]
    if missing:
        raise _fail(path, f"vertices have no {'/'.join(missing)} property", "export the x, y, z coordinates")
    if v.has_lists:
        raise _fail(path, "vertices have list properties", "export points only (x, y, z, normals, colours)")
    if v.count == 0:
        raise _fail(
            path, "has no points (its header declares 0 points)", "the scan is empty; capture it again"
        )
    if h.fmt == "ascii":
        elements = [(e.name, e.count, None if e.has_lists else len(e.props)) for e in h.elements]
        min_bytes = sum(e.count * 2 * len(e.props) for e in h.elements if not e.has_lists)
        _check_ascii_rows(path, _ascii_rows(path, h.body_start, size, min_bytes), elements, "vertex")
    else:
        _check_ply_binary(path, h, size)
    comments = [ln.strip()[len("comment") :].strip() for ln in h.lines[1:] if ln.split()[:1] == ["comment"]]
    return CloudFileInfo(path, "ply", h.fmt, v.count, [n for _, n in v.props], comments)


def _pcd_header(path: Path, head: bytes) -> tuple[dict[str, list[str]], int, list[str]]:
    pos, keys, comments = 0, {}, []
    while True:
        nl = head.find(b"\n", pos)
        if nl < 0:
            raise _fail(path, "PCD header has no DATA line")
        line = _head_text(path, head[pos:nl], nl - pos, "PCD")
        pos = nl + 1
        tok = line[0].split() if line else []
        if tok and tok[0].startswith("#"):
            comments.append(line[0].lstrip()[1:].strip())
        if not tok or tok[0].startswith("#"):
            continue
        key = tok[0].upper()
        if key not in PCD_KEYS:
            raise _fail(path, f"unknown PCD header key {tok[0]!r}")
        if key in keys:
            raise _fail(path, f"PCD header repeats {key}")
        keys[key] = tok[1:]
        if key == "DATA":
            return keys, pos, comments


def check_pcd(path: Path, head: bytes, size: int) -> CloudFileInfo:
    """Check a PCD file's header (fields, sizes, types, counts) and the size of its body."""
    keys, body_start, comments = _pcd_header(path, head)
    for k in ("FIELDS", "SIZE", "TYPE", "WIDTH", "DATA"):
        if not keys.get(k):
            raise _fail(path, f"PCD header has no {k}")
    fields, sizes, types = keys["FIELDS"], keys["SIZE"], keys["TYPE"]
    counts = keys.get("COUNT") or ["1"] * len(fields)
    if not len(fields) == len(sizes) == len(types) == len(counts):
        raise _fail(
            path,
            f"PCD header lists {len(fields)} FIELDS but {len(sizes)} SIZE, {len(types)} TYPE "
            f"and {len(counts)} COUNT values",
        )
    sizes = [_int(s, path, "SIZE") for s in sizes]
    counts = [_int(c, path, "COUNT") for c in counts]
    for f, t, s in zip(fields, types, sizes, strict=True):
        if (t.upper(), s) not in PCD_TYPES:
            raise _fail(path, f"field {f}: TYPE {t} with SIZE {s} is not a PCD type")
    if missing := [c for c in "xyz" if c not in fields]:
        raise _fail(path, f"PCD fields have no {'/'.join(missing)}", "export the x, y, z coordinates")
    width = _int(keys["WIDTH"][0], path, "WIDTH")
    height = _int((keys.get("HEIGHT") or ["1"])[0], path, "HEIGHT")
    points = _int((keys.get("POINTS") or [str(width * height)])[0], path, "POINTS")
    if width * height != points:
        raise _fail(path, f"WIDTH x HEIGHT = {width} x {height} but POINTS = {points}")
    if points == 0:
        raise _fail(
            path, "has no points (its header declares 0 points)", "the scan is empty; capture it again"
        )
    data, row = keys["DATA"][0].lower(), sum(s * c for s, c in zip(sizes, counts, strict=True))
    body = size - body_start
    if data == "ascii":
        rows = _ascii_rows(path, body_start, size, points * 2 * sum(counts))
        _check_ascii_rows(path, rows, [("point", points, sum(counts))], "point")
    elif data == "binary":
        if body < points * row:
            raise _fail(path, f"declares {points} points ({points * row} B), holds {body} B: cut short")
        if body > points * row + 2:
            raise _fail(path, f"holds {body - points * row} bytes more data than its header declares")
    elif data == "binary_compressed":
        _check_pcd_compressed(path, body_start, body, points * row)
    else:
        raise _fail(path, f"unknown PCD DATA {data!r}", "use ascii, binary or binary_compressed")
    return CloudFileInfo(path, "pcd", data, points, fields, comments)


def _check_pcd_compressed(path: Path, body_start: int, body: int, raw_size: int) -> None:
    if body < 8:
        raise _fail(path, "compressed PCD data is missing its size fields: cut short")
    with open(path, "rb") as f:
        f.seek(body_start)
        sizes = f.read(8)
    packed, unpacked = int.from_bytes(sizes[:4], "little"), int.from_bytes(sizes[4:], "little")
    if unpacked != raw_size:
        raise _fail(path, f"compressed data unpacks to {unpacked} bytes, the header's points need {raw_size}")
    if body < 8 + packed:
        raise _fail(path, f"compressed data is {packed} bytes but the file holds {body - 8}: cut short")


def check_cloud_file(path: str | Path) -> CloudFileInfo:
    """Check a PLY or PCD file before reading it: exists, known format, header well formed with
    x/y/z, body consistent with the declared point count and types. DataError with the fix otherwise."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"point cloud file not found: {path}", "check the path")
    suffix = path.suffix.lower()
    if suffix not in (".ply", ".pcd"):
        raise DataError(f"{path}: unsupported point cloud format '{path.suffix}'", "use a .ply or .pcd file")
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(HEADER_LIMIT)
    except OSError as e:
        raise DataError(f"cannot read {path}: {e.strerror}", "check the file's permissions") from None
    if size == 0:
        raise _fail(path, "the file is empty", "export the scan again as PLY or PCD")
    return check_ply(path, head, size) if suffix == ".ply" else check_pcd(path, head, size)


_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
_LIB_TAG = re.compile(r"\[Open3D [A-Z]+\]\s*")


def _printable(text: bytes, limit: int = 160) -> str:
    """Native output as one short printable line: colour codes, library tags and raw bytes removed."""
    s = _LIB_TAG.sub("", _ANSI.sub("", text.decode("utf-8", "replace")))
    s = "".join(c if c.isprintable() and c != "\ufffd" else " " for c in s)
    return " ".join(s.split())[:limit]


@contextlib.contextmanager
def quiet_native_output() -> Iterator[list[str]]:
    """Keep what a native library prints off the terminal while the block runs: file descriptors 1
    and 2 (C/C++ code such as RPly) and Python's ``sys.stdout``/``sys.stderr`` (Open3D's logger prints
    through them) go to a buffer. The yielded list receives that text afterwards (printable, one
    short line) for an error message."""
    captured: list[str] = []
    for s in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            s.flush()
    saved = [os.dup(1), os.dup(2)]
    libc = _libc()
    py_text = io.StringIO()
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        try:
            with contextlib.redirect_stdout(py_text), contextlib.redirect_stderr(py_text):
                yield captured
        finally:
            if libc is not None:
                libc.fflush(None)
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            text = _printable(sink.read(4096) + py_text.getvalue()[:4096].encode("utf-8", "replace"))
            if text:
                captured.append(text)


def _libc():
    try:
        return ctypes.CDLL(None)
    except OSError:  # pragma: no cover - not on POSIX
        return None
