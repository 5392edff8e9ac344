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
from weldcell.plugins.handeye.result import HandEyeResult, HandEyeSample, config_name, finite_json
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


def _guess_length_units(values: np.ndarray, what: str) -> str:
    med = float(np.median(np.linalg.norm(np.asarray(values, float).reshape(-1, 3), axis=1)))
    if med > 20:
        return "mm"
    if med < 5:
        return "m"
    raise DataError(
        f"cannot tell whether {what} is in m or mm (median distance {med:.3g})",
        "say which: pass --units m or --units mm (or convert to metres before reading)",
    )


def read_ancorasir_sample(folder: str | Path) -> SampleSet:
    """The ``calib_toolbox/data/<date>-sample`` layout: ``calib_data.json`` with per sample
    ``p_cam`` (camera, mm), ``p_robot`` (base, m) and ``robot_pose`` ``[x y z qw qx qy qz]`` (m,
    scalar-first quaternion), plus one ``NN_tool.ply`` raw scan (mm) per entry in sorted order.
    The mm/m mix is detected per field and converted; the notes say what was done."""
    folder = Path(folder)
    f = folder / "calib_data.json"
    doc = expect_object(read_json_file(f, "calib_data.json"), str(f), '{"0": {"p_cam": ..., ...}}')
    keys = sorted(doc, key=lambda k: int(k) if str(k).isdigit() else str(k))
    if not keys:
        raise DataError(f"{f} lists no samples", "record at least 4 flange positions")
    fields = {"p_cam": (3,), "p_robot": (3,), "robot_pose": (7,)}
    cols = {name: [] for name in fields}
    for k in keys:
        entry = expect_object(doc[k], f"{f.name} sample {k}")
        for name, shape in fields.items():
            if name not in entry:
                raise DataError(
                    f"{f.name} sample {k} has no '{name}'", f"give every sample {', '.join(fields)}"
                )
            cols[name].append(
                as_matrix(entry[name], shape, f"{f.name} sample {k} {name}", "write the numbers")
            )
    p_cam, p_rob, pose = (np.array(cols[n]) for n in fields)
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
                meta={
                    "key": k,
                    "index": i,
                    "id": clouds[i].name.split("_")[0] if clouds else str(k),
                    "cloud_units": "mm",
                    "source": str(folder),
                },
            )
        )
    return SampleSet("eye-on-base", samples, folder, notes)


def read_ancorasir_point_pairs(folder: str | Path, units: str = "auto") -> SampleSet:
    """``paper_dda5a35/data/<robot>/`` point pairs: ``p_camera_mat.npy`` and ``p_robot_mat.npy``
    (3 x N, millimetres in the authors' files). Only positions: samples carry ``p_cam`` and ``p_base``.
    ``units`` "auto" tells mm from m by the distances (a camera sees the flange 0.2-5 m away); given
    units that do not fit are refused by the unit checks of :func:`calibrate`."""
    folder = Path(folder)
    pc, pr = _load_npy(folder / "p_camera_mat.npy"), _load_npy(folder / "p_robot_mat.npy")
    if pc.ndim != 2 or pr.ndim != 2 or 3 not in pc.shape:
        raise DataError(f"{folder}: the point files are not 3 x N arrays", "save them as 3 x N (mm)")
    if pc.shape[0] == 3 and pc.shape[1] != 3:
        pc, pr = pc.T, pr.T
    if pc.shape != pr.shape:
        raise DataError(
            f"{folder}: {pc.shape} camera points but {pr.shape} robot points", "the files do not match"
        )
    notes = []
    if units == "auto":
        units = _guess_length_units(np.vstack([pc, pr]), "the point pairs")
        notes.append(f"point pairs read as {units} (from their size; --units overrides)")
    else:
        notes.append(f"point pairs read as {units}")
    s = UNIT_SCALE[units]
    samples = [
        HandEyeSample(p_cam=a * s, p_base=b * s, meta={"index": i})
        for i, (a, b) in enumerate(zip(pc, pr, strict=True))
    ]
    return SampleSet("eye-on-base", samples, folder, notes)


def read_ancorasir_kinect(folder: str | Path) -> SampleSet:
    """``paper_dda5a35/Kinect_Result``: ``readRobot.txt`` (UR poses: x y z in mm and a rotation
    vector in rad) and ``measureRobot.txt`` (circle centres in the camera, mm). The circle is the
    90 mm wrist circle, not the flange face (§4.2), so its offset along the flange axis is unknown:
    calibrate with ``feature="estimate"``."""
    folder = Path(folder)
    try:
        rob = np.loadtxt(folder / "readRobot.txt", ndmin=2)
        cam = np.loadtxt(folder / "measureRobot.txt", ndmin=2)
    except (OSError, ValueError, UnicodeDecodeError) as e:
        why = " ".join(str(e).split())[:120]
        raise DataError(
            f"{folder}: cannot read the Kinect result files ({why})", "point at the Kinect_Result folder"
        ) from None
    if not (np.all(np.isfinite(rob)) and np.all(np.isfinite(cam))):
        raise DataError(f"{folder}: the Kinect result files hold NaN or infinite values", "export them again")
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


def _load_npy(f: Path) -> np.ndarray:
    """A finite float array from a ``.npy`` file (no pickles); DataError naming the file otherwise."""
    try:
        arr = np.asarray(np.load(f, allow_pickle=False), float)
    except FileNotFoundError:
        raise DataError(
            f"{f.parent}: missing {f.name}", "point at a paper_dda5a35/data/<robot> folder"
        ) from None
    except (OSError, ValueError, TypeError, EOFError) as e:
        why = " ".join(str(e).split())[:100]
        raise DataError(
            f"{f}: not a numeric .npy array ({why})", "save it with numpy.save as a 3 x N array"
        ) from None
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{f}: holds NaN or infinite values", "drop those points and save it again")
    return arr
