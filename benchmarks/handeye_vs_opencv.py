"""Flange method vs the target-based AX=XB / AX=YB solvers on the same simulated cell and noise.

    .venv/bin/python benchmarks/handeye_vs_opencv.py [--realizations 20]

Cell of §3.1 (eq. 19 camera, 30 poses in the 0.3 x 0.3 x 0.2 m box, orientations within 0.3 rad).
Eq. 19's rotation is exactly 180° (about (1, -1, 0)), Tsai's singularity: Tsai is refused there
(DataError), so it is also run on the text's rpy [3.1415, 0, -1.57] camera (0.005° from 180°).
Flange methods see the flange centre with N(0, σ) noise; target-based methods see a 5 x 5 corner,
80 mm board on the flange whose every corner carries the same N(0, σ) noise (pose fitted to the
corners). Solvers: cv2.calibrateHandEye / calibrateRobotWorldHandEye when the installed OpenCV has
them (OpenCV 4.x), else this package's numpy implementations of the same methods (``--backend numpy``
forces them; the backend is printed).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from weldcell.plugins.handeye.calibrate import calibrate
from weldcell.plugins.handeye.classical import HAND_EYE_METHODS, solve_hand_eye, solve_robot_world
from weldcell.plugins.handeye.result import HandEyeSample
from weldcell.plugins.handeye.simulation import simulate_cell
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy, pose_error

METHODS = [
    "flange-svd",
    "flange",
    "flange-iterative",
    "tsai",
    "tsai (rpy camera)",
    "park",
    "horaud",
    "andreff",
    "andreff (t re-solved)",
    "daniilidis",
    "daniilidis (t re-solved)",
    "shah",
    "li",
    "li (t re-solved)",
]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--realizations", type=int, default=20)
    ap.add_argument("--poses", type=int, default=30)
    ap.add_argument("--backend", choices=["auto", "opencv", "numpy"], default="auto")
    a = ap.parse_args()
    t0 = time.time()
    sigmas = [0.2e-3, 1e-3, 2e-3, 5e-3]
    T_ft = T_from_rpy([0, 0, 0.2], [0, 0, 0.005])
    T_rpy = T_from_rpy([3.1415, 0.0, -1.57], [0.6, -0.0125, 1.0])
    res = {m: {s: [] for s in sigmas} for m in METHODS}
    backend = "?"
    for s in sigmas:
        for k in range(a.realizations):
            for rpy_cam in (False, True):
                rng = np.random.default_rng(k)
                cell = simulate_cell(n_poses=a.poses, rng=rng, T_base_camera=T_rpy if rpy_cam else None)
                c = cell.noisy_p_cam(s, rng)
                C = cell.board_poses(s, rng, T_ft)
                smp = [
                    HandEyeSample(T_base_flange=g, p_cam=p, T_cam_target=t)
                    for g, p, t in zip(cell.T_base_flange, c, C, strict=True)
                ]
                for m in [x for x in METHODS if ("rpy" in x) == rpy_cam]:
                    if "re-solved" in m:  # not exposed by calibrate(): the solver option directly
                        solve = solve_hand_eye if m.split()[0] in HAND_EYE_METHODS else solve_robot_world
                        X, _ = solve(cell.T_base_flange, C, "eye-on-base", m.split()[0], a.backend, True)
                        res[m][s].append(pose_error(X, cell.T_base_camera))
                        continue
                    try:
                        r = calibrate(smp, "eye-on-base", method=m.split()[0], bootstrap=0, backend=a.backend)
                    except DataError:
                        res[m][s].append((np.nan, np.nan))
                        continue
                    backend = r.metrics.get("backend", backend)
                    res[m][s].append(pose_error(r.T, cell.T_base_camera))
    print(
        f"## Eye-on-base, {a.poses} poses, {a.realizations} realizations; target solvers backend: {backend}\n"
    )
    print("| method | " + " | ".join(f"σ={s * 1e3:g} mm: ‖δt‖ mm / δθ °" for s in sigmas) + " |")
    print("|---|" + "---|" * len(sigmas))
    for m in METHODS:
        cells = []
        for s in sigmas:
            e = np.array(res[m][s])
            if np.isnan(e).all():
                cells.append("refused (180°)")
                continue
            cells.append(
                f"{np.nanmean(e[:, 0]) * 1e3:.2f} ± {np.nanstd(e[:, 0]) * 1e3:.2f} / "
                f"{np.degrees(np.nanmean(e[:, 1])):.3f}"
            )
        print(f"| {m} | " + " | ".join(cells) + " |")
    print(f"\n({time.time() - t0:.1f} s)")


if __name__ == "__main__":
    main()
