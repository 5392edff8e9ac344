"""Flange hand-eye on the real ancorasir data (Franka + PhoXi, UR10e + Azure Kinect).

    .venv/bin/python benchmarks/handeye_real.py [--shuffles 50]

(1) full pipeline from the raw Franka PhoXi scans (segmentation + RANSAC circle + eqs. 9-12) next
to the authors' stored p_cam and calib_result.json; (2) the 48-pair Franka set: all-data SVD, the
robust fit, Algorithm 1 over shuffled orders (as §3.2.1: 50 shuffles); (3) the Kinect set with the
TCP assumed vs the feature offset estimated. Prints markdown tables.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from weldcell.plugins.handeye.calibrate import DEFAULTS, calibrate, measure_flange_centre
from weldcell.plugins.handeye.result import HandEyeSample
from weldcell.plugins.handeye.samples_io import (
    read_ancorasir_kinect,
    read_ancorasir_point_pairs,
    read_ancorasir_sample,
)
from weldcell.sdk.geometry import T_to_rpy, invert, pose_error, transform_points

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "flange-handeye-ancorasir"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--shuffles", type=int, default=50)
    a = ap.parse_args()
    t0 = time.time()
    folder = DATA / "calib_toolbox/data/2019-06-14-sample"
    ss = read_ancorasir_sample(folder)
    stored = np.array([s.p_cam for s in ss.samples])
    print("## Franka + PhoXi raw scans (2019-06-14-sample, 6 poses)\n")
    print("| scan | points | radius found (mm) | circle support | ‖p_cam − stored‖ (mm) | time (s) |")
    print("|---|---|---|---|---|---|")
    found = []
    for s, p0 in zip(ss.samples, stored, strict=True):
        t = time.time()
        c, rep = measure_flange_centre(s.cloud, {**DEFAULTS, "cloud_units": "mm"})
        found.append(c)
        print(
            f"| {Path(s.cloud).name} | {rep['segment']['n_raw']} | {rep['radius'] * 1e3:.2f} | {rep['support']} | "  # noqa: E501
            f"{np.linalg.norm(c - p0) * 1e3:.3f} | {time.time() - t:.2f} |"
        )
    H = np.array(json.loads((folder / "calib_result.json").read_text())["H"]).reshape(4, 4)
    H[:3, 3] *= 1e-3
    p_base = np.array([s.p_base for s in ss.samples])
    for s in ss.samples:
        s.p_cam = None
    r = calibrate(ss, method="flange-svd", allow_coplanar=True, bootstrap=0)
    rs = calibrate(
        [HandEyeSample(p_cam=c, p_base=b) for c, b in zip(stored, p_base, strict=True)],
        method="flange-svd",
        allow_coplanar=True,
        bootstrap=0,
    )
    res_H = np.linalg.norm(transform_points(H, stored) - p_base, axis=1)
    moved = np.linalg.norm(transform_points(invert(H) @ r.T, stored) - stored, axis=1)
    dt, dr = pose_error(r.T, H)
    print("\n| T_base_camera from | residuals on the 6 pairs (mm) | rms (mm) |")
    print("|---|---|---|")
    print(
        f"| calib_result.json (authors) | {', '.join(f'{x * 1e3:.2f}' for x in res_H)} | "
        f"{np.sqrt(np.mean(res_H**2)) * 1e3:.3f} |"
    )
    print(
        f"| our SVD on the stored p_cam | {', '.join(f'{x * 1e3:.2f}' for x in rs.residuals)} | "
        f"{rs.metrics['rms_inliers_m'] * 1e3:.3f} |"
    )
    print(
        f"| our full pipeline from raw scans | {', '.join(f'{x * 1e3:.2f}' for x in r.residuals)} | "
        f"{r.metrics['rms_inliers_m'] * 1e3:.3f} |"
    )
    print(
        f"\nfull pipeline vs calib_result.json: Δt at the base origin {dt * 1e3:.2f} mm, Δangle {np.degrees(dr):.3f}°, "  # noqa: E501
        f"displacement over the 6 flange positions {moved.min() * 1e3:.2f}-{moved.max() * 1e3:.2f} mm "
        "(the 6 poses are coplanar: 4 of them on one line)\n"
    )

    pp = read_ancorasir_point_pairs(DATA / "paper_dda5a35/data/franka")
    Ha = np.load(DATA / "paper_dda5a35/data/franka/H.npy")
    Ha[:3, 3] *= 1e-3
    c = np.array([s.p_cam for s in pp.samples])
    b = np.array([s.p_base for s in pp.samples])
    print("## Franka 48 point pairs (paper_dda5a35)\n")
    print(
        "| method | inliers | rms inliers (mm) | max inlier (mm) | outliers (index: residual mm) | vs authors' H.npy: Δt (mm), Δ° |"  # noqa: E501
    )
    print("|---|---|---|---|---|---|")
    for m, kw in (("flange-svd", {}), ("flange", {}), ("flange", {"inlier_threshold": 0.001})):
        rr = calibrate(pp, method=m, bootstrap=0, **kw)
        out = ", ".join(f"{i}: {rr.residuals[i] * 1e3:.1f}" for i in rr.outliers)
        d1, d2 = pose_error(rr.T, Ha)
        lab = m + (" (1 mm threshold)" if kw else "")
        print(
            f"| {lab} | {rr.metrics['n_inliers']}/48 | {rr.metrics['rms_inliers_m'] * 1e3:.3f} | "
            f"{rr.metrics['max_inlier_m'] * 1e3:.3f} | {out or '-'} | {d1 * 1e3:.2f}, {np.degrees(d2):.3f} |"
        )
    ref = calibrate(pp, method="flange", bootstrap=200)
    bs = ref.metrics["bootstrap"]
    print(
        f"\nrobust fit bootstrap (200): std t = {', '.join(f'{x * 1e3:.3f}' for x in bs['t_std'])} mm, "
        f"rot {np.degrees(bs['rot_std']):.3f}°"
    )
    rng = np.random.default_rng(0)
    fin = []
    for _ in range(a.shuffles):
        order = rng.permutation(48)
        rr = calibrate([pp.samples[i] for i in order], method="flange-iterative", bootstrap=0)
        e = invert(rr.T) @ ref.T  # error against the robust all-inlier fit
        fin.append(np.r_[e[:3, 3], T_to_rpy(e)])
    fin = np.array(fin)
    print(f"\nAlgorithm 1 (consensus verifier), {a.shuffles} shuffled orders, error vs the robust fit:")
    print("| | δx | δy | δz (mm) | δroll | δpitch | δyaw (°) |\n|---|---|---|---|---|---|---|")
    for lab, f in (("mean", np.mean), ("std", np.std)):
        v = f(fin, axis=0)
        print(
            f"| {lab} | {' | '.join(f'{x * 1e3:.3f}' for x in v[:3])} | "
            f"{' | '.join(f'{np.degrees(x):.3f}' for x in v[3:])} |"
        )
    res_pool = np.linalg.norm(c @ rr.T[:3, :3].T + rr.T[:3, 3] - b, axis=1)
    print(
        f"\nlast shuffle: median residual of all 48 under the pool's H: {np.median(res_pool) * 1e3:.3f} mm\n"
    )

    k = read_ancorasir_kinect(DATA / "paper_dda5a35/Kinect_Result")
    print("## UR10e + Azure Kinect (49 pairs, 90 mm wrist circle)\n")
    print("| method | feature | inliers | mean all (mm) | rms inliers (mm) | feature offset in flange (mm) |")
    print("|---|---|---|---|---|---|")
    for m, f in (
        ("flange-svd", "tcp"),
        ("flange", "tcp"),
        ("flange-svd", "estimate"),
        ("flange", "estimate"),
    ):
        rr = calibrate(k, method=m, feature=f, bootstrap=0)
        off = rr.extra.get("feature_flange")
        print(
            f"| {m} | {f} | {rr.metrics['n_inliers']}/49 | {rr.metrics['mean_all_m'] * 1e3:.3f} | "
            f"{rr.metrics['rms_inliers_m'] * 1e3:.3f} | {'-' if off is None else ', '.join(f'{x * 1e3:.1f}' for x in off)} |"  # noqa: E501
        )
    print(f"\n({time.time() - t0:.1f} s)")


if __name__ == "__main__":
    main()
