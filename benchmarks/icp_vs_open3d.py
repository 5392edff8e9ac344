"""Linear point-to-plane ICP (weldcell.plugins.scan_plan.registration) vs Open3D's point-to-plane ICP.

Both get the same source, target, target normals (PCA, k = 20), initial guess, correspondence distance
and convergence thresholds (relative fitness and RMSE 1e-6, at most 50 iterations). Times are the median
of ``--repeat`` runs of the registration call alone (each builds its own KD-tree), ours and Open3D's
interleaved so that load from other processes hits both alike. Prints a markdown table.

    .venv/bin/python benchmarks/icp_vs_open3d.py [--repeat 7]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import open3d as o3d
from weldcell.plugins.scan_plan.denoise import pca_normals, voxel_downsample
from weldcell.plugins.scan_plan.nearest import backend_name
from weldcell.plugins.scan_plan.registration import IcpOptions, linear_icp
from weldcell.sdk.cloud import read_cloud
from weldcell.sdk.geometry import T_from_rotvec, invert, pose_error, transform_points

ROOT = Path(__file__).resolve().parents[1]
LIDAR = ROOT / ".." / "shared" / "data" / "small-gicp-lidar-pair" / "data"
sys.path.insert(0, str(ROOT / "tests"))
from scan_plan.synthetic import corner_workpiece  # noqa: E402


def lidar_case(voxel: float, d_max: float):
    src = read_cloud(LIDAR / "source.ply", check_scale=False).points
    tgt = read_cloud(LIDAR / "target.ply", check_scale=False).points
    s, t = voxel_downsample(src, voxel_size=voxel), voxel_downsample(tgt, voxel_size=voxel)
    return f"LiDAR pair, voxel {voxel} m", s, t, np.loadtxt(LIDAR / "T_target_source.txt"), d_max


def workpiece_case(spacing: float):
    target, _ = corner_workpiece(spacing=spacing, noise=0.0002, seed=1)
    surf, _ = corner_workpiece(spacing=spacing, noise=0.0002, seed=2)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    T_true = T_from_rotvec(np.deg2rad(5.0) * axis, [0.012, -0.01, 0.0125])
    name = f"workpiece 5 deg / 2 cm, {spacing * 1e3:g} mm spacing"
    return name, transform_points(invert(T_true), surf), target, T_true, 0.05


def open3d_icp(s, t, n, d_max, iters):
    ps = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s))
    pt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(t))
    pt.normals = o3d.utility.Vector3dVector(n)
    crit = o3d.pipelines.registration.ICPConvergenceCriteria(1e-6, 1e-6, iters)
    est = o3d.pipelines.registration.TransformationEstimationPointToPlane()

    def run():
        return o3d.pipelines.registration.registration_icp(ps, pt, d_max, np.eye(4), est, crit)

    return run


def open3d_iterations(run) -> int:
    """Open3D does not return its iteration count: count its debug lines (C++ stdout) in one extra run."""
    sys.stdout.flush()
    saved = os.dup(1)
    with tempfile.TemporaryFile(mode="w+") as tmp:
        os.dup2(tmp.fileno(), 1)
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Debug)
        try:
            run()
        finally:
            o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Warning)
            os.dup2(saved, 1)
            os.close(saved)
        tmp.seek(0)
        return sum("ICP Iteration #" in line for line in tmp)


def median_times(fns, repeat: int) -> list[tuple[float, object]]:
    """Median wall time of each function over ``repeat`` rounds that call them in turn (after a warm-up)."""
    outs = [fn() for fn in fns]
    times: list[list[float]] = [[] for _ in fns]
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            outs[k] = fn()
            times[k].append(time.perf_counter() - t0)
    return [(float(np.median(t)), o) for t, o in zip(times, outs, strict=True)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--iterations", type=int, default=50)
    args = ap.parse_args()
    cases = [workpiece_case(0.002), workpiece_case(0.001)]
    if (LIDAR / "source.ply").is_file():
        cases = [lidar_case(0.25, 0.5), lidar_case(0.1, 1.0), *cases]
    else:
        print(f"(LiDAR pair not found at {LIDAR}; synthetic cases only)")
    print(
        "| case | points src/tgt | method | iterations | fitness (inliers/src) | eq. 20 fitness | "
        "inlier RMSE (mm) | error vs reference (mm / deg) | time (ms) | time ratio ours/Open3D |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    notes: list[str] = []
    for name, s, t, T_ref, d_max in cases:
        n = pca_normals(t, k=20)
        run = open3d_icp(s, t, n, d_max, args.iterations)
        (t_ours, r), (t_o3d, ro) = median_times(
            [
                lambda s=s, t=t, n=n, d=d_max: linear_icp(
                    s,
                    t,
                    IcpOptions(max_correspondence_distance=d, max_iterations=args.iterations, tolerance=1e-6),
                    target_normals=n,
                ),
                run,
            ],
            args.repeat,
        )
        it_o3d = open3d_iterations(run)
        e_ours, e_o3d = pose_error(r.T, T_ref), pose_error(ro.transformation, T_ref)
        pts = f"{len(s)}/{len(t)}"
        print(
            f"| {name} | {pts} | linear ICP (ours) | {r.iterations} | {r.inlier_fraction:.4f} | "
            f"{r.fitness:.4f} | "
            f"{r.inlier_rmse * 1e3:.2f} | {e_ours[0] * 1e3:.2f} / {np.rad2deg(e_ours[1]):.3f} | "
            f"{t_ours * 1e3:.1f} | {t_ours / t_o3d:.2f} |"
        )
        print(
            f"| {name} | {pts} | Open3D point-to-plane | {it_o3d} | {ro.fitness:.4f} | "
            f"{ro.fitness * len(s) / len(t):.4f} | {ro.inlier_rmse * 1e3:.2f} | "
            f"{e_o3d[0] * 1e3:.2f} / {np.rad2deg(e_o3d[1]):.3f} | {t_o3d * 1e3:.1f} | 1.00 |"
        )
        dT = float(np.abs(r.T - ro.transformation).max())
        notes.append(f"{name}: largest difference of the two transforms {dT:.1e}")
    print(f"\nOur nearest-neighbour back-end: {backend_name()}; Open3D {o3d.__version__}.")
    print("\n".join(notes))


if __name__ == "__main__":
    main()
