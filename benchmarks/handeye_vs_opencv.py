"""Flange method vs the target-based AX=XB / AX=YB solvers on the same simulated cell and noise.

    /work/venv/bin/python benchmarks/handeye_vs_opencv.py [--realizations 20]

Cell of §3.1 (eq. 19 camera, 30 poses in the 0.3 x 0.3 x 0.2 m box, orientations within 0.3 rad).
Flange methods see the flange centre with N(0, σ) noise; target-based methods see a 5 x 5 corner,
80 mm board on the flange whose every corner carries the same N(0, σ) noise (pose fitted to the
corners). Solvers: cv2.calibrateHandEye / calibrateRobotWorldHandEye when the installed OpenCV has
them, else this package's numpy implementations of the same methods (the backend is printed).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from weldcell.plugins.handeye.calibrate import calibrate
from weldcell.plugins.handeye.result import HandEyeSample
from weldcell.plugins.handeye.simulation import simulate_cell
from weldcell.sdk.geometry import T_from_rpy, pose_error

METHODS = [
    "flange-svd",
    "flange",
    "flange-iterative",
    "tsai",
    "park",
    "horaud",
    "andreff",
    "daniilidis",
    "shah",
    "li",
]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--realizations", type=int, default=20)
    ap.add_argument("--poses", type=int, default=30)
    a = ap.parse_args()
    t0 = time.time()
    sigmas = [0.2e-3, 1e-3, 2e-3, 5e-3]
    T_ft = T_from_rpy([0, 0, 0.2], [0, 0, 0.005])
    res = {m: {s: [] for s in sigmas} for m in METHODS}
    backend = "?"
    for s in sigmas:
        for k in range(a.realizations):
            rng = np.random.default_rng(k)
            cell = simulate_cell(n_poses=a.poses, rng=rng)
            c = cell.noisy_p_cam(s, rng)
            C = cell.board_poses(s, rng, T_ft)
            smp = [
                HandEyeSample(T_base_flange=g, p_cam=p, T_cam_target=t)
                for g, p, t in zip(cell.T_base_flange, c, C, strict=True)
            ]
            for m in METHODS:
                r = calibrate(smp, "eye-on-base", method=m, bootstrap=0)
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
            cells.append(
                f"{e[:, 0].mean() * 1e3:.2f} ± {e[:, 0].std() * 1e3:.2f} / {np.degrees(e[:, 1]).mean():.3f}"
            )
        print(f"| {m} | " + " | ".join(cells) + " |")
    print(f"\n({time.time() - t0:.1f} s)")


if __name__ == "__main__":
    main()
