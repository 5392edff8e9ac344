"""Hand-eye calibration files: the result record ``weldcell/hand-eye@1`` and the samples file
``weldcell/handeye-samples@1``, with their readers and writers.

Public because more than the hand-eye plugin uses them: a job that consumes a calibration (e.g. the
tactile plugin's ``tactile-track`` reads ``T_base_camera``), the hand-eye stages' result type
(:class:`HandEyeResult`, see :mod:`weldcell.sdk.stages`), tools that analyse recorded samples.

``samples.json`` (``weldcell/handeye-samples@1``)::

    {"schema": "weldcell/handeye-samples@1", "config": "eye-on-base", "units": "m",
     "samples": [{"T_base_flange": [[4x4]], "cloud": "000.ply"}, {"T_base_flange": ..., "p_cam": [x, y, z]},
                 {"T_base_flange": ..., "image": "003.png"}, ...]}

``units`` applies to every length (translations, p_cam, p_base, clouds); values are converted to
metres on reading. A sample may carry ``"normal"`` (the measured face normal in the camera frame, for
the stage's ``normal_weight``); the file may say where a fixed feature is for a moving camera,
``"feature_base"``: ``"origin"`` (the base mounting flange), ``"estimate"`` or ``[x, y, z]``.
Field by field: docs/file-formats.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk.artifacts import write_json
from weldcell.sdk.cloud import UNIT_SCALE
from weldcell.sdk.datafile import (
    as_matrix,
    check_keys,
    expect_object,
    kind_of,
    read_json_file,
    short,
)
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid

SCHEMA = "weldcell/hand-eye@1"
#: a hand-eye translation beyond this (m) is no cell's camera mount: the file holds millimetres
MAX_TRANSLATION = 20.0
CONVENTION = "p_a = T_a_b @ p_b (T_a_b maps coordinates in frame b into frame a); metres, radians"

#: configuration -> (name of the transform solved for, what it means) (§2.1.1)
CONFIGS: dict[str, tuple[str, str]] = {
    "eye-on-base": ("T_base_camera", "camera fixed in the cell, flange/marker on the robot (AX=YB, eq. 4)"),
    "eye-in-hand": (
        "T_flange_camera",
        "camera on the flange, feature/marker fixed to the base (AX=XB, eq. 1)",
    ),
    "eye-on-arm": ("T_arm_camera", "camera on an intermediate link {Arm} (eqs. 7-8)"),
    "co-manipulation": ("T_base1_base2", "camera on robot 1, marker on robot 2, solved as eq. 6 a-c"),
}


def config_name(config: str) -> str:
    """Normalized configuration name (DataError listing the four for an unknown one)."""
    c = str(config).strip().lower().replace("_", "-")
    aliases = {"eye-to-hand": "eye-on-base", "comanipulation": "co-manipulation"}
    c = aliases.get(c, c)
    if c not in CONFIGS:
        raise DataError(f"unknown hand-eye configuration '{config}'", f"use one of {', '.join(CONFIGS)}")
    return c


#: why a value is not a finite number, by the key it sits under (the JSON gets ``null`` and this reason)
NULL_REASONS = {
    "residuals_m": "NaN: no flange centre (or board pose) for this sample, so no residual",
    "cost": "+inf: the eq. 13 verifier found no pool it could verify (ICP did not converge)",
    "cost_history": "+inf: no verified 4-pair pool yet after this many pairs (first three pairs, or the "
    "verifier failed)",
    "mean_all_m": "NaN: no sample has a residual",
}


def finite_json(doc: dict) -> dict:
    """``doc`` with every non-finite float replaced by ``null`` (strict JSON has no NaN/Infinity) and a
    top-level ``"nulls"`` map: JSON path of each replaced value (lists collapsed to ``[]``) -> why."""
    reasons: dict[str, str] = {}

    def walk(v, path: str, key: str):
        if isinstance(v, dict):
            return {k: walk(x, f"{path}.{k}" if path else str(k), str(k)) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [walk(x, f"{path}[]", key) for x in v]
        if isinstance(v, float | np.floating) and not np.isfinite(v):
            kind = "NaN" if np.isnan(v) else ("+inf" if v > 0 else "-inf")
            reasons.setdefault(path, NULL_REASONS.get(key, f"{kind}: not a finite number"))
            return None
        return v

    out = walk({k: v for k, v in doc.items() if k != "nulls"}, "", "")
    if reasons:
        out["nulls"] = {**doc.get("nulls", {}), **reasons}
    return out


@dataclass
class HandEyeSample:
    """One robot pose with what the camera saw. Units: metres.

    ``T_base_flange``: robot flange pose (robot 1 in co-manipulation); ``p_cam``: the reference
    feature (flange centre) in the camera; ``cloud``: a raw scan (points (N, 3) m, or a path) to get
    ``p_cam`` from; ``p_base``: the flange centre in the base when only positions were recorded
    (point-pair data sets); ``T_cam_target``: a board pose for target-based solvers; ``image``: a board
    photo; ``T_base_arm``: pose of the camera-carrying link (eye-on-arm); ``T_base2_flange2`` and
    ``phase`` ("a"/"b"): co-manipulation (eq. 6)."""

    T_base_flange: np.ndarray | None = None
    p_cam: np.ndarray | None = None
    p_base: np.ndarray | None = None
    cloud: Any = None
    T_cam_target: np.ndarray | None = None
    image: Any = None
    T_base_arm: np.ndarray | None = None
    T_base2_flange2: np.ndarray | None = None
    phase: str | None = None
    meta: dict = field(default_factory=dict)


def sample_id(sample: HandEyeSample, i: int) -> str:
    """The user's name of a sample: its ``meta["id"]`` (a file stem such as ``01`` or a timestamp),
    else its index in the file."""
    v = sample.meta.get("id")
    return str(v) if v not in (None, "") else str(sample.meta.get("index", i))


@dataclass
class HandEyeResult:
    """A hand-eye calibration. ``T`` is the transform called ``name`` (e.g. ``T_base_camera``:
    camera coordinates into the base frame, ``p_base = T @ p_cam``). ``extra`` holds other solved
    quantities (feature offsets, the marker transform of AX=YB, co-manipulation parts). Residuals
    are per sample in metres; ``inliers`` marks the samples used."""

    T: np.ndarray
    name: str
    config: str
    method: str
    residuals: np.ndarray
    inliers: np.ndarray
    metrics: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    convention: str = CONVENTION

    @property
    def outliers(self) -> list[int]:
        return np.flatnonzero(~np.asarray(self.inliers, bool)).tolist()

    def to_json(self) -> dict:
        """The ``weldcell/hand-eye@1`` document."""

        def conv(v):
            if isinstance(v, np.ndarray):
                return v.tolist()
            if isinstance(v, dict):
                return {k: conv(x) for k, x in v.items()}
            if isinstance(v, list | tuple):
                return [conv(x) for x in v]
            if isinstance(v, np.generic):
                return v.item()
            return v

        doc = {
            "schema": SCHEMA,
            "config": self.config,
            "transform": self.name,
            "T": np.asarray(self.T).tolist(),
            "convention": self.convention,
            "frames": {"from": self.name.split("_")[-1], "to": self.name.split("_")[1]},
            "units": "m",
            "method": self.method,
            "settings": conv(self.settings),
            "residuals_m": np.asarray(self.residuals).tolist(),
            "inliers": np.asarray(self.inliers, bool).tolist(),
            "outliers": self.outliers,
            "metrics": conv(self.metrics),
            "extra": conv(self.extra),
            "warnings": list(self.warnings),
        }
        return finite_json(doc)

    @classmethod
    def from_json(cls, doc: dict, where: str = "hand-eye result") -> HandEyeResult:
        """Read a ``weldcell/hand-eye@1`` document; DataError (naming ``where``, the file) for a wrong
        schema, a missing or mistyped key, a ``T`` that is not a finite rigid 4x4, or lengths that do
        not fit the declared units."""
        expect_object(doc, where, '{"schema": "weldcell/hand-eye@1", "T": [[...4x4...]], ...}')
        if doc.get("schema") != SCHEMA:
            raise DataError(
                f"{where}: not a hand-eye result (schema {doc.get('schema')!r})", f"expected '{SCHEMA}'"
            )
        fix = "write the file again with `weldcell calibrate hand-eye`"
        for k in ("T", "transform", "config", "method"):
            if k not in doc:
                raise DataError(f"{where}: no '{k}'", fix)
        for k in ("transform", "config", "method"):
            if not isinstance(doc[k], str):
                raise DataError(f"{where}: '{k}' is {kind_of(doc[k])}, not text", fix)
        if doc["transform"].count("_") < 2:
            raise DataError(f"{where}: transform {doc['transform']!r} is not a name like T_base_camera", fix)
        T = as_matrix(doc["T"], (4, 4), f"{where}: T", fix)
        if not is_rigid(T, tol=1e-4):
            raise DataError(f"{where}: T is not a rigid transform (rotation not orthonormal)", fix)
        units = doc.get("units", "m")
        if units != "m":
            raise DataError(f"{where}: units {units!r}; hand-eye results are in metres", 'write "units": "m"')
        if np.linalg.norm(T[:3, 3]) > MAX_TRANSLATION:
            raise DataError(
                f"{where}: T moves {np.linalg.norm(T[:3, 3]):.4g} m; that is millimetres, not metres",
                "divide the translation by 1000 (hand-eye results are in metres)",
            )
        extra_maps = {k: doc.get(k, {}) for k in ("metrics", "settings", "extra")}
        for k, v in extra_maps.items():
            expect_object(v, f"{where}: {k}")
        residuals = doc.get("residuals_m", [])
        inliers = doc.get("inliers", [])
        if (
            not isinstance(residuals, list)
            or not isinstance(inliers, list)
            or (inliers and len(inliers) != len(residuals))
        ):
            raise DataError(f"{where}: residuals_m and inliers must be lists of one value per sample", fix)
        try:
            res = np.asarray([np.nan if r is None else r for r in residuals], float)
        except (TypeError, ValueError):
            raise DataError(f"{where}: residuals_m holds values that are not numbers", fix) from None
        warnings = doc.get("warnings", [])
        if not isinstance(warnings, list):
            raise DataError(f"{where}: warnings is {kind_of(warnings)}, not a list", fix)
        return cls(
            T=T,
            name=doc["transform"],
            config=doc["config"],
            method=doc["method"],
            residuals=res,
            inliers=np.asarray(inliers, bool),
            metrics=extra_maps["metrics"],
            settings=extra_maps["settings"],
            extra=extra_maps["extra"],
            warnings=[str(w) for w in warnings],
        )


# -- units ----------------------------------------------------------------------------------------

#: nothing a cell records sits within 1 cm of its frame's origin on median (a camera's minimum range, a
#: flange never at the robot base's origin): below it, metres were read as millimetres
MIN_MEDIAN_DISTANCE = 0.01


def check_units(name: str, points: np.ndarray, units: str = "m", max_range: float = 20.0) -> None:
    """Refuse points that cannot be metres, both ways: a camera or robot coordinate beyond ``max_range``
    m (millimetres read as metres), a median distance from the origin under 1 cm (metres read as
    millimetres), and columns where some samples are ~1000x the others (a mm/m mix in one data set)."""
    P = np.asarray(points, float).reshape(-1, 3)
    norms = np.linalg.norm(P, axis=1)
    if units == "m" and np.any(norms > max_range):
        big = np.flatnonzero(norms > max_range)
        if len(big) == len(P):
            raise DataError(
                f"{name} is up to {norms.max():.4g} units from the origin; that is millimetres, not metres",
                "declare units 'mm' (the reader scales to metres) or divide by 1000",
            )
        raise DataError(
            f"{name}: samples {big.tolist()[:10]} are ~1000x farther than the others (mixed mm and m)",
            "convert those samples to metres (divide by 1000) or re-export them in one unit",
        )
    med = float(np.median(norms)) if len(norms) else 0.0
    if units == "m" and 0 < med < MIN_MEDIAN_DISTANCE:
        raise DataError(
            f"{name} lie within {med * 1e3:.3g} mm of the origin on median (span "
            f"{np.ptp(P, axis=0).max() * 1e3:.3g} mm): the values look like metres read as millimetres, a "
            "unit problem before a motion problem",
            "declare units 'm' (the values are already metres)",
        )
    if med > 0:
        ratio = norms / med
        odd = np.flatnonzero((ratio > 100) | (ratio < 0.01))
        if len(odd):
            raise DataError(
                f"{name}: samples {odd.tolist()[:10]} differ from the median distance by >100x (mixed units)",
                "convert every sample to one unit (metres) before calibrating",
            )


# -- samples and result files -------------------------------------------------------------------

SAMPLES_SCHEMA = "weldcell/handeye-samples@1"
_POSE_KEYS = ("T_base_flange", "T_cam_target", "T_base_arm", "T_base2_flange2")
_POINT_KEYS = ("p_cam", "p_base")


@dataclass
class SampleSet:
    """Samples (metres) with their configuration, the folder they came from and reading notes."""

    config: str
    samples: list[HandEyeSample]
    root: Path | None = None
    notes: list[str] = field(default_factory=list)
    feature_base: str | list[float] | None = None  # the file's "feature_base" (metres), if it gives one
    board: dict | None = None  # what the layout says of the board (e.g. {"square": 0.02} in metres)


_SAMPLE_KEYS = (*_POSE_KEYS, *_POINT_KEYS, "cloud", "image", "normal", "cloud_units", "phase", "id")
_DOC_KEYS = ("schema", "config", "units", "samples", "feature_base")
_POSE_FIX = "write the pose as 4 rows of 4 numbers (row-major 4x4, last row 0 0 0 1)"


def _pose(value, scale: float, where: str) -> np.ndarray:
    T = as_matrix(value, (4, 4), where, _POSE_FIX)
    if not is_rigid(T, tol=1e-4):
        raise DataError(
            f"{where} is not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)",
            "check the pose export (row-major 4x4, rotation part orthonormal)",
        )
    T = T.copy()
    T[:3, 3] *= scale
    return T


def _units(value, where: str) -> str:
    if not isinstance(value, str) or value not in UNIT_SCALE:
        raise DataError(f"{where}: unknown units {short(value)}", f"use one of {', '.join(UNIT_SCALE)}")
    return value


def _file_ref(value, where: str, root: Path) -> str:
    if not isinstance(value, str):
        raise DataError(f"{where} is {kind_of(value)}, not a file name", 'write it as text, e.g. "000.ply"')
    return str((root / value).resolve())


def _read_sample(s, i: int, path: Path, units: str) -> HandEyeSample:
    where = f"{path.name} sample {i}"
    expect_object(s, where, '{"T_base_flange": [[...4x4...]], "cloud": "000.ply"}')
    check_keys(s, _SAMPLE_KEYS, where)
    scale = UNIT_SCALE[units]
    kw: dict = {"meta": {"index": i}}
    for k in _POSE_KEYS:
        if s.get(k) is not None:
            kw[k] = _pose(s[k], scale, f"{where} {k}")
    for k in _POINT_KEYS:
        if s.get(k) is not None:
            kw[k] = as_matrix(s[k], (3,), f"{where} {k}", "write it as [x, y, z] (3 finite numbers)") * scale
    for k in ("cloud", "image"):
        if s.get(k):
            kw[k] = _file_ref(s[k], f"{where} {k}", path.parent)
    if s.get("normal") is not None:
        kw["meta"]["normal"] = _unit_vector(s["normal"], f"{where} normal")
    kw["meta"]["cloud_units"] = _units(s.get("cloud_units", units), f"{where} cloud_units")
    if s.get("phase"):
        kw["phase"] = str(s["phase"])
    if s.get("id") not in (None, ""):
        kw["meta"]["id"] = str(s["id"])
    elif isinstance(kw.get("cloud") or kw.get("image"), str):
        kw["meta"]["id"] = Path(kw.get("cloud") or kw.get("image")).stem
    return HandEyeSample(**kw)


def read_samples(path: str | Path, units: str | None = None) -> SampleSet:
    """Read a ``samples.json``; relative cloud/image paths are resolved against its folder. Lengths
    are converted to metres; a value that does not fit the declared units (e.g. millimetres in a
    file that says metres, metres in one that says millimetres, or a mix) raises DataError naming
    the samples and the fix. Unknown keys (misspellings) and values of the wrong type are refused.
    ``units`` (the command line's ``--units``) overrides the file's ``units``."""
    path = Path(path)
    doc = read_json_file(path, "samples file")
    schema = doc.get("schema") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or doc.get("schema") != SAMPLES_SCHEMA:
        raise DataError(
            f"{path}: not a hand-eye samples file (schema {short(schema)})",
            f'write it with "schema": "{SAMPLES_SCHEMA}"',
        )
    check_keys(doc, _DOC_KEYS, str(path))
    units = _units(units or doc.get("units", "m"), str(path))
    scale = UNIT_SCALE[units]
    config = doc.get("config", "eye-on-base")
    if not isinstance(config, str):
        raise DataError(f"{path}: config is {kind_of(config)}", 'write e.g. "config": "eye-on-base"')
    config = config_name(config)
    raw = doc.get("samples")
    if not isinstance(raw, list) or not raw:
        raise DataError(f"{path}: no samples", 'add a "samples" list with one entry per robot pose')
    out = [_read_sample(s, i, path, units) for i, s in enumerate(raw)]
    for k in ("p_cam", "p_base"):
        pts = [s_.__dict__[k] for s_ in out if s_.__dict__[k] is not None]
        if pts:
            check_units(f"{path.name} {k}", np.array(pts))
            _check_declared_units(f"{path.name} {k}", np.array(pts), units)
    tr = [s_.T_base_flange[:3, 3] for s_ in out if s_.T_base_flange is not None]
    if tr:
        check_units(f"{path.name} T_base_flange translations", np.array(tr))
        _check_declared_units(f"{path.name} T_base_flange translations", np.array(tr), units)
    feature_base = _feature_base(doc.get("feature_base"), scale, path)
    return SampleSet(config, out, path.parent, feature_base=feature_base)


# Nothing a cell records sits within 1 cm of its frame's origin on median: a flange is never at the
# robot base's origin, a camera's minimum range is several centimetres. Below that the numbers are
# metres in a file that says millimetres (1000x too small).
_MIN_MEDIAN_DISTANCE = 0.01


def _check_declared_units(name: str, points_m: np.ndarray, units: str) -> None:
    norms = np.linalg.norm(np.asarray(points_m, float).reshape(-1, 3), axis=1)
    med = float(np.median(norms)) if len(norms) else 0.0
    if 0.0 < med < _MIN_MEDIAN_DISTANCE and units != "m":
        raise DataError(
            f"{name}: the median distance from the origin is {med * 1e3:.3g} mm with units '{units}'; "
            "the values look like metres",
            'write "units": "m" in the file (or pass --units m)',
        )


def _unit_vector(value, where: str) -> list[float]:
    v = as_matrix(value, (3,), where, "write the normal as [x, y, z], not all zero")
    if np.linalg.norm(v) < 1e-9:
        raise DataError(f"{where} must be 3 finite numbers, not all zero", "fix or drop the sample's normal")
    return (v / np.linalg.norm(v)).tolist()


def _feature_base(value, scale: float, path: Path) -> str | list[float] | None:
    if value is None or value in ("origin", "estimate"):
        return value
    fix = "give the fixed feature's position in the base frame, or 'estimate'"
    if isinstance(value, str):
        raise DataError(f"{path.name}: feature_base {short(value)} is not 'origin', 'estimate', [x,y,z]", fix)
    p = as_matrix(value, (3,), f"{path.name}: feature_base", fix)
    return (p * scale).tolist()


def write_samples(
    path: str | Path,
    samples: list[HandEyeSample],
    config: str = "eye-on-base",
    feature_base: str | list[float] | None = None,
) -> Path:
    """Write samples (metres) as ``samples.json``. Clouds/images must already be files (their
    paths are written relative to the file's folder when possible); a sample's ``meta["normal"]`` is
    kept; ``feature_base`` (moving camera: "origin", "estimate" or xyz in m) is written when given."""
    path = Path(path)
    rows = []
    for s in samples:
        row: dict = {}
        for k in _POSE_KEYS + _POINT_KEYS:
            v = getattr(s, k)
            if v is not None:
                row[k] = np.asarray(v, float).tolist()
        for k in ("cloud", "image"):
            v = getattr(s, k)
            if isinstance(v, str | Path):
                p = Path(v)
                try:
                    row[k] = str(p.resolve().relative_to(path.parent.resolve()))
                except ValueError:
                    row[k] = str(p)
        if s.phase:
            row["phase"] = s.phase
        if s.meta.get("id") not in (None, ""):
            row["id"] = str(s.meta["id"])
        if s.meta.get("normal") is not None:
            row["normal"] = np.asarray(s.meta["normal"], float).tolist()
        rows.append(row)
    doc: dict = {"schema": SAMPLES_SCHEMA, "config": config_name(config), "units": "m"}
    if feature_base is not None:
        fb = feature_base
        doc["feature_base"] = fb if isinstance(fb, str) else [float(v) for v in fb]
    return write_json(path, finite_json({**doc, "samples": rows}))


def write_result(path: str | Path, result: HandEyeResult) -> Path:
    """Write a ``weldcell/hand-eye@1`` file."""
    return write_json(path, result.to_json())


def read_result(path: str | Path) -> HandEyeResult:
    """Read a ``weldcell/hand-eye@1`` file."""
    return HandEyeResult.from_json(read_json_file(path, "hand-eye result"), where=str(path))


def guess_length_units(values: np.ndarray, what: str) -> str:
    """``"mm"`` or ``"m"`` from the median distance of points from their origin (DataError if unclear)."""
    med = float(np.median(np.linalg.norm(np.asarray(values, float).reshape(-1, 3), axis=1)))
    if med > 20:
        return "mm"
    if med < 5:
        return "m"
    raise DataError(
        f"cannot tell whether {what} is in m or mm (median distance {med:.3g})",
        "say which: pass --units m or --units mm (or convert to metres before reading)",
    )
