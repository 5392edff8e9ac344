"""Threshold sweep of the edge-intensity seam detector (paper 000, Figs. 12-13).

For synthetic workpieces with known seams (cylinder on plate = the paper's cylinder piece; T fillet;
60 deg V-groove) sampled with Gaussian noise, the edge points of eq. 16 are scored with the
rasterised F1 of eq. 21 (``metrics.seam_f1``) for a range of thresholds t, before and after the
bilateral filter (eqs. 9-10); the final seam polylines are scored too, with their accuracy against
the true line and the run time of ``extract_seams``.

    .venv/bin/python benchmarks/seam_threshold_sweep.py [--noise 0.0004] [--seeds 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from scan_plan import test_seams as wp  # noqa: E402  (synthetic workpieces)
from weldcell.plugins.scan_plan.denoise import bilateral_filter  # noqa: E402
from weldcell.plugins.scan_plan.metrics import seam_f1  # noqa: E402
from weldcell.plugins.scan_plan.seams import extract_seams  # noqa: E402

THRESHOLDS = [27.5, 30, 35, 40, 45, 50, 55, 60, 70, 80, 100, 130, 170, 250]


def workpieces(seed: int, n: int):
    """(name, dense noisy points, dense normals, ground-truth seam points)."""
    P, N, ring = cylinder_on_plate_dense(seed, n)
    yield "cylinder", P, N, ring
    Pt, Nt, roots = t_fillet_dense(seed, n)
    yield "t-fillet", Pt, Nt, roots
    Pv, Nv, gv = v_groove_dense(seed, n)
    yield "v-groove", Pv, Nv, gv


def _line(seg, step=2e-4):
    a, b = seg
    k = int(np.linalg.norm(b - a) / step) + 1
    return a + np.linspace(0, 1, k)[:, None] * (b - a)


def _dense(mesh_fn, seed, n):
    return wp.sample_mesh(mesh_fn(), n, np.random.default_rng(seed))


def t_fillet_dense(seed, n, W=0.04, T=0.008, w=0.005, H=0.03, L=0.1):
    poly = [(-W, 0), (W, 0), (W, T), (w, T), (w, T + H), (-w, T + H), (-w, T), (-W, T)]
    P, N = _dense(lambda: wp.prism_mesh(poly, L, drop_edges=(0,)), seed, n)
    gt = np.vstack([_line(np.array([[s * w, 0, T], [s * w, L, T]])) for s in (-1, 1)])
    return P, N, gt


def v_groove_dense(seed, n, W=0.04, T=0.01, f=0.002, L=0.1):
    g = (T - f) * np.tan(np.deg2rad(30))
    poly = [(-W, 0), (W, 0), (W, T), (g, T), (0, f), (-g, T), (-W, T)]
    P, N = _dense(lambda: wp.prism_mesh(poly, L, drop_edges=(0,)), seed, n)
    return P, N, _line(np.array([[0, 0, f], [0, L, f]]))


def cylinder_on_plate_dense(seed, n, R=0.02, T=0.008):
    import open3d as o3d

    rng = np.random.default_rng(seed)
    W, H = 0.05, 0.03
    plate = wp.prism_mesh([(-W, 0), (W, 0), (W, T), (-W, T)], 2 * W, drop_edges=(0,)).translate((0, -W, 0))
    cyl = o3d.geometry.TriangleMesh.create_cylinder(radius=R, height=H, resolution=120, split=4)
    cyl.translate((0, 0, T + H / 2))
    Pp, Np = wp.sample_mesh(plate, int(n * 0.75), rng)
    keep = ~((np.hypot(Pp[:, 0], Pp[:, 1]) < R) & (Pp[:, 2] > T - 1e-3))
    Pc, Nc = wp.sample_mesh(cyl, int(n * 0.25), rng)
    keepc = Pc[:, 2] > T + 4 * wp.NOISE
    th = np.linspace(0, 2 * np.pi, 4000)
    ring = np.column_stack([R * np.cos(th), R * np.sin(th), np.full_like(th, T)])
    return np.vstack([Pp[keep], Pc[keepc]]), np.vstack([Np[keep], Nc[keepc]]), ring


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise", type=float, default=4e-4, help="Gaussian noise sigma (m), default 0.4 mm")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--points", type=int, default=80000, help="dense samples per workpiece")
    ap.add_argument("--voxel", type=float, default=1.5e-3)
    ap.add_argument("--cell", type=float, default=2e-3, help="raster cell of eq. 21 (m)")
    args = ap.parse_args()
    wp.NOISE = args.noise
    rows: dict[tuple[str, str], list] = {}
    seam_rows = []
    for seed in range(args.seeds):
        for name, P, N, gt in workpieces(seed, args.points):
            for stage in ("raw", "bilateral"):
                Q = P
                if stage == "bilateral":
                    Q, _ = bilateral_filter(P, radius=4 * args.voxel / 1.5, iterations=1)
                Pv, Nv = wp.voxelize(Q, N, args.voxel)
                f1s = []
                for t in THRESHOLDS:
                    res = extract_seams(Pv, Nv, t=t, min_intensity=0.0)
                    edge = Pv[res.edge_mask]
                    f1s.append(seam_f1(edge, gt, cell=args.cell)["f1"] if len(edge) else 0.0)
                rows.setdefault((name, stage), []).append(f1s)
                t0 = time.perf_counter()
                res = extract_seams(Pv, Nv)
                dt = time.perf_counter() - t0
                pts = np.vstack([s.points for s in res.seams]) if res.seams else np.zeros((0, 3))
                dev = cKDTree(gt).query(pts)[0] if len(pts) else np.array([np.nan])
                sf1 = seam_f1(pts, gt, cell=args.cell, tolerance_cells=1)["f1"] if len(pts) else 0.0
                seam_rows.append(
                    (
                        name,
                        stage,
                        seed,
                        len(Pv),
                        len(res.seams),
                        sf1,
                        1e3 * np.mean(dev),
                        1e3 * np.max(dev),
                        1e3 * dt,
                    )
                )
    print(
        f"noise {args.noise * 1e3:.2f} mm, voxel {args.voxel * 1e3:.1f} mm, cell {args.cell * 1e3:.1f} mm, "
        f"{args.seeds} seeds; F1 (eq. 21) of the eq. 16 edge points (min_intensity=0) against t"
    )
    print("workpiece  stage      " + " ".join(f"{t:>6g}" for t in THRESHOLDS))
    for (name, stage), v in rows.items():
        m = np.mean(v, axis=0)
        best = THRESHOLDS[int(np.argmax(m))]
        print(f"{name:10s} {stage:10s} " + " ".join(f"{x:6.3f}" for x in m) + f"   best t={best}")
    print("\nfinal seams (default settings; F1 with 1-cell tolerance):")
    print("workpiece  stage      seed points seams F1 mean_dev_mm max_dev_mm ms")
    for r in seam_rows:
        print(f"{r[0]:10s} {r[1]:10s} {r[2]} {r[3]:6d} {r[4]:2d} {r[5]:.3f} {r[6]:.2f} {r[7]:.2f} {r[8]:.0f}")


if __name__ == "__main__":
    main()
