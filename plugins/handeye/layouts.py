"""Readers for recording layouts other than ``samples.json``, with the checks a guessed convention needs.

``rwhe`` — the robot-world/hand-eye chessboard data sets of Tabb & Yousef and Ali et al. (e.g. the
KUKA sets of github.com/ihtishamaliktk/RWHE-Calib, ``Datasets/kuka_1``): a folder of board photos
(``01.png`` …, or ``im_01.bmp`` …, sorted by name), ``RobotPosesVec.txt`` (one robot flange pose per
photo, 16 numbers a line: the 4x4 ``T_base_flange`` row-major, metres) and ``squaresize.txt`` (the
chessboard square, e.g. ``20mm``). The camera rides on the robot: eye-in-hand.

``ancorasir-aubo`` — the layout the paper's authors record on their AUBO i5 cell (their scripts
``calibration_ransac_circle_aubo.py`` and ``utils.write_data``): a folder with

* ``data.txt``: one block per pose::

      p_robot 6-DoF index:<timestamp>
      [x, y, z, q1, q2, q3, q4]
      p_camera 3-DoF index:<timestamp>
      [x, y, z]

  robot flange (``tool0``) position and orientation quaternion in the base frame, and the measured
  flange-circle centre in the camera; lengths in metres in the authors' files (told from the size);
* ``tool0_<timestamp>.pcd``: the segmented flange face of that pose (optional).

The quaternion order is not written in the file. Assumed: ``[qx, qy, qz, qw]`` (scalar last), the ROS
order — the AUBO poses come from ROS (``geometry_msgs/Pose``) and the authors' AUBO script builds
``T_base_tool`` with ``tf.transformations.quaternion_matrix``, which takes ``[x, y, z, w]``; their later
``calib_toolbox`` writes ``[qw, qx, qy, qz]`` instead, so both are checked: with the camera placed by
the positions alone (eqs. 10-12 with the flange centre at the TCP), the flange's z axis must face the
camera (point back along the line of sight, within 80 deg) in every pose, or no scanner could have seen
its face. Where every pose has its ``tool0`` face scan, the stronger check is used: the flange z predicted in
the camera must lie within 10 deg of the scanned face's normal. The order that fails is rejected with
the count of poses it would turn away; when both pass
(robot orientations symmetric about the view) the ROS order is kept; when neither passes the data are
refused.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from weldcell.sdk.cloud import UNIT_SCALE
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_quat
from weldcell.sdk.handeye_files import HandEyeSample, SampleSet, guess_length_units

QUATERNION_ORDERS = ("auto", "xyzw", "wxyz")
#: a face more than this far from facing the camera cannot be scanned (cos 80 deg)
MIN_FACING = float(np.cos(np.radians(80)))
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def is_aubo_folder(path: Path) -> bool:
    """A folder with a ``data.txt`` holding ``p_robot`` blocks."""
    f = path / "data.txt"
    if not f.is_file():
        return False
    try:
        return "p_robot" in f.read_text(encoding="utf-8", errors="replace")[:4096]
    except OSError:
        return False


def _vector(line: str, n: tuple[int, ...], where: str) -> np.ndarray:
    body = line[line.find("[") + 1 : line.rfind("]")] if "[" in line else line
    vals = [float(v) for v in re.findall(_NUM, body)]
    if len(vals) not in n or not np.all(np.isfinite(vals)):
        raise DataError(
            f"{where}: expected {' or '.join(map(str, n))} numbers in [...], got {len(vals)}: "
            f"{line.strip()[:80]}",
            "write the pose as [x, y, z, qx, qy, qz, qw] and the centre as [x, y, z]",
        )
    return np.array(vals)


def parse_data_txt(path: Path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``(index, p_robot (7,), p_camera (3,))`` per block of an authors' ``data.txt``."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    out = []
    i = 0
    while i < len(lines):
        line = lines[i]
        if "p_robot" in line:
            index = line.split("index:", 1)[1].strip() if "index:" in line else str(len(out))
            where = f"{path.name} line {i + 2} (index {index})"
            if i + 3 >= len(lines) or "p_camera" not in lines[i + 2]:
                raise DataError(
                    f"{where}: a p_robot block without its p_camera line",
                    "each pose needs 'p_robot ... index:<t>', [pose], 'p_camera ... index:<t>', [centre]",
                )
            robot = _vector(lines[i + 1], (7,), where)
            cam = _vector(lines[i + 3], (3,), f"{path.name} line {i + 4} (index {index})")
            out.append((index, robot, cam))
            i += 4
        else:
            i += 1
    if not out:
        raise DataError(f"{path}: no 'p_robot' blocks", "point at the folder of the authors' data.txt")
    return out


def _facing(R_cam_base: np.ndarray, Rs: np.ndarray, p_cam: np.ndarray) -> np.ndarray:
    """cos of the angle between each flange z (in the camera) and the direction back to the camera."""
    z_cam = np.einsum("ij,njk->nik", R_cam_base, Rs)[:, :, 2]
    view = -p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
    return np.einsum("ni,ni->n", z_cam, view)


#: a scanned face normal and the flange z predicted from the robot pose agree better than this (rad);
#: the real Franka sample agrees to 0.6-0.8 deg
MAX_NORMAL_ANGLE = float(np.radians(10))


def face_normals(clouds: list[Path | None], units: str) -> np.ndarray | None:
    """The plane normal (toward the camera) of each segmented face cloud (``tool0_<t>.pcd`` holds the
    face only); None unless every pose has one."""
    from weldcell.sdk.cloud import read_cloud

    if not clouds or any(c is None for c in clouds):
        return None
    out = []
    for c in clouds:
        P = read_cloud(c, units=units, frame="camera").points
        mu = P.mean(0)
        n = np.linalg.svd(P - mu, full_matrices=False)[2][2]
        out.append(n if n @ -mu > 0 else -n)
    return np.array(out)


def check_quaternion_order(
    p_cam: np.ndarray,
    p_base: np.ndarray,
    q: np.ndarray,
    order: str = "auto",
    normals: np.ndarray | None = None,
) -> tuple[str, list[str]]:
    """The quaternion order of ``q`` (n, 4) under which the robot's flange z agrees with what the camera
    saw (see the module docstring): with ``normals`` (the scanned face normals, camera frame) within
    :data:`MAX_NORMAL_ANGLE` of them in every pose, else facing the camera (within 80 deg). Returns the
    order and notes; DataError when the order given (or both) disagrees."""
    from weldcell.sdk.pointfit import scaled_svd_fit

    if len(p_cam) < 3:
        raise DataError(f"{len(p_cam)} poses; at least 3 are needed", "record more poses")
    R_cb = scaled_svd_fit(p_cam, p_base).T[:3, :3].T
    perm = {"xyzw": [0, 1, 2, 3], "wxyz": [1, 2, 3, 0]}
    n = len(q)
    bad, worst = {}, {}
    for name, idx in perm.items():
        Rs = np.array([T_from_quat(qq[idx] / np.linalg.norm(qq), np.zeros(3))[:3, :3] for qq in q])
        if normals is None:
            ang = np.arccos(np.clip(_facing(R_cb, Rs, p_cam), -1, 1))
            bad[name] = int(np.sum(ang > np.arccos(MIN_FACING)))
        else:
            z_cam = np.einsum("ij,njk->nik", R_cb, Rs)[:, :, 2]
            ang = np.arccos(np.clip(np.einsum("ni,ni->n", z_cam, normals), -1, 1))
            bad[name] = int(np.sum(ang > MAX_NORMAL_ANGLE))
        worst[name] = float(np.degrees(ang.max()))
    what = "the scanned face normal" if normals is not None else "facing the camera"

    def why(k: str) -> str:
        name = "[x y z w]" if k == "xyzw" else "[w x y z]"
        return (
            f"{name} would turn the flange away from {what} in {bad[k]} of {n} poses"
            f" (worst {worst[k]:.0f} deg)"
        )

    if order != "auto":
        if bad[order]:
            raise DataError(
                f"quaternions read as {order}: {why(order)}",
                "check the order your recorder writes (--quaternion xyzw or wxyz) and that the poses are the "
                "flange's",
            )
        return order, [
            f"quaternions read as {order} (given); the flange z agrees with {what} in all {n} poses"
        ]
    ok = [k for k in perm if bad[k] == 0]
    if not ok:
        raise DataError(
            f"in neither quaternion order does the flange face the camera: {why('xyzw')}; {why('wxyz')}",
            "check that the poses are the flange (tool0) poses in the base frame and p_camera the flange "
            "centres in the camera",
        )
    if len(ok) == 2:
        return "xyzw", [
            f"quaternions read as [x y z w] (the ROS order of the authors' AUBO recorder); [w x y z] also "
            f"agrees with {what} in every pose (the two differ by a turn about the flange axis), so the "
            "order could not be checked: pass --quaternion if it is scalar first"
        ]
    other = "wxyz" if ok[0] == "xyzw" else "xyzw"
    return ok[0], [
        f"quaternions read as {ok[0]}: the flange z agrees with {what} in all {n} poses; {why(other)}"
    ]


def read_aubo_folder(folder: str | Path, quaternion: str = "auto", units: str | None = None) -> SampleSet:
    """The ``ancorasir-aubo`` layout (module docstring): samples with ``T_base_flange``, ``p_cam`` and,
    where ``tool0_<index>.pcd`` exists, its cloud; named by their timestamps. ``units`` overrides the
    size-based guess of each field's units."""
    folder = Path(folder)
    if quaternion not in QUATERNION_ORDERS:
        raise DataError(
            f"unknown quaternion order '{quaternion}'", f"use one of {', '.join(QUATERNION_ORDERS)}"
        )
    blocks = parse_data_txt(folder / "data.txt")
    idx = [b[0] for b in blocks]
    rob = np.array([b[1] for b in blocks])
    cam = np.array([b[2] for b in blocks])
    u_rob = units or guess_length_units(rob[:, :3], "the p_robot positions")
    u_cam = units or guess_length_units(cam, "the p_camera centres")
    notes = [
        f"ancorasir-aubo layout: {len(blocks)} poses from data.txt; p_robot in {u_rob}, p_camera in {u_cam}"
    ]
    p_base = rob[:, :3] * UNIT_SCALE[u_rob]
    p_cam = cam * UNIT_SCALE[u_cam]
    q = rob[:, 3:7]
    bad = np.flatnonzero(np.abs(np.linalg.norm(q, axis=1) - 1) > 1e-3)
    if len(bad):
        raise DataError(
            f"{folder / 'data.txt'}: quaternions of poses {[idx[i] for i in bad[:5]]} are not unit length",
            "write the orientation as a unit quaternion (4 numbers after x, y, z)",
        )
    clouds = [folder / f"tool0_{k}.pcd" for k in idx]
    clouds = [c if c.is_file() else None for c in clouds]
    normals = face_normals(clouds, u_cam)
    order, qnotes = check_quaternion_order(p_cam, p_base, q, quaternion, normals)
    notes += qnotes
    perm = [0, 1, 2, 3] if order == "xyzw" else [1, 2, 3, 0]
    samples, n_clouds = [], sum(c is not None for c in clouds)
    for i, k in enumerate(idx):
        cloud = clouds[i]
        samples.append(
            HandEyeSample(
                T_base_flange=T_from_quat(q[i][perm] / np.linalg.norm(q[i]), p_base[i]),
                p_cam=p_cam[i],
                cloud=None if cloud is None else str(cloud),
                meta={"index": i, "id": k, "cloud_units": u_cam, "quaternion_order": order},
            )
        )
    extra = sorted(p.name for p in folder.glob("tool0_*.pcd") if p.stem[len("tool0_") :] not in set(idx))
    notes.append(f"{n_clouds} of {len(idx)} poses have a tool0_<index>.pcd scan")
    if extra:
        notes.append(f"{len(extra)} tool0_*.pcd without a data.txt entry ignored (e.g. {extra[0]})")
    return SampleSet("eye-on-base", samples, folder, notes)


_IMAGE_EXT = (".png", ".bmp", ".jpg", ".jpeg", ".tif", ".tiff")


def is_rwhe_folder(path: Path) -> bool:
    return (path / "RobotPosesVec.txt").is_file()


def _square_size(path: Path) -> float | None:
    """The square of ``squaresize.txt`` in metres ("20mm", "0.02m", "0.02" = m), None when absent."""
    if not path.is_file():
        return None
    raw = path.read_text(encoding="utf-8", errors="replace").strip().lower().replace(" ", "")
    m = re.fullmatch(rf"({_NUM})(mm|m)?", raw)
    if not m:
        raise DataError(f"{path}: square size {raw[:20]!r} is not a length", "write e.g. 20mm")
    v = float(m.group(1))
    return v * 1e-3 if m.group(2) == "mm" or (m.group(2) is None and v > 1) else v


def read_rwhe_folder(folder: str | Path, units: str | None = None) -> SampleSet:
    """The ``rwhe`` layout (module docstring): eye-in-hand samples with ``T_base_flange`` and the photo,
    named by the photo; the board square from ``squaresize.txt`` in ``SampleSet.board``."""
    folder = Path(folder)
    f = folder / "RobotPosesVec.txt"
    try:
        rows = np.loadtxt(f, ndmin=2)
    except ValueError as e:
        raise DataError(
            f"{f}: not a table of numbers ({str(e)[:80]})", "16 numbers a line (4x4 row-major)"
        ) from None
    if rows.shape[1] != 16 or not np.all(np.isfinite(rows)):
        raise DataError(
            f"{f}: {rows.shape[1]} numbers a line", "write each pose as 16 numbers (4x4 row-major)"
        )
    T = rows.reshape(-1, 4, 4)
    u = units or guess_length_units(T[:, :3, 3], "the robot positions")
    T[:, :3, 3] *= UNIT_SCALE[u]
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_EXT)
    if len(images) != len(T):
        raise DataError(
            f"{folder}: {len(images)} photos for {len(T)} robot poses",
            "keep one photo per line of RobotPosesVec.txt (sorted by name)",
        )
    samples = [
        HandEyeSample(T_base_flange=T[i], image=str(img), meta={"index": i, "id": img.stem})
        for i, img in enumerate(images)
    ]
    square = _square_size(folder / "squaresize.txt")
    notes = [f"rwhe layout: {len(T)} photos with robot poses (m from {u}); camera on the robot (eye-in-hand)"]
    if square:
        notes.append(f"board square {square * 1e3:g} mm (squaresize.txt)")
    return SampleSet("eye-in-hand", samples, folder, notes, board={"square": square} if square else None)
