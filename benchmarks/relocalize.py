"""Registration and relocalization (paper 004 §II-D, §II-E, Table IV).

Part A, local registration on the same pairs and the same coarse-to-fine ladder (NDT's, from the data):
our NDT vs small-gicp GICP / VGICP vs Open3D point-to-plane ICP. Pairs: the real LiDAR pair
(../shared/data/small-gicp-lidar-pair, error against its reference transform) and simulated site/visit pairs,
each from ``--trials`` random initial guesses (1-2 m, +-10 deg off). Time includes each method's own
preprocessing (NDT: the target's cells; small-gicp: downsampling, covariances, KD-tree).

Part B, the Table IV protocol in simulation: ``--n`` relocalizations per prior combination (GNSS only,
IMU yaw only, both, neither) of a visit at a random place (up to 8 m from the site centre) and heading in a
40 x 30 m site; GNSS = true position + N(0, 1 m) per axis, stated sigma 2 m; IMU yaw = true + N(0, 3 deg),
stated sigma 5 deg. Success: status ok and error < 5 cm / 0.5 deg; wrong-ok: status ok but wrong (must be 0).
Also ``--n`` trials against a prior map of another site and with a magnetometer 90 deg off (sigma 5 deg).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/relocalize.py [--trials 5] [--n 20] [--part a|b|both]

Part B prints wall time and the process CPU time of each relocalization (on a shared, loaded machine
the CPU time is what one relocalization costs; numpy/BLAS limited to one thread).
"""

from __future__ import annotations

import argparse
import math
import time
import zlib
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.plugins.relocalize import synth
from weldcell.plugins.relocalize.local_reg import METHODS, refine
from weldcell.plugins.relocalize.relocalize import PriorMap, Priors, RelocalizeSettings, relocalize
from weldcell.sdk.cloud import read_cloud
from weldcell.sdk.registration.ndt import NDT

LIDAR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "small-gicp-lidar-pair" / "data"
SIZE = (40.0, 30.0)


def err(T_true, T):
    E = np.linalg.inv(T_true) @ T
    return float(np.linalg.norm(E[:3, 3])), math.degrees(Rotation.from_matrix(E[:3, :3]).magnitude())


def perturb(rng, T):
    d = rng.normal(size=3) * [1, 1, 0.1]
    d = d / np.linalg.norm(d) * rng.uniform(1.0, 2.0)
    return synth.pose(*d, math.radians(rng.uniform(-10, 10))) @ T


def local_table(name, target, source, T_ref, trials, rng):
    inits = [perturb(rng, T_ref) for _ in range(trials)]
    lad = NDT(target).ladder(2.0)
    print(f"\n{name}: {len(source)} -> {len(target)} points, ladder {[round(r, 2) for r in lad]} m")
    print("| method | median t err (m) | max t err (m) | median r err (deg) | ok (<5 cm, <0.5°) | time (s) |")
    print("|---|---|---|---|---|---|")
    for m in METHODS:
        te, re, ts = [], [], []
        for T0 in inits:
            t = time.perf_counter()
            T = refine(NDT(target), source, T0, lad, m)
            ts.append(time.perf_counter() - t)
            a, b = err(T_ref, T)
            te.append(a)
            re.append(b)
        ok = sum(a < 0.05 and b < 0.5 for a, b in zip(te, re, strict=True))
        print(
            f"| {m} | {np.median(te):.4f} | {np.max(te):.3f} | {np.median(re):.3f} | {ok}/{trials} "
            f"| {np.median(ts):.2f} |"
        )


def part_a(trials):
    rng = np.random.default_rng(0)
    if LIDAR.is_dir():
        src = read_cloud(LIDAR / "source.ply", check_scale=False).points
        tgt = read_cloud(LIDAR / "target.ply", check_scale=False).points
        local_table("real LiDAR pair", tgt, src, np.loadtxt(LIDAR / "T_target_source.txt"), trials, rng)
    site = synth.site_cloud(0, SIZE)
    T = synth.pose(3.0, -2.0, 0.1, 0.7)
    local_table("simulated site / visit", site, synth.visit(site, (20, 15), 9, T, seed=1), T, trials, rng)


def _trial(rng, site, combo):
    yaw = rng.uniform(-math.pi, math.pi)
    c = np.array([20.0, 15.0]) + rng.uniform(-8, 8, 2)
    T = synth.pose(*(c + rng.uniform(-3, 3, 2) - [20, 15]), rng.uniform(-0.3, 0.3), yaw)
    cur = synth.visit(site, tuple(c), 9.0, T, seed=int(rng.integers(1 << 30)))
    pr = Priors()
    if "gnss" in combo:
        pr.position, pr.position_sigma = T[:3, 3] + rng.normal(scale=1.0, size=3), 2.0
    if "imu" in combo:
        pr.yaw, pr.yaw_sigma = yaw + math.radians(rng.normal(scale=3.0)), math.radians(5.0)
    if combo == "imu90":  # magnetometer disturbed by steel: 90 deg off, stated 5 deg
        pr.yaw, pr.yaw_sigma = yaw + math.pi / 2, math.radians(5.0)
        pr.position, pr.position_sigma = T[:3, 3] + rng.normal(scale=1.0, size=3), 2.0
    return T, cur, pr


def part_b(n, method):
    site = synth.site_cloud(0, SIZE)
    other = synth.site_cloud(17, SIZE)
    s = RelocalizeSettings(method=method)
    # the prior maps are prepared once, as a robot does when it loads its prior map (NDT cells, KD-tree,
    # small-gicp covariances); that time is reported apart and not in the per-relocalization times
    t0 = time.perf_counter()
    site_pm = PriorMap(site, s.ndt).warm(s)
    print(f"\nprior map prepared once: {len(site)} points, {time.perf_counter() - t0:.2f} s")
    other_pm = PriorMap(other, s.ndt).warm(s)
    print(f"\nTable IV protocol (simulation), method {method}, {n} per row")
    print(
        "| priors | success | failed | wrong ok | wall mean ± sd (s) | CPU mean / median (s) "
        "| min overlap ok | max overlap failed |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for combo in ("gnss", "imu", "gnss+imu", "neither", "other-site gnss+imu", "imu90 + gnss"):
        rng = np.random.default_rng(zlib.crc32(combo.encode()))
        good = fail = wrong = 0
        ts, cpu, ov_ok, ov_fail, wrongs = [], [], [], [], []
        for _ in range(n):
            T, cur, pr = _trial(rng, site, combo.split()[0].replace("other-site", "gnss+imu"))
            c0 = time.process_time()
            res = relocalize(other_pm if combo.startswith("other") else site_pm, cur, pr, s)
            ts.append(res.seconds)
            cpu.append(time.process_time() - c0)
            correct = not combo.startswith("other") and all(
                np.array(err(T, res.T_prior_current)) < [0.05, 0.5]
            )
            if res.status == "ok":
                ov_ok.append(res.overlap)
                good += correct
                wrong += not correct
                if not correct:
                    e = err(T, res.T_prior_current) if not combo.startswith("other") else ("other site",)
                    wrongs.append(f"{combo}: error {e}, overlap {res.overlap:.3f}, {res.priors_used}")
            else:
                ov_fail.append(res.overlap)
                fail += 1
        print(
            f"| {combo} | {good}/{n} | {fail} | {wrong} | {np.mean(ts):.2f} ± {np.std(ts):.2f} "
            f"| {np.mean(cpu):.2f} / {np.median(cpu):.2f} "
            f"| {min(ov_ok, default=float('nan')):.3f} | {max(ov_fail, default=float('nan')):.3f} |"
        )
        for w in wrongs:
            print(f"  wrong ok: {w}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--part", choices=["a", "b", "both"], default="both")
    ap.add_argument("--method", choices=METHODS, default="gicp")
    a = ap.parse_args()
    if a.part in ("a", "both"):
        part_a(a.trials)
    if a.part in ("b", "both"):
        part_b(a.n, a.method)


if __name__ == "__main__":
    main()
