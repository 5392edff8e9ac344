"""Reading and writing hand-eye samples and results.

``samples.json`` (``weldcell/handeye-samples@1``)::

    {"schema": "weldcell/handeye-samples@1", "config": "eye-on-base", "units": "m",
     "samples": [{"T_base_flange": [[4x4]], "cloud": "000.ply"}, {"T_base_flange": ..., "p_cam": [x, y, z]},
                 {"T_base_flange": ..., "image": "003.png"}, ...]}

``units`` applies to every length (translations, p_cam, p_base, clouds); values are converted to
metres on reading. A sample may carry ``"normal"`` (the measured face normal in the camera frame, for
the stage's ``normal_weight``); the file may say where a fixed feature is for a moving camera,
``"feature_base"``: ``"origin"`` (the base mounting flange), ``"estimate"`` or ``[x, y, z]``.
Readers for the layouts of the ancorasir flange hand-eye data set convert their own unit mix
explicitly.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from weldcell.plugins.handeye.diagnostics import check_units
from weldcell.plugins.handeye.result import HandEyeResult, HandEyeSample, config_name
from weldcell.sdk.artifacts import read_json, write_json
from weldcell.sdk.cloud import UNIT_SCALE
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_quat, T_from_rotvec, is_rigid

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


def _pose(value, scale: float, where: str) -> np.ndarray:
    T = np.asarray(value, dtype=float)
    if T.shape != (4, 4):
        raise DataError(
            f"{where} is not a 4x4 matrix (shape {T.shape})", "write the pose as 4 rows of 4 numbers"
        )
    if not np.all(np.isfinite(T)):
        raise DataError(f"{where} has NaN or infinite values", "drop the sample or re-record the pose")
    if not is_rigid(T, tol=1e-4):
        raise DataError(
            f"{where} is not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)",
            "check the pose export (row-major 4x4, rotation part orthonormal)",
        )
    T = T.copy()
    T[:3, 3] *= scale
    return T


def read_samples(path: str | Path) -> SampleSet:
    """Read a ``samples.json``; relative cloud/image paths are resolved against its folder. Lengths
    are converted to metres; a value that does not fit the declared units (e.g. millimetres in a
    file that says metres, or a mix) raises DataError naming the samples and the fix."""
    path = Path(path)
    doc = read_json(path)
    schema = doc.get("schema") if isinstance(doc, dict) else None
    if not isinstance(doc, dict) or doc.get("schema") != SAMPLES_SCHEMA:
        raise DataError(
            f"{path}: not a hand-eye samples file (schema {schema!r})",
            f'write it with "schema": "{SAMPLES_SCHEMA}"',
        )
    units = doc.get("units", "m")
    if units not in UNIT_SCALE:
        raise DataError(f"{path}: unknown units '{units}'", f"use one of {', '.join(UNIT_SCALE)}")
    scale = UNIT_SCALE[units]
    config = config_name(doc.get("config", "eye-on-base"))
    raw = doc.get("samples")
    if not isinstance(raw, list) or not raw:
        raise DataError(f"{path}: no samples", 'add a "samples" list with one entry per robot pose')
    out = []
    for i, s in enumerate(raw):
        kw: dict = {"meta": {"index": i}}
        for k in _POSE_KEYS:
            if s.get(k) is not None:
                kw[k] = _pose(s[k], scale, f"{path.name} sample {i} {k}")
        for k in _POINT_KEYS:
            if s.get(k) is not None:
                p = np.asarray(s[k], float).reshape(-1)
                if p.shape != (3,) or not np.all(np.isfinite(p)):
                    raise DataError(
                        f"{path.name} sample {i} {k} must be 3 finite numbers", "fix or drop the sample"
                    )
                kw[k] = p * scale
        for k in ("cloud", "image"):
            if s.get(k):
                kw[k] = str((path.parent / s[k]).resolve())
        if s.get("normal") is not None:
            kw["meta"]["normal"] = _unit_vector(s["normal"], f"{path.name} sample {i} normal")
        kw["meta"]["cloud_units"] = s.get("cloud_units", units)
        if s.get("phase"):
            kw["phase"] = str(s["phase"])
        out.append(HandEyeSample(**kw))
    for k in ("p_cam", "p_base"):
        pts = [s_.__dict__[k] for s_ in out if s_.__dict__[k] is not None]
        if pts:
            check_units(f"{path.name} {k}", np.array(pts))
    tr = [s_.T_base_flange[:3, 3] for s_ in out if s_.T_base_flange is not None]
    if tr:
        check_units(f"{path.name} T_base_flange translations", np.array(tr))
    feature_base = _feature_base(doc.get("feature_base"), scale, path)
    return SampleSet(config, out, path.parent, feature_base=feature_base)


def _unit_vector(value, where: str) -> list[float]:
    v = np.asarray(value, float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-9:
        raise DataError(f"{where} must be 3 finite numbers, not all zero", "fix or drop the sample's normal")
    return (v / np.linalg.norm(v)).tolist()


def _feature_base(value, scale: float, path: Path) -> str | list[float] | None:
    if value is None or value in ("origin", "estimate"):
        return value
    p = np.asarray(value, float).reshape(-1) if not isinstance(value, str) else np.zeros(0)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise DataError(
            f"{path.name}: feature_base {value!r} is not 'origin', 'estimate' or [x, y, z]",
            "give the fixed feature's position in the base frame, or 'estimate'",
        )
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
        if s.meta.get("normal") is not None:
            row["normal"] = np.asarray(s.meta["normal"], float).tolist()
        rows.append(row)
    doc: dict = {"schema": SAMPLES_SCHEMA, "config": config_name(config), "units": "m"}
    if feature_base is not None:
        fb = feature_base
        doc["feature_base"] = fb if isinstance(fb, str) else [float(v) for v in fb]
    return write_json(path, {**doc, "samples": rows})


def write_result(path: str | Path, result: HandEyeResult) -> Path:
    """Write a ``weldcell/hand-eye@1`` file."""
    return write_json(path, result.to_json())


def read_result(path: str | Path) -> HandEyeResult:
    """Read a ``weldcell/hand-eye@1`` file."""
    return HandEyeResult.from_json(read_json(path))


def _guess_length_units(values: np.ndarray, what: str) -> str:
    med = float(np.median(np.linalg.norm(np.asarray(values, float).reshape(-1, 3), axis=1)))
    if med > 20:
        return "mm"
    if med < 5:
        return "m"
    raise DataError(
        f"cannot tell whether {what} is in m or mm (median distance {med:.3g})",
        "convert it to metres before reading",
    )


def read_ancorasir_sample(folder: str | Path) -> SampleSet:
    """The ``calib_toolbox/data/<date>-sample`` layout: ``calib_data.json`` with per sample
    ``p_cam`` (camera, mm), ``p_robot`` (base, m) and ``robot_pose`` ``[x y z qw qx qy qz]`` (m,
    scalar-first quaternion), plus one ``NN_tool.ply`` raw scan (mm) per entry in sorted order.
    The mm/m mix is detected per field and converted; the notes say what was done."""
    folder = Path(folder)
    doc = read_json(folder / "calib_data.json")
    keys = sorted(doc, key=lambda k: int(k) if str(k).isdigit() else str(k))
    p_cam = np.array([doc[k]["p_cam"] for k in keys], float)
    p_rob = np.array([doc[k]["p_robot"] for k in keys], float)
    pose = np.array([doc[k]["robot_pose"] for k in keys], float)
    u_cam, u_rob = _guess_length_units(p_cam, "p_cam"), _guess_length_units(p_rob, "p_robot")
    notes = []
    if u_cam != u_rob:
        notes.append(f"mixed units: p_cam in {u_cam}, p_robot/robot_pose in {u_rob}; both converted to m")
    p_cam = p_cam * UNIT_SCALE[u_cam]
    p_rob = p_rob * UNIT_SCALE[u_rob]
    q = pose[:, 3:7]
    if np.any(np.abs(np.linalg.norm(q, axis=1) - 1) > 1e-3):
        raise DataError(f"{folder}: robot_pose quaternions are not unit length", "check the export")
    notes.append("robot_pose quaternions read as [qw qx qy qz] (scalar first) and reordered to [x y z w]")
    clouds = sorted(folder.glob("*_tool.ply"))
    if clouds and len(clouds) != len(keys):
        notes.append(f"{len(clouds)} *_tool.ply scans for {len(keys)} samples: scans not attached")
        clouds = []
    samples = []
    for i, k in enumerate(keys):
        T = T_from_quat(q[i][[1, 2, 3, 0]], pose[i, :3] * UNIT_SCALE[u_rob])
        samples.append(
            HandEyeSample(
                T_base_flange=T,
                p_cam=p_cam[i],
                p_base=p_rob[i],
                cloud=str(clouds[i]) if clouds else None,
                meta={"key": k, "cloud_units": "mm", "source": str(folder)},
            )
        )
    return SampleSet("eye-on-base", samples, folder, notes)


def read_ancorasir_point_pairs(folder: str | Path, units: str = "mm") -> SampleSet:
    """``paper_dda5a35/data/<robot>/`` point pairs: ``p_camera_mat.npy`` and ``p_robot_mat.npy``
    (3 x N, millimetres). Only positions: samples carry ``p_cam`` and ``p_base``."""
    folder = Path(folder)
    try:
        pc = np.load(folder / "p_camera_mat.npy")
        pr = np.load(folder / "p_robot_mat.npy")
    except FileNotFoundError as e:
        raise DataError(
            f"{folder}: missing {Path(e.filename).name}", "point at a paper_dda5a35/data/<robot> folder"
        ) from None
    pc, pr = np.asarray(pc, float), np.asarray(pr, float)
    if pc.shape[0] == 3 and pc.shape[1] != 3:
        pc, pr = pc.T, pr.T
    if pc.shape != pr.shape:
        raise DataError(
            f"{folder}: {pc.shape} camera points but {pr.shape} robot points", "the files do not match"
        )
    s = UNIT_SCALE[units]
    samples = [
        HandEyeSample(p_cam=a * s, p_base=b * s, meta={"index": i})
        for i, (a, b) in enumerate(zip(pc, pr, strict=True))
    ]
    return SampleSet("eye-on-base", samples, folder, [f"point pairs read as {units}"])


def read_ancorasir_kinect(folder: str | Path) -> SampleSet:
    """``paper_dda5a35/Kinect_Result``: ``readRobot.txt`` (UR poses: x y z in mm and a rotation
    vector in rad) and ``measureRobot.txt`` (circle centres in the camera, mm). The circle is the
    90 mm wrist circle, not the flange face (§4.2), so its offset along the flange axis is unknown:
    calibrate with ``feature="estimate"``."""
    folder = Path(folder)
    try:
        rob = np.loadtxt(folder / "readRobot.txt", ndmin=2)
        cam = np.loadtxt(folder / "measureRobot.txt", ndmin=2)
    except (FileNotFoundError, OSError) as e:
        raise DataError(
            f"{folder}: cannot read the Kinect result files ({e})", "point at the Kinect_Result folder"
        ) from None
    if len(rob) != len(cam) or rob.shape[1] < 6 or cam.shape[1] < 3:
        raise DataError(
            f"{folder}: {len(rob)} robot poses but {len(cam)} measurements", "the files do not match"
        )
    samples = [
        HandEyeSample(
            T_base_flange=T_from_rotvec(r[3:6], r[:3] * 1e-3), p_cam=c[:3] * 1e-3, meta={"index": i}
        )
        for i, (r, c) in enumerate(zip(rob, cam, strict=True))
    ]
    return SampleSet(
        "eye-on-base", samples, folder, ["lengths in mm converted to m; rotations as UR rotation vectors"]
    )
