"""Inputs of ``weldcell map relocalize``: a map folder (``map.ply`` + ``keyframes.json``,
``weldcell/keyframes@1``, docs/file-formats.md) or a plain PLY/PCD cloud; and the prior options
``--yaw DEG[±DEG]`` and ``--position X,Y,Z[±M]``."""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from weldcell.sdk.cloud import read_cloud
from weldcell.sdk.errors import DataError, UsageError

KEYFRAMES_SCHEMA = "weldcell/keyframes@1"
_PM = re.compile(r"\s*(?:±|\+-|\+/-|pm)\s*")


@dataclass
class MapInput:
    """Points (N, 3) in the map's world frame and, for a map folder, its key-frame positions (K, 3)."""

    points: np.ndarray
    keyframe_positions: np.ndarray | None
    path: Path


def load_map(path: str | Path) -> MapInput:
    """A map folder (its ``map.ply`` and key frames) or a PLY/PCD file, validated by weldcell.sdk.cloud."""
    path = Path(path)
    if not path.exists():
        raise UsageError(f"{path} does not exist", "give a map folder or a .ply/.pcd cloud")
    if path.is_dir():
        cloud_file = path / "map.ply"
        if not cloud_file.is_file():
            raise UsageError(
                f"{path} is a folder without map.ply", "give a map folder written by weldcell map"
            )
        pts = read_cloud(cloud_file, check_scale=False).points
        return MapInput(pts, _keyframes(path / "keyframes.json"), path)
    if path.suffix.lower() not in (".ply", ".pcd"):
        raise UsageError(f"{path}: not a map folder, .ply or .pcd", "give a map folder or a PLY/PCD cloud")
    return MapInput(read_cloud(path, check_scale=False).points, None, path)


def _keyframes(index: Path) -> np.ndarray | None:
    if not index.is_file():
        return None
    try:
        doc = json.loads(index.read_text(encoding="utf-8"))
        if doc.get("schema") != KEYFRAMES_SCHEMA:
            raise ValueError(f"schema {doc.get('schema')!r}, expected {KEYFRAMES_SCHEMA}")
        recs = doc.get("keyframes", doc.get("records", []))
        pos = np.array([np.asarray(r["T_world_imu"], float)[:3, 3] for r in recs]).reshape(-1, 3)
    except (ValueError, KeyError, TypeError, IndexError) as e:
        raise DataError(f"{index}: unreadable key-frame store ({e})", "write the map again") from None
    return pos if len(pos) and np.all(np.isfinite(pos)) else None


def travelled(positions: np.ndarray) -> float:
    """Path length (m) through the key-frame positions."""
    return float(np.sum(np.linalg.norm(np.diff(positions, axis=0), axis=1))) if len(positions) > 1 else 0.0


def sample_keyframes(prior_kf: np.ndarray, current_kf: np.ndarray | None, spacing: float) -> np.ndarray:
    """§II-E: prior key frames within twice the current travelled distance (along the prior's path from its
    start), thinned to one per ``spacing`` cell."""
    kf = prior_kf
    if current_kf is not None and len(current_kf) > 1:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(prior_kf, axis=0), axis=1))])
        near = prior_kf[arc <= 2.0 * travelled(current_kf)]
        kf = near if len(near) else prior_kf
    _, first = np.unique(np.floor(kf / max(spacing, 1e-6)).astype(np.int64), axis=0, return_index=True)
    return kf[np.sort(first)]


def _split(text: str, what: str) -> tuple[str, str | None]:
    parts = _PM.split(text.strip())
    if len(parts) > 2 or not parts[0]:
        raise UsageError(f"{what} {text!r} is not VALUE[±UNCERTAINTY]", f"write e.g. {what} 45±10")
    return parts[0], parts[1] if len(parts) == 2 else None


def _float(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise UsageError(f"{what}: {text!r} is not a number", f"write e.g. {what} 45±10") from None
    if not math.isfinite(v):
        raise UsageError(f"{what}: {text!r} is not finite", "give a finite number")
    return v


def parse_yaw(text: str | None, default_sigma_deg: float = 5.0) -> tuple[float | None, float]:
    """``--yaw 45`` or ``45±10`` (degrees) -> (yaw, sigma) in radians."""
    if text is None:
        return None, math.radians(default_sigma_deg)
    v, u = _split(text, "--yaw")
    sigma = _float(u, "--yaw") if u is not None else default_sigma_deg
    if sigma <= 0:
        raise UsageError(f"--yaw: uncertainty {sigma} must be > 0", "write e.g. --yaw 45±10")
    return math.radians(_float(v, "--yaw")), math.radians(sigma)


def parse_position(text: str | None, default_sigma: float = 2.0) -> tuple[np.ndarray | None, float]:
    """``--position X,Y,Z`` or ``X,Y,Z±M`` (metres) -> (position, sigma)."""
    if text is None:
        return None, default_sigma
    v, u = _split(text, "--position")
    xyz = [_float(c, "--position") for c in v.split(",")]
    if len(xyz) != 3:
        raise UsageError(f"--position {text!r} needs three coordinates", "write e.g. --position 12.5,-3,0±2")
    sigma = _float(u, "--position") if u is not None else default_sigma
    if sigma <= 0:
        raise UsageError(f"--position: uncertainty {sigma} must be > 0", "write e.g. --position 1,2,0±2")
    return np.array(xyz), sigma
