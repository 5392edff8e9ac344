"""Readers of the scan-and-plan offline commands: input clouds (``weldcell seam``), posed-scan lists
(``weldcell/posed-scans@1`` or a run folder's ``state.json``, for ``weldcell reconstruct``) and the
hand-eye file's plausibility. Every reader checks what it reads and refuses a bad file with one
:class:`~weldcell.sdk.errors.DataError` line and its fix (docs/file-formats.md)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk.cloud import UNIT_SCALE, PointCloud, check_units, drop_invalid, load_cloud_file
from weldcell.sdk.datafile import as_matrix, as_number, check_keys, kind_of, read_json_file, short
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid
from weldcell.sdk.scan import PosedScan

SCANS_SCHEMA = "weldcell/posed-scans@1"


def read_input_cloud(path: Path, units: str, frame: str) -> tuple[PointCloud, int]:
    """Read a PLY/PCD cloud in ``units``; returns it (and the viewpoints it stored) in metres and how many
    invalid points were dropped.

    NaN/inf points (and points at exactly the origin, the invalid pixels of a depth camera) are dropped;
    an empty cloud, a cloud with no valid point, or one whose size does not fit ``units`` is refused.
    """
    path = Path(path)
    if units not in UNIT_SCALE:
        raise DataError(f"unknown units '{units}'", f"use one of {', '.join(UNIT_SCALE)}")
    raw = load_cloud_file(path, frame=frame)  # header and body checked, Open3D's prints silenced
    if len(raw) == 0:
        raise DataError(
            f"{path} has no points (empty or unreadable file)",
            "check the file; export the scan again as PLY or PCD",
        )
    cloud = drop_invalid(raw)
    if len(cloud) == 0:
        raise DataError(
            f"{path}: all {len(raw)} points are NaN, infinite or at the origin",
            "the scan holds no valid depth; capture it again",
        )
    check_units(cloud, units, what=str(path))
    cloud = cloud.scaled(UNIT_SCALE[units])  # the stored viewpoints are in the file's units too
    cloud.meta["source"] = str(path)
    return cloud, len(raw) - len(cloud)


@dataclass
class PosedScans:
    """Scans read from a folder: the views, their names, and the hand-eye stored with them (or None)."""

    scans: list[PosedScan]
    names: list[str]
    T_flange_camera: np.ndarray | None
    layout: str
    roi: tuple[Any, Any] = (None, None)


_SCANS_KEYS = ("schema", "units", "scans", "T_flange_camera", "roi_min", "roi_max")
_SCAN_KEYS = ("cloud", "T_base_flange", "stamp")


def _pose(value: Any, name: str, where: Path, scale: float) -> np.ndarray:
    if value is None:
        raise DataError(
            f"{where}: scan {name} has no pose (T_base_flange)",
            "give every scan the robot's flange pose at capture as a 4x4 matrix 'T_base_flange'",
        )
    try:
        T = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        T = np.zeros(0)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DataError(
            f"{where}: the pose of scan {name} is not a finite 4x4 matrix",
            "write T_base_flange as [[r11, r12, r13, x], ..., [0, 0, 0, 1]]",
        )
    T = T.copy()
    T[:3, 3] *= scale
    if not is_rigid(T, tol=1e-4):
        raise DataError(
            f"{where}: the pose of scan {name} is not a rigid transform",
            "its rotation part must be orthonormal with determinant +1 and its last row 0 0 0 1",
        )
    return T


def load_posed_scans(source: Path) -> PosedScans:
    """Posed scans from a run folder (``state.json``) or a ``scans.json`` (``weldcell/posed-scans@1``).

    ``source`` is the folder or the JSON file itself. Every scan needs its cloud file (camera frame)
    and its flange pose ``T_base_flange``; a scan without a pose is refused by name.
    """
    source = Path(source)
    if source.is_file():
        index, folder = source, source.parent
    elif (source / "scans.json").is_file():
        index, folder = source / "scans.json", source
    elif (source / "state.json").is_file():
        index, folder = source / "state.json", source
    elif source.is_dir():
        raise DataError(
            f"{source} holds neither scans.json nor a run's state.json",
            f'write a scans.json: {{"schema": "{SCANS_SCHEMA}", "units": "m", "scans": '
            '[{"cloud": "000.ply", "T_base_flange": [[...4x4...]], "stamp": 0.0}, ...]}',
        )
    else:
        raise DataError(f"scans folder not found: {source}", "check the path")
    doc = read_json_file(index, "scan list")
    if not isinstance(doc, dict):
        raise DataError(f"{index}: expected a JSON object", f"see the {SCANS_SCHEMA} layout in the docs")
    T_fc = None
    if index.name == "state.json" and "captures" in doc:
        layout, units, records = "run folder", "m", doc.get("captures") or []
        if not isinstance(records, list):
            raise DataError(
                f"{index}: 'captures' is {kind_of(records)}, not a list", "the run folder is damaged"
            )
        notes = doc.get("notes") if isinstance(doc.get("notes"), dict) else {}
        he = notes.get("hand_eye")
        if isinstance(he, dict):
            T_fc = _pose(he.get("T_flange_camera"), "hand-eye", index, 1.0)
        key = "file"
        roi = _run_roi(folder)
    else:
        if doc.get("schema") != SCANS_SCHEMA:
            raise DataError(
                f"{index}: schema is {doc.get('schema')!r}, expected {SCANS_SCHEMA!r}",
                f'add "schema": "{SCANS_SCHEMA}"',
            )
        layout, units, records, key = "scans.json", doc.get("units", "m"), doc.get("scans"), "cloud"
        roi = (doc.get("roi_min"), doc.get("roi_max"))
        check_keys(doc, _SCANS_KEYS, str(index))
        if not isinstance(units, str) or units not in UNIT_SCALE:
            raise DataError(f"{index}: unknown units {short(units)}", f"use one of {', '.join(UNIT_SCALE)}")
        roi = tuple(_corner(c, f"{index}: {k}") for c, k in zip(roi, ("roi_min", "roi_max"), strict=True))
        if not isinstance(records, list):
            raise DataError(f"{index}: 'scans' must be a list", "list one object per scan")
        if doc.get("T_flange_camera") is not None:
            T_fc = _pose(doc["T_flange_camera"], "hand-eye", index, UNIT_SCALE[units])
    if not records:
        raise DataError(f"{index} lists no scans", "capture at least one view")
    scale = UNIT_SCALE[units]
    scans, names = [], []
    for i, rec in enumerate(records):
        if not isinstance(rec, dict) or not rec.get(key):
            raise DataError(f"{index}: scan {i} names no cloud file ('{key}')", f'add "{key}": "NNN.ply"')
        if layout == "scans.json":
            check_keys(rec, _SCAN_KEYS, f"{index}: scan {i}")
        if not isinstance(rec[key], str):
            raise DataError(
                f"{index}: scan {i} '{key}' is {kind_of(rec[key])}", f'write e.g. "{key}": "000.ply"'
            )
        name = f"{i} ({rec[key]})"
        T = _pose(rec.get("T_base_flange"), name, index, scale)
        stamp = as_number(
            rec.get("stamp", float(i)), f"{index}: scan {name} stamp", "write the time in seconds"
        )
        cloud, _ = read_input_cloud(folder / rec[key], units, "camera")
        scans.append(PosedScan(cloud, T, stamp))
        names.append(rec[key])
    if units != "m":
        roi = tuple(None if r is None else [v * scale for v in r] for r in roi)
    return PosedScans(scans, names, T_fc, layout, roi)


def _run_roi(folder: Path) -> tuple[Any, Any]:
    """The region of interest the run's job used (from its result.json), or (None, None)."""
    f = folder / "result.json"
    if not f.is_file():
        return None, None
    doc = read_json_file(f, "run result")
    job = {}
    for k in ("provenance", "settings", "job"):
        doc = doc.get(k) if isinstance(doc, dict) else None
        job = doc if isinstance(doc, dict) else {}
    where = f"{f}: provenance.settings.job"
    return _corner(job.get("roi_min"), f"{where}.roi_min"), _corner(job.get("roi_max"), f"{where}.roi_max")


def _corner(value: Any, where: str) -> list[float] | None:
    """A region-of-interest corner [x, y, z] (finite numbers) or None."""
    if value is None:
        return None
    return as_matrix(value, (3,), where, "write the corner as [x, y, z] in the file's units").tolist()


# A camera sits on the flange: its origin is more than a millimetre and less than 2 m from the flange's.
_MOUNT_RANGE = (1e-3, 2.0)


def check_mount(T: np.ndarray, path: Path) -> np.ndarray:
    """Refuse a hand-eye ``T_flange_camera`` whose offset does not fit its declared units."""
    d = float(np.linalg.norm(T[:3, 3]))
    lo, hi = _MOUNT_RANGE
    if d > hi:
        raise DataError(
            f"{path}: the camera is {d:.4g} m from the flange; the file's lengths look like millimetres",
            'write "units": "mm" in the hand-eye file (or convert it to metres)',
        )
    if d < lo:
        units = read_json_file(path, "hand-eye file").get("units", "m")
        if units != "m":
            raise DataError(
                f"{path}: the camera is {d * 1e3:.3g} mm from the flange with units {units!r}: "
                "the lengths look like metres",
                'write "units": "m" in the hand-eye file',
            )
    return T
