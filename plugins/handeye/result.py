"""Hand-eye samples, configurations and the result record (``weldcell/hand-eye@1``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
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
        from weldcell.sdk.datafile import as_matrix, expect_object, kind_of

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
