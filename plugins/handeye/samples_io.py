"""Readers for the layouts of the ancorasir flange hand-eye data set (their own unit mix converted
explicitly), and the ``weldcell/handeye-samples@1`` / ``weldcell/hand-eye@1`` readers and writers,
which live in :mod:`weldcell.sdk.handeye_files` and are re-exported here for existing imports
(docs/file-formats.md, benchmarks, user scripts)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from weldcell.sdk.cloud import UNIT_SCALE
from weldcell.sdk.datafile import as_matrix, expect_object, read_json_file
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_quat, T_from_rotvec
from weldcell.sdk.handeye_files import (
    SAMPLES_SCHEMA,
    HandEyeSample,
    SampleSet,
    guess_length_units,
    read_result,
    read_samples,
    write_result,
    write_samples,
)

__all__ = [
    "SAMPLES_SCHEMA",
    "SampleSet",
    "read_ancorasir_kinect",
    "read_ancorasir_point_pairs",
    "read_ancorasir_sample",
    "read_result",
    "read_samples",
    "write_result",
    "write_samples",
]



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
    u_cam, u_rob = guess_length_units(p_cam, "p_cam"), guess_length_units(p_rob, "p_robot")
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
        units = guess_length_units(np.vstack([pc, pr]), "the point pairs")
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
