"""The weld path: seams found and the torch poses planned along them (``weldcell/weld-path@1``).

JSON layout (see docs/file-formats.md)::

    {"schema": "weldcell/weld-path@1", "frame": "base", "units": "m",
     "seams": [{"id": "s0", "joint": "fillet", "closed": false, "length": 0.3,
                "points": [[x, y, z], ...],                 # the seam line, ordered along travel
                "poses": [[x, y, z, qx, qy, qz, qw], ...]}],  # torch (TCP) poses, z toward the work
     "metrics": {...}}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk.artifacts import read_json, write_json
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_pose7, T_to_pose7

SCHEMA = "weldcell/weld-path@1"


@dataclass
class SeamPath:
    """One seam: its line (K, 3) and torch poses (M, 4, 4) in the path's frame."""

    id: str
    joint: str
    points: np.ndarray
    poses: np.ndarray
    closed: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def length(self) -> float:
        p = np.asarray(self.points)
        seg = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0
        if self.closed and len(p) > 2:
            seg += float(np.linalg.norm(p[0] - p[-1]))
        return seg


@dataclass
class WeldPath:
    """Every seam of a part with its torch poses, the frame they are in, and figures of merit."""

    seams: list[SeamPath]
    frame: str = "base"
    metrics: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "schema": SCHEMA,
            "frame": self.frame,
            "units": "m",
            "seams": [
                {
                    "id": s.id,
                    "joint": s.joint,
                    "closed": bool(s.closed),
                    "length": round(s.length, 6),
                    "points": np.round(np.asarray(s.points, dtype=float), 7).tolist(),
                    "poses": [np.round(T_to_pose7(T), 7).tolist() for T in s.poses],
                    **s.extra,
                }
                for s in self.seams
            ],
            "metrics": self.metrics,
        }

    def write(self, path: str | Path) -> Path:
        return write_json(path, self.to_json())

    @classmethod
    def from_json(cls, data: dict[str, Any] | str | Path) -> WeldPath:
        """Parse and validate a weld-path document (a dict or a file path)."""
        where = "weld path"
        if isinstance(data, str | Path):
            where = str(data)
            data = read_json(data)
        fix = "pass a file written by `weldcell seam` or a scan-and-plan run"
        if not isinstance(data, dict):
            raise DataError(f"{where}: expected a JSON object, got {type(data).__name__}", fix)
        if data.get("schema") != SCHEMA:
            raise DataError(f"{where}: schema is {data.get('schema')!r}, expected {SCHEMA!r}", fix)
        if data.get("units", "m") != "m":
            raise DataError(
                f"{where}: units {data.get('units')!r}; weld paths are stored in metres",
                "convert the file to metres",
            )
        if not isinstance(data.get("seams"), list):
            raise DataError(f"{where}: needs a 'seams' list", fix)
        layout = "each seam needs 'points' [[x,y,z],...] and 'poses' [[x,y,z,qx,qy,qz,qw],...]"
        seams = []
        for i, s in enumerate(data["seams"]):
            missing = [k for k in ("points", "poses") if not isinstance(s, dict) or k not in s]
            if missing:
                raise DataError(f"{where}: seams[{i}] is missing {', '.join(missing)}", layout)
            try:
                pts = np.asarray(s["points"], dtype=float).reshape(-1, 3)
                poses7 = np.asarray(s["poses"], dtype=float).reshape(-1, 7)
            except (TypeError, ValueError) as e:
                raise DataError(f"{where}: seams[{i}] is malformed ({e})", layout) from None
            if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(poses7))):
                raise DataError(f"{where}: seams[{i}] has NaN or infinite values", "regenerate the path")
            if np.any(np.abs(np.linalg.norm(poses7[:, 3:], axis=1) - 1.0) > 1e-6):
                raise DataError(
                    f"{where}: seams[{i}] has non-unit quaternions in its poses",
                    "normalise the quaternions [qx, qy, qz, qw]",
                )
            extra = {
                k: v for k, v in s.items() if k not in ("id", "joint", "closed", "length", "points", "poses")
            }
            seams.append(
                SeamPath(
                    str(s.get("id", f"s{i}")),
                    str(s.get("joint", "unknown")),
                    pts,
                    np.stack([T_from_pose7(p) for p in poses7]) if len(poses7) else np.zeros((0, 4, 4)),
                    bool(s.get("closed", False)),
                    extra,
                )
            )
        return cls(seams, frame=str(data.get("frame", "base")), metrics=dict(data.get("metrics", {})))
