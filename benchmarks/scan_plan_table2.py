"""Paper 000, Table II: runtime of weld-path planning on a 500 mm straight V-groove butt joint, one capture,
in four placements, in the simulated cell.

Run:  .venv/bin/python benchmarks/scan_plan_table2.py [--repeats 5] [--preset realsense-d415]

Scene: the cell's V-groove butt joint (500 x 150 mm, 12 mm plates, 60 deg included angle, 1 mm root
gap and face) lying on a 0.8 x 0.6 m fixture plate, placed

* ``flat``: plates horizontal, seam horizontal (PA); camera straight above;
* ``tilted``: the assembly turned 30 deg about the seam axis; camera along the plate normal;
* ``horizontal``: plates vertical, seam horizontal (PC); camera looking horizontally at the plates;
* ``vertical``: plates vertical, seam vertical (PF); camera looking horizontally at the plates.

One frame of the camera (default: RealSense D415 at its full 1280x720, no decimation, 0.5 m from the
part: the whole 500 mm seam is in view) is rendered with the preset's noise, dropouts and stereo
shadows. Timed, median of ``--repeats`` runs after one warm-up:

* ``plan``: bilateral filter (eqs. 9-10, with its voxel down-sampling) + seam extraction (eqs. 11-17 +
  chaining) + torch path (eqs. 18-19) on the region-of-interest cloud -- what the paper's Table II
  times ("denoise + seam + path");
* ``capture-to-path``: the above plus depth image -> cloud, eq. 1 into the base frame and the ROI crop
  that drops the fixture plate (everything after the frame arrives);
* ``Open3D normals``: Open3D's ``estimate_normals`` (30 nearest neighbours) on the same ROI cloud, timed
  right after each plan run (issue 16: the host-independent figure is ``plan / normals``, a floor no
  seam method on that cloud can go under).

Speed = found seam length / time. Accuracy columns use the job's ``evaluate()`` (eq. 21 F1, eq. 22
RMSE of the seam frames). Prints a markdown table; nothing is asserted. Uses 2 threads (KD-tree
queries); set OMP/BLAS threads yourself if you want to pin it.

The four placements run as one ``weldcell study`` of the trial function ``scan_plan_table2:trial``
(``placement=cycle(...)``, one trial each), by default on one Dask worker so that no two timings compete
for the cores (``--workers``, ``--scheduler``; ``--workers 0``: in this process). The render seed is
``--seed`` for every placement, as before. From the command line (in benchmarks/)::

    weldcell study --function scan_plan_table2:trial --trials 4 --workers 1 --by placement -o t2 \
        --vary 'placement=cycle(flat, tilted, horizontal, vertical)'
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
from weldcell.hal.sim.camera_model import RaycastCamera
from weldcell.hal.sim.workpieces import v_groove_butt
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
from weldcell.sdk.geometry import T_from_rpy, frame_from_axes, transform_points

PAPER = {"flat": (3691, 135), "tilted": (3891, 129), "horizontal": (3600, 139), "vertical": (4100, 122)}
PLACEMENTS = {  # (roll about the seam axis x, pitch about y), degrees, of the part + fixture plate
    "flat": (0.0, 0.0),
    "tilted": (30.0, 0.0),
    "horizontal": (90.0, 0.0),
    "vertical": (90.0, 90.0),
}


def scene(placement: str):
    """The placed workpiece, the fixture mesh and T_world_part for ``placement``."""
    roll, pitch = PLACEMENTS[placement]
    T = T_from_rpy((np.radians(roll), 0.0, 0.0), (0.0, 0.0, 0.0))
    if pitch:
        T = T_from_rpy((0.0, np.radians(-pitch), 0.0), (0.0, 0.0, 0.0)) @ T
    T[:3, 3] = [0.5, 0.0, 0.3]
    wp = v_groove_butt(length=0.5, width=0.15, thickness=0.012).placed(T)
    plate = o3d.geometry.TriangleMesh.create_box(0.8, 0.6, 0.01).translate((-0.4, -0.3, -0.0101))
    plate.transform(T)
    return wp, plate, T


def camera_pose(T_world_part: np.ndarray, distance: float) -> np.ndarray:
    """Camera looking along -plate normal at the seam's centre from ``distance`` (image x along the seam)."""
    centre = transform_points(T_world_part, np.array([[0.0, 0.0, 0.012]]))[0]
    n, x = T_world_part[:3, 2], T_world_part[:3, 0]
    return frame_from_axes(x, -n, centre + distance * n)


def roi_crop(P: np.ndarray, T_world_part: np.ndarray) -> np.ndarray:
    """Points inside the part's box (+5 mm), i.e. without the fixture plate (the job's roi_min/max)."""
    Q = transform_points(np.linalg.inv(T_world_part), P)
    keep = (np.abs(Q[:, 0]) <= 0.255) & (np.abs(Q[:, 1]) <= 0.08) & (Q[:, 2] >= -0.001) & (Q[:, 2] <= 0.02)
    return P[keep]


def run(placement: str, preset: str, distance: float, repeats: int, seed: int) -> dict:
    wp, plate, T = scene(placement)
    cam = RaycastCamera(preset, [wp, plate])
    T_wc = camera_pose(T, distance)
    img = cam.render(T_wc, rng=seed)
    denoise = BilateralDenoiser(BilateralSettings())
    seam_stage = EdgeSeamExtractor(EdgeSeamSettings())
    planner = TorchPathPlanner(TorchPathSettings(standoff=0.015, travel_angle=np.radians(10)))

    def capture_to_path():
        t0 = time.perf_counter()
        P = img.to_points()  # depth image -> camera-frame cloud
        n_capture = len(P)
        P = roi_crop(transform_points(T_wc, P), T)  # eq. 1 (the camera pose is exact here) + ROI
        cloud = PointCloud(P, frame="base", viewpoints=[T_wc[:3, 3]])
        t1 = time.perf_counter()
        clean = denoise(cloud)
        ex = seam_stage(clean)
        path = planner(ex.seams)
        t2 = time.perf_counter()
        floor = open3d_normals_time(P)
        return t2 - t0, t2 - t1, n_capture, len(P), len(clean), ex, path, floor

    capture_to_path()  # warm-up
    runs = [capture_to_path() for _ in range(repeats)]
    total = statistics.median(r[0] for r in runs)
    plan = statistics.median(r[1] for r in runs)
    floor = statistics.median(r[7] for r in runs)
    _, _, n_cap, n_roi, n_clean, ex, path, _ = runs[-1]
    seam = wp.seams_in_world()[0]
    m = evaluate(path, [("v-groove", seam)], 0.015)
    length = sum(s.length for s in ex.seams)
    return dict(
        placement=placement,
        n_capture=n_cap,
        n_roi=n_roi,
        n_clean=n_clean,
        seams=len(ex.seams),
        length_mm=length * 1000,
        plan_ms=plan * 1000,
        total_ms=total * 1000,
        o3d_normals_ms=floor * 1000,
        ratio=plan / floor if floor > 0 else float("nan"),
        speed=length * 1000 / plan if plan > 0 else 0.0,
        f1=m.get("f1", {}).get("f1", 0.0),
        t_mm=m.get("translation_rmse_mm", float("nan")),
        r_deg=m.get("rotation_rmse_deg", float("nan")),
    )


def open3d_normals_time(P: np.ndarray) -> float:
    """Seconds Open3D takes to estimate normals (its default 30 nearest neighbours, its own threads) on the
    ROI cloud ``P``, from the numpy array on: the floor any seam method on that cloud stands on."""
    t0 = time.perf_counter()
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    pc.estimate_normals()
    return time.perf_counter() - t0


def trial(values: dict[str, Any], seed: int, trial: int) -> dict:
    """One placement (study trial function): ``values`` placement, preset, distance (m), repeats,
    render_seed (default 0: the same frame noise as earlier runs)."""
    return run(
        str(values.get("placement", "flat")),
        str(values.get("preset", "realsense-d415")),
        float(values.get("distance", 0.5)),
        int(values.get("repeats", 5)),
        int(values.get("render_seed", 0)),
    )


def study_rows(args) -> list[dict]:
    """The four placements as one study (one trial each); rows in the table's order."""
    from weldcell.sdk.scale.cluster import ClusterOptions
    from weldcell.sdk.scale.progress import TaskProgress
    from weldcell.sdk.scale.study import run_study

    study = run_study(
        None,
        len(PLACEMENTS),
        [
            f"placement=cycle({', '.join(PLACEMENTS)})",
            f"preset=choice({args.preset})",
            f"distance=choice({args.distance!r})",
            f"repeats=choice({args.repeats})",
            f"render_seed=choice({args.seed})",
        ],
        args.out or Path(tempfile.mkdtemp(prefix="weldcell-table2-")),
        ClusterOptions(workers=None if args.scheduler else args.workers, scheduler=args.scheduler),
        progress=TaskProgress(True),
        function="scan_plan_table2:trial",
        by="placement",
    )
    rows = []
    for t in sorted(study["trials"].values(), key=lambda t: t["trial"]):
        if t["status"] != "ok":
            print(f"  {t['values']['placement']}: {t['status']}: {t['error']['line']}")
            continue
        counts = {k: int(t["figures"][k]) for k in ("n_capture", "n_roi", "n_clean", "seams")}
        nans = {"t_mm": float("nan"), "r_deg": float("nan")}  # NaN (no seam) is not a figure
        rows.append({"placement": t["values"]["placement"], **nans, **t["figures"], **counts})
        print(f"  {t['values']['placement']}: {t['figures']}", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--preset", default="realsense-d415")
    ap.add_argument("--distance", type=float, default=0.5, help="camera to part (m)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1, help="local Dask workers (0: in this process)")
    ap.add_argument("--scheduler", default=None, help="an existing Dask scheduler address")
    ap.add_argument("--out", type=Path, help="the study's folder (default: a new temporary one)")
    args = ap.parse_args()
    rows = study_rows(args)
    print()
    print(
        f"Table II (paper 000) in simulation: {args.preset}, one frame at {args.distance} m, median of "
        f"{args.repeats} runs"
    )
    print()
    print(
        "| placement | points (frame / ROI / denoised) | seams | seam mm | F1 | RMSE mm / deg | "
        "plan ms | capture-to-path ms | mm/s | paper ms | paper mm/s | Open3D normals ms | plan / normals |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        pm, ps = PAPER[r["placement"]]
        print(
            f"| {r['placement']} | {r['n_capture']} / {r['n_roi']} / {r['n_clean']} | {r['seams']} | "
            f"{r['length_mm']:.1f} | {r['f1']:.3f} | {r['t_mm']:.2f} / {r['r_deg']:.2f} | "
            f"{r['plan_ms']:.0f} | {r['total_ms']:.0f} | {r['speed']:.0f} | {pm} | {ps} | "
            f"{r['o3d_normals_ms']:.0f} | {r['ratio']:.2f} |"
        )


if __name__ == "__main__":
    main()
