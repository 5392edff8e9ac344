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
        [--workers N] [--scheduler ADDRESS] [--rows gnss imu ...] [--out DIR] [--seed S]

Part B is one ``weldcell study`` of the trial function ``weldcell.plugins.relocalize.table4:trial``
(``priors=cycle(rows)``, statistics per row with ``by="priors"``) on Dask: each worker prepares the prior
maps once; each trial draws its visit from its own study seed. It prints wall time and the process CPU
time of each relocalization (on a shared, loaded machine the CPU time is what one relocalization costs;
numpy/BLAS limited to one thread). The same study from the command line is in docs/scale-out.md.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from math import nan
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.plugins.relocalize import synth
from weldcell.plugins.relocalize.local_reg import METHODS, refine
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


ROWS = ("gnss", "imu", "gnss+imu", "neither", "other-site", "imu90+gnss")
LABELS = {"other-site": "other-site gnss+imu", "imu90+gnss": "imu90 + gnss"}


def part_b(n, method, workers, scheduler, out, seed, rows=ROWS):
    """Table IV through ``weldcell study``: ``n`` trials per row of the trial function
    ``weldcell.plugins.relocalize.table4:trial`` (rows by ``cycle``), statistics per row (``--by``)."""
    from weldcell.sdk.scale.cluster import ClusterOptions
    from weldcell.sdk.scale.progress import TaskProgress
    from weldcell.sdk.scale.study import run_study

    opts = ClusterOptions(workers=None if scheduler else workers, scheduler=scheduler)
    vary = [f"priors=cycle({', '.join(rows)})", f"method=choice({method})"]
    t0 = time.perf_counter()
    study = run_study(
        None,
        n * len(rows),
        vary,
        Path(out),
        opts,
        seed=seed,
        progress=TaskProgress(False),
        function="weldcell.plugins.relocalize.table4:trial",
        by="priors",
    )
    print(f"\nstudy: {study['runner']}, {time.perf_counter() - t0:.0f} s wall, {out}/index.html")
    print(
        f"\nTable IV protocol (simulation), method {method}, {n} per row (weldcell study --seed {seed}); "
        "each worker prepares the prior map once, not in the times"
    )
    print(
        "| priors | success | failed | wrong ok | wall mean ± sd (s) | CPU mean / median (s) "
        "| min overlap ok | max overlap failed |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        g = study["groups"].get(row, {})
        st, c = g.get("statistics", {}), g.get("counts", {})

        def total(k, st=st):
            return round(st[k]["mean"] * st[k]["n"]) if st.get(k, {}).get("n") else 0

        wall, cpu = st.get("wall_s", {}), st.get("cpu_s", {})
        lost = c.get("trials", 0) - c.get("ok", 0)
        print(
            f"| {LABELS.get(row, row)} | {total('success')}/{c.get('trials', 0)} | {total('failed')} "
            f"| {total('wrong_ok')} | {wall.get('mean', nan):.2f} ± {wall.get('std', nan):.2f} "
            f"| {cpu.get('mean', nan):.2f} / {cpu.get('p50', nan):.2f} "
            f"| {st.get('overlap_ok', {}).get('min', nan):.3f} "
            f"| {st.get('overlap_failed', {}).get('max', nan):.3f} |"
            + (f" ({lost} trials lost)" if lost else "")
        )
    for t in study["trials"].values():
        if (t.get("figures") or {}).get("wrong_ok"):
            f = t["figures"]
            print(
                f"  wrong ok: trial {t['trial']} ({t['values']['priors']}): overlap {f.get('overlap_ok'):.3f}"
            )


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--part", choices=["a", "b", "both"], default="both")
    ap.add_argument("--method", choices=METHODS, default="gicp")
    ap.add_argument("--workers", type=int, default=None, help="part B: local Dask workers (0: in-process)")
    ap.add_argument("--scheduler", default=None, help="part B: an existing Dask scheduler address")
    ap.add_argument(
        "--out", help="part B: study folder (default: a new temporary one; a finished one resumes)"
    )
    ap.add_argument("--seed", type=int, default=0, help="part B: the study's seed")
    ap.add_argument("--rows", nargs="*", choices=ROWS, default=list(ROWS), help="part B: the rows to run")
    a = ap.parse_args()
    if a.part in ("a", "both"):
        part_a(a.trials)
    if a.part in ("b", "both"):
        out = a.out or tempfile.mkdtemp(prefix="weldcell-table4-")
        part_b(a.n, a.method, a.workers, a.scheduler, out, a.seed, tuple(a.rows))


if __name__ == "__main__":
    main()
