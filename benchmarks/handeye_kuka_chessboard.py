"""Board photos from the command line, on a real public chessboard hand-eye set: KUKA ``kuka_1`` of
Ali et al., "Methods for Simultaneous Robot-World-Hand-Eye Calibration: A Comparative Study" (Sensors
2019), github.com/ihtishamaliktk/RWHE-Calib ``Datasets/kuka_1`` (30 photos 1928x1208, KUKA flange poses,
28x17 inner-corner chessboard of 20 mm squares, camera on the robot). The repository carries no licence
file (its README offers the data as open access, to be cited): the data are used locally only, never
copied into this tree.

What runs: the same path as ``weldcell calibrate hand-eye DIR --board chessboard:28x17
--calibrate-intrinsics`` (rwhe layout reader, chessboard detection, Zhang intrinsics from the same
photos, solvePnP), then every AX=XB / AX=YB solver of weldcell (its own numpy implementations) and
OpenCV's ``cv2.calibrateHandEye`` (5 methods) and ``cv2.calibrateRobotWorldHandEye`` (2 methods) on the
same board poses. The set has no reference transform (only the synthetic CS_* sets do), so each answer
is compared with OpenCV's Park and judged by its consistency: how far the chessboard's position in the
base (``T_base_flange X T_cam_board``, constant in truth) scatters over the 30 poses.

    .venv/bin/python benchmarks/handeye_kuka_chessboard.py [KUKA_1_DIR]

KUKA_1_DIR defaults to $WELDCELL_RWHE_KUKA1, else it is extracted from a local mirror of the repository
(``fetch github:ihtishamaliktk/RWHE-Calib``) into a temporary folder.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

MIRROR = Path("/work/.mirror/ihtishamaliktk+RWHE-Calib/repo")


def dataset() -> Path:
    if len(sys.argv) > 1:
        return Path(sys.argv[1])
    if os.environ.get("WELDCELL_RWHE_KUKA1"):
        return Path(os.environ["WELDCELL_RWHE_KUKA1"])
    if not MIRROR.is_dir():
        sys.exit("kuka_1 not found: give its folder, set WELDCELL_RWHE_KUKA1, or fetch the RWHE-Calib mirror")
    out = Path(tempfile.mkdtemp(prefix="kuka_1-"))
    names = subprocess.run(
        ["git", "-C", str(MIRROR), "ls-tree", "--name-only", "HEAD", "Datasets/kuka_1/"],
        capture_output=True, text=True, check=True,
    ).stdout.split()  # fmt: skip
    for n in names:
        blob = subprocess.run(
            ["git", "-C", str(MIRROR), "show", f"HEAD:{n}"], capture_output=True, check=True
        )
        (out / Path(n).name).write_bytes(blob.stdout)
    return out


def spread_mm(G: np.ndarray, X: np.ndarray, C: np.ndarray) -> float:
    """RMS scatter (mm) of the board origin in the base, T_base_flange X T_cam_board, over the poses."""
    p = np.einsum("nij,jk,nkl->nil", G, X, C)[:, :3, 3]
    return float(np.sqrt(np.mean(np.sum((p - p.mean(0)) ** 2, axis=1))) * 1e3)


def main() -> None:
    import cv2
    from weldcell.plugins.handeye.board import BoardSpec, board_pose, calibrate_intrinsics
    from weldcell.plugins.handeye.calibrate import calibrate
    from weldcell.plugins.handeye.layouts import read_rwhe_folder
    from weldcell.plugins.handeye.result import HandEyeSample
    from weldcell.sdk.geometry import pose_error

    folder = dataset()
    t0 = time.perf_counter()
    ss = read_rwhe_folder(folder)
    spec = BoardSpec(kind="chessboard", squares_x=28, squares_y=17, square=ss.board["square"])
    intr = calibrate_intrinsics([s.image for s in ss.samples], spec)
    poses = [board_pose(s.image, spec, intr.K, intr.dist) for s in ss.samples]
    t_detect = time.perf_counter() - t0
    G = np.array([s.T_base_flange for s in ss.samples])
    C = np.array([p.T_cam_board for p in poses])
    worst = max(p.reprojection_rms for p in poses)
    print(f"kuka_1: {len(G)} photos, intrinsics RMS {intr.rms:.3f} px, board pose RMS max {worst:.3f} px, "
          f"detection + intrinsics {t_detect:.1f} s")  # fmt: skip
    samples = [HandEyeSample(T_base_flange=g, T_cam_target=c) for g, c in zip(G, C, strict=True)]

    rows = {}
    flags = {
        "tsai": "TSAI",
        "park": "PARK",
        "horaud": "HORAUD",
        "andreff": "ANDREFF",
        "daniilidis": "DANIILIDIS",
    }
    for m, f in flags.items():
        R, t = cv2.calibrateHandEye(G[:, :3, :3], G[:, :3, 3], C[:, :3, :3], C[:, :3, 3],
                                    method=getattr(cv2, f"CALIB_HAND_EYE_{f}"))  # fmt: skip
        X = np.eye(4)
        X[:3, :3], X[:3, 3] = R, t.ravel()
        rows[f"opencv {m}"] = X
    Gi = np.linalg.inv(G)  # OpenCV's robot-world: base->gripper and world(board)->camera
    for m in ("shah", "li"):
        R_bw, t_bw, R_gc, t_gc = cv2.calibrateRobotWorldHandEye(
            C[:, :3, :3], C[:, :3, 3], Gi[:, :3, :3], Gi[:, :3, 3],
            method=getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{m.upper()}"),
        )  # fmt: skip
        Z = np.eye(4)  # T_gripper_camera = inv(gripper->camera of OpenCV's naming: cam in gripper)
        Z[:3, :3], Z[:3, 3] = R_gc, t_gc.ravel()
        rows[f"opencv {m}"] = np.linalg.inv(Z)
    for m in (*flags, "shah", "li"):
        r = calibrate(samples, "eye-in-hand", method=m, backend="numpy", bootstrap=0)
        rows[f"weldcell {m} ({r.metrics['backend']})"] = r.T
    ref = rows["opencv park"]
    print(f"\n{'solver':<28}{'t_flange_camera [mm]':>32}{'vs OpenCV Park':>22}{'board scatter':>16}")
    for k, X in rows.items():
        if k.startswith("_"):
            continue
        dt, dr = pose_error(X, ref)
        t = X[:3, 3] * 1e3
        print(f"{k:<28}[{t[0]:8.2f} {t[1]:8.2f} {t[2]:8.2f}]  {dt * 1e3:7.2f} mm {np.degrees(dr):6.3f} deg"
              f"{spread_mm(G, X, C):10.2f} mm")  # fmt: skip


if __name__ == "__main__":
    main()
