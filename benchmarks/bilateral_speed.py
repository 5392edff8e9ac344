"""Speed of the point-cloud bilateral filter (eqs. 9-10) and voxel down-sampling on a large noisy scan.

.venv/bin/python benchmarks/bilateral_speed.py [--points 500000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from weldcell.plugins.scan_plan.denoise import bilateral_filter, mean_spacing, voxel_downsample


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=500_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n = args.points
    P = np.c_[rng.uniform(0, 0.5, (n, 2)), rng.normal(0, 0.0005, n)]  # 0.5 m plate, 0.5 mm noise
    t0 = time.perf_counter()
    sp = mean_spacing(P)
    t_sp = time.perf_counter() - t0
    radius = 4 * sp
    t0 = time.perf_counter()
    Q, _ = bilateral_filter(P, radius)
    t_bil = time.perf_counter() - t0
    t0 = time.perf_counter()
    D = voxel_downsample(Q, factor=2.0, spacing=sp)
    t_vox = time.perf_counter() - t0
    rms = lambda z: float(np.sqrt(np.mean(z**2)))  # noqa: E731
    print(
        "| points | mean spacing (mm) | radius (mm) | noise RMS before / after (mm) | mean_spacing (s) "
        "| bilateral_filter (s) | voxel_downsample x2 (s) | points after |"
    )
    print("|---|---|---|---|---|---|---|---|")
    print(
        f"| {n} | {sp * 1e3:.3f} | {radius * 1e3:.2f} | "
        f"{rms(P[:, 2]) * 1e3:.3f} / {rms(Q[:, 2]) * 1e3:.3f} | "
        f"{t_sp:.2f} | {t_bil:.2f} | {t_vox:.2f} | {len(D)} |"
    )


if __name__ == "__main__":
    main()
