"""Seam stage on the sim's other joint types (lap, outside corner, T-fillet) scanned like Table I.

Run:  .venv/bin/python benchmarks/seam_joints.py [--seeds 1] [--views 8] [--low-views 4] [--decimation 1]

For each workpiece and seed a RealSense D415 (sim, Intel's stereo noise model) captures the Table I view
set (``scan_plan_table1.view_poses``: a ring at 50 deg elevation, a lower ring at 20 deg, one view from
above, 0.5 m from the first seam's centre). The views are merged with their *true* poses (transform +
1.5 mm voxel grid: the reconstruction is not what is measured here), then the job's stages run with
their defaults (bilateral filter, seam extraction, torch frames) and ``evaluate()`` scores the seams
against all of the workpiece's true seams: number of seams, F1 (eq. 21), translation / rotation RMSE
(eq. 22) and the RMS approach error. Prints a markdown table; nothing is asserted.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from scan_plan_table1 import mean_worst, view_poses
from weldcell.hal.sim.camera_model import RaycastCamera
from weldcell.hal.sim.workpieces import make_workpiece
from weldcell.plugins.scan_plan.denoise import voxel_downsample
from weldcell.plugins.scan_plan.job import evaluate
from weldcell.plugins.scan_plan.stages import (
    BilateralDenoiser,
    BilateralSettings,
    EdgeSeamExtractor,
    EdgeSeamSettings,
    TorchPathPlanner,
    TorchPathSettings,
)
from weldcell.sdk.cloud import PointCloud

PIECES = ("lap", "corner", "fillet-t")


def scan_cloud(kind: str, seed: int, views: int, low_views: int, decimation: int) -> tuple[PointCloud, list]:
    """The merged, voxelised cloud of the Table I view set around ``kind`` (base frame, meta viewpoints)."""
    wp = make_workpiece(kind)
    target = wp.seams_in_world()[0].points.mean(axis=0)
    cam = RaycastCamera("realsense-d415", [wp], decimation=decimation)
    rng = np.random.default_rng(seed)
    parts, eyes = [], []
    for T_wc in view_poses(target, views, n_low=low_views):
        pts = cam.render(T_wc, rng=rng).to_points()
        parts.append(pts @ T_wc[:3, :3].T + T_wc[:3, 3])
        eyes.append(T_wc[:3, 3].tolist())
    P = voxel_downsample(np.vstack(parts), voxel_size=0.0015)
    return PointCloud(P, frame="base", meta={"viewpoints": eyes}), wp.seams_in_world()


def run_case(kind: str, seed: int, views: int, low_views: int, decimation: int) -> dict:
    cloud, truth = scan_cloud(kind, seed, views, low_views, decimation)
    t0 = time.perf_counter()
    clean = BilateralDenoiser(BilateralSettings())(cloud)
    ex = EdgeSeamExtractor(EdgeSeamSettings())(clean)
    path = TorchPathPlanner(TorchPathSettings(standoff=0.0, travel_angle=0.0))(ex.seams)
    dt = time.perf_counter() - t0
    m = evaluate(path, [(s.id, s) for s in truth], 0.0)
    per = m.get("per_seam", [])
    approach = np.sqrt(np.mean([p["approach_rad"] ** 2 for p in per])) if per else float("nan")
    return {
        "seams": len(ex.seams),
        "true": len(truth),
        "f1": m["f1"]["f1"] if "f1" in m else 0.0,
        "t_mm": m.get("translation_rmse_mm", float("nan")),
        "r_deg": m.get("rotation_rmse_deg", float("nan")),
        "a_deg": float(np.degrees(approach)),
        "length": sum(s.length for s in ex.seams) / sum(s.length for s in truth),
        "points": len(cloud),
        "t_plan": dt,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--low-views", type=int, default=4)
    ap.add_argument("--decimation", type=int, default=1, help="camera image decimation (1: full 1280x720)")
    ap.add_argument("--pieces", nargs="*", default=list(PIECES))
    args = ap.parse_args()
    rows = []
    for kind in args.pieces:
        res = [run_case(kind, s, args.views, args.low_views, args.decimation) for s in range(args.seeds)]
        for i, r in enumerate(res):
            print(
                f"  {kind} seed {i}: {r['seams']}/{r['true']} seam(s), F1 {r['f1']:.3f}, {r['t_mm']:.2f} mm, "
                f"{r['r_deg']:.2f} deg (approach {r['a_deg']:.2f}), length {r['length']:.3f}, "
                f"{r['points']} pts, stages {r['t_plan']:.2f} s",
                flush=True,
            )
        rows.append((kind, res))
    print()
    print(
        f"Seam joints (sim D415, {args.views}+{args.low_views}+1 views, decimation {args.decimation}, "
        f"true poses, {args.seeds} seed(s); mean, worst seed in brackets)"
    )
    print()
    print(
        "| workpiece | seams found / true | F1 (eq. 21) | RMSE_p mm | RMSE_theta deg | approach deg "
        "| length ratio |"
    )
    print("|---|---|---|---|---|---|---|")
    for kind, res in rows:

        def stat(key: str, res: list[dict] = res) -> str:
            return mean_worst(r[key] for r in res)

        print(
            f"| {kind} | {statistics.mean(r['seams'] for r in res):.1f} / {res[0]['true']} | "
            f"{statistics.mean(r['f1'] for r in res):.3f} | {stat('t_mm')} | {stat('r_deg')} | "
            f"{stat('a_deg')} | {statistics.mean(r['length'] for r in res):.2f} |"
        )


if __name__ == "__main__":
    main()
