"""Hand-eye error found by reconstruction: ``reconstruct(anchor="hand-eye")`` vs "mean" and "first".

Run:  .venv/bin/python benchmarks/reconstruct_hand_eye.py [--seeds 3] [--seam]

The Table I scene (benchmarks/scan_plan_table1.py: RealSense D415 noise model, 8 views on a ring at
50 deg, 4 at 20 deg, one from above, 0.5 m from the seam's centre) on the cylinder-on-plate and the
Y-pipe; the views are posed through a hand-eye transform that is off by 1 mm / 0.3 deg (the Table I
"hand-eye" case: same seeds, same error), 3 mm / 1 deg (same random directions, larger) or, with
``--errors none``, not at all (Table I's "exact" case). The same captures are merged with each anchor
(voxel 1.5 mm, 5 mm correspondence distance, as Table I) and scored against the truth (the true camera
poses and the workpiece's mesh):

* ``he``: error of the hand-eye after the correction, ``T_flange_camera @ D`` vs the true mount (mm /
  deg; for "mean"/"first" the uncorrected error);
* ``view``: per-view placement error, RMS over the views of the RMS displacement of the view's points
  between the estimated and the true camera pose (mm), and the worst view;
* ``surface``: mean distance of the merged model's points to the true surface (mm);
* with ``--seam``: the job's denoise + seam + torch stages with default settings and the on-seam
  translation RMSE / seam count of Table I (mm).

Prints one line per case and a markdown table (mean over seeds, worst seed in brackets).
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import numpy as np
import open3d as o3d
from scan_plan_table1 import WORKPIECES, capture, mean_worst
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan.job import evaluate
from weldcell.plugins.scan_plan.reconstruct import ReconstructOptions, reconstruct
from weldcell.plugins.scan_plan.stages import (
    BilateralDenoiser,
    BilateralSettings,
    EdgeSeamExtractor,
    EdgeSeamSettings,
    TorchPathPlanner,
    TorchPathSettings,
)
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.geometry import pose_error, transform_points
from weldcell.sdk.weldpath import WeldPath

ANCHORS = ("first", "mean", "hand-eye")
ERRORS = {"1mm/0.3deg": (0.001, 0.3), "3mm/1deg": (0.003, 1.0), "none": (0.0, 0.0)}


def placement_error(rec, scans, truth) -> tuple[float, float]:
    """(RMS over views, worst view) of the RMS point displacement between estimated and true pose (m)."""
    per = []
    for T, T_true, sc in zip(rec.T_base_camera, truth, scans, strict=True):
        P = sc.cloud.points[::20]
        d = transform_points(T, P) - transform_points(T_true, P)
        per.append(float(np.sqrt(np.mean(np.sum(d * d, axis=1)))))
    return float(np.sqrt(np.mean(np.square(per)))), max(per)


def surface_error(cloud: PointCloud, wp) -> float:
    """Mean distance (m) of the model's points to the workpiece's true surface."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(wp.mesh_in_world()))
    d = scene.compute_distance(o3d.core.Tensor(cloud.points.astype(np.float32))).numpy()
    return float(np.mean(d))


def on_seam(rec, wp) -> tuple[float, int]:
    """(on-seam translation RMSE m, number of seams found) after the job's default stages."""
    seam = wp.seams_in_world()[0]
    clean = BilateralDenoiser(BilateralSettings())(rec.cloud)
    ex = EdgeSeamExtractor(EdgeSeamSettings())(clean)
    path = TorchPathPlanner(TorchPathSettings(standoff=0.0, travel_angle=0.0))(ex.seams)
    tree = cKDTree(seam.points)
    on = [s for s in path.seams if np.median(tree.query(s.points)[0]) < 0.005]
    if not on:
        return float("nan"), len(ex.seams)
    m = evaluate(WeldPath(on, frame="base"), [(wp.kind, seam)], 0.0)
    return m["translation_rmse_mm"] * 1e-3, len(ex.seams)


def run(kind: str, seed: int, error: tuple[float, float], with_seam: bool) -> dict:
    wp, truth, scans, T_fc = capture(kind, seed, error)
    out = {}
    for anchor in ANCHORS:
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            options = ReconstructOptions(voxel=0.0015, max_correspondence_distance=0.005, anchor=anchor)
            rec = reconstruct(scans, T_fc, options)
        dt = time.perf_counter() - t0
        he = T_fc @ rec.hand_eye.D if rec.hand_eye is not None and rec.hand_eye.applied else T_fc
        he_t, he_r = pose_error(he, np.eye(4))
        v_rms, v_max = placement_error(rec, scans, truth)
        r = {
            "he_mm": he_t * 1e3,
            "he_deg": np.degrees(he_r),
            "view_mm": v_rms * 1e3,
            "view_max_mm": v_max * 1e3,
            "surface_mm": surface_error(rec.cloud, wp) * 1e3,
            "time_s": dt,
            "notes": [str(w.message) for w in caught],
            "fit": rec.hand_eye.summary() if rec.hand_eye is not None else None,
        }
        if with_seam:
            seam_rmse, n_seams = on_seam(rec, wp)
            r["seam_mm"], r["seams"] = seam_rmse * 1e3, n_seams
        out[anchor] = r
    return out


def case_line(x: dict) -> str:
    """One printed line per anchor and case."""
    out = (
        f"hand-eye {x['he_mm']:.2f} mm / {x['he_deg']:.3f} deg, views {x['view_mm']:.2f} "
        f"[{x['view_max_mm']:.2f}] mm, surface {x['surface_mm']:.3f} mm, {x['time_s']:.1f} s"
    )
    if "seam_mm" in x:
        out += f", on-seam {x['seam_mm']:.3f} mm ({x['seams']} seams)"
    fit = x["fit"]
    if fit:
        out += (
            f"; D {fit['translation_mm']:.2f} mm / {fit['rotation_deg']:.3f} deg, applied {fit['applied']}, "
            f"spread {fit['spread_deg']:.0f} deg, "
            f"sigma {fit['sigma_mm']:.3f} mm / {fit['sigma_deg']:.4f} deg, "
            f"residual {fit['residual_mm']:.3f} mm / {fit['residual_deg']:.4f} deg"
        )
    return out + (f" {x['notes']}" if x["notes"] else "")


def table(rows: list, with_seam: bool) -> None:
    """Markdown table: mean over seeds, worst seed in brackets."""
    cols = ["workpiece", "hand-eye error", "anchor", "hand-eye after mm", "deg", "views mm", "worst view mm"]
    cols += ["surface mm"] + (["on-seam mm", "seams"] if with_seam else [])
    print("| " + " | ".join(cols) + " |")
    print("|---" * len(cols) + "|")
    for kind, err, res in rows:
        for a in ANCHORS:

            def stat(key: str, a: str = a, res: list = res, f: str = ".2f") -> str:
                return mean_worst((r[a][key] for r in res), f)

            cells = [
                kind,
                err,
                a,
                stat("he_mm"),
                stat("he_deg", f=".3f"),
                stat("view_mm"),
                stat("view_max_mm"),
            ]
            cells.append(stat("surface_mm", f=".3f"))
            if with_seam:
                cells += [stat("seam_mm", f=".3f"), f"{statistics.mean(r[a]['seams'] for r in res):.1f}"]
            print("| " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--pieces", nargs="*", default=list(WORKPIECES))
    ap.add_argument(
        "--errors",
        nargs="*",
        default=["1mm/0.3deg", "3mm/1deg"],
        choices=list(ERRORS),
        help="planted hand-eye errors; 'none' = the true hand-eye (what each anchor does without an error)",
    )
    ap.add_argument("--seam", action="store_true", help="also run the seam stages (on-seam RMSE)")
    args = ap.parse_args()
    rows = []
    for kind in args.pieces:
        for err in args.errors:
            res = []
            for seed in range(args.seeds):
                res.append(run(kind, seed, ERRORS[err], args.seam))
                for a in ANCHORS:
                    print(f"  {kind} {err} seed {seed} {a:>8}: {case_line(res[-1][a])}", flush=True)
            rows.append((kind, err, res))
    print()
    print(f"Hand-eye error found by reconstruction: {args.seeds} seeds (mean; worst seed in brackets)")
    print()
    table(rows, args.seam)


if __name__ == "__main__":
    main()
