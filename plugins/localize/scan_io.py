"""Laser scans in the base frame: the input of edge extraction (paper 002, §III-D).

``weldcell/laser-scan@1`` CSV: a ``# schema: weldcell/laser-scan@1`` comment line (optional on read),
then the header ``t,x,y,z,line`` and one row per reading: seconds, metres in the robot base frame, the
scan-line index. An out-of-range reading has an empty or ``nan`` z (a gap, never a zero); rows are in
acquisition order and the line index never decreases.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from weldcell.sdk.artifacts import atomic_path
from weldcell.sdk.errors import DataError

SCHEMA = "weldcell/laser-scan@1"
HEADER = "t,x,y,z,line"


@dataclass
class LaserScan:
    """Readings in acquisition order: ``t`` (N,) s, ``xyz`` (N, 3) m base frame (z NaN = out of range),
    ``line`` (N,) int scan-line index (non-decreasing)."""

    t: np.ndarray
    xyz: np.ndarray
    line: np.ndarray

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float).reshape(-1)
        self.xyz = np.asarray(self.xyz, dtype=float).reshape(-1, 3)
        self.line = np.asarray(self.line).astype(np.int64).reshape(-1)

    def __len__(self) -> int:
        return len(self.t)

    def validate(self, what: str = "scan") -> LaserScan:
        """Refuse inconsistent scans with one clear error; returns self."""
        n = len(self.t)
        if not (len(self.xyz) == n == len(self.line)):
            raise DataError(f"{what}: t, xyz and line differ in length", "write one row per reading")
        if n == 0:
            raise DataError(f"{what} has no reading", "record the inspection again")
        if not (np.isfinite(self.t).all() and np.isfinite(self.xyz[:, :2]).all()):
            raise DataError(f"{what}: t, x or y is NaN or infinite", "only z may be empty (out of range)")
        if np.isinf(self.xyz[:, 2]).any():
            raise DataError(f"{what}: z is infinite", "write out-of-range readings as an empty z or nan")
        if np.any(np.diff(self.line) < 0):
            k = int(np.flatnonzero(np.diff(self.line) < 0)[0]) + 1
            raise DataError(
                f"{what}: line index decreases at reading {k}", "rows must be in acquisition order"
            )
        if np.any(np.diff(self.t) < 0):
            k = int(np.flatnonzero(np.diff(self.t) < 0)[0]) + 1
            raise DataError(
                f"{what}: time goes backwards at reading {k}", "rows must be in acquisition order"
            )
        if np.isnan(self.xyz[:, 2]).all():
            raise DataError(
                f"{what}: every reading is out of range", "check the sensor's stand-off and range"
            )
        return self

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.xyz[:, 2])


def read_laser_scan(path: str | Path) -> LaserScan:
    """Read and validate a ``weldcell/laser-scan@1`` CSV."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"scan file not found: {path}", "check the path")
    text = path.read_text()
    lines = text.splitlines()
    k = 0
    while k < len(lines) and lines[k].startswith("#"):
        if "schema" in lines[k] and SCHEMA not in lines[k]:
            raise DataError(f"{path}: {lines[k].strip()}", f"expected a {SCHEMA} CSV")
        k += 1
    if k >= len(lines) or lines[k].replace(" ", "") != HEADER:
        got = lines[k] if k < len(lines) else "(nothing)"
        raise DataError(f"{path}: header is {got!r}, expected '{HEADER}'", f"write a {SCHEMA} CSV")
    body = "\n".join(lines[k + 1 :]).replace(",,", ",nan,")
    try:
        arr = np.loadtxt(io.StringIO(body), delimiter=",", dtype=float, ndmin=2)
    except ValueError as e:
        raise DataError(f"{path}: malformed row ({e})", "every row is t,x,y,z,line") from None
    if arr.size == 0:
        raise DataError(f"{path} has no reading", "record the inspection again")
    if arr.shape[1] != 5:
        raise DataError(f"{path}: rows have {arr.shape[1]} columns", "every row is t,x,y,z,line")
    if not np.isfinite(arr[:, 4]).all() or np.any(arr[:, 4] != np.round(arr[:, 4])):
        raise DataError(
            f"{path}: the line column is not an integer on every row", "write the scan-line index"
        )
    return LaserScan(arr[:, 0], arr[:, 1:4], arr[:, 4].astype(np.int64)).validate(str(path))


def write_laser_scan(path: str | Path, scan: LaserScan) -> Path:
    """Write a scan as ``weldcell/laser-scan@1`` CSV (atomically; out-of-range z written empty)."""
    scan.validate()
    path = Path(path)
    buf = io.StringIO()
    buf.write(f"# schema: {SCHEMA}\n{HEADER}\n")
    table = np.column_stack([scan.t, scan.xyz, scan.line])
    np.savetxt(buf, table, fmt=["%.6f", "%.7f", "%.7f", "%.7f", "%d"], delimiter=",")
    text = buf.getvalue().replace(",nan,", ",,")  # out of range: an empty z, never a zero
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path
