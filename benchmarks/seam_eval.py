"""Seam-stage evaluation set: every joint, any placement, three scanners (weldcell.testing.seam_cases).

Run:  .venv/bin/python benchmarks/seam_eval.py [--cases 231] [--seed 0] [--only 0 5 17] [--joints lap ...]

Each case is a seeded simulated scan (``weldcell.testing.seam_cases.make_case``): a joint of random size
placed at random (resting on a table face, or held in a fixture at any rotation, the scene sometimes in a
turned base frame) and scanned by an area RGB-D camera, a structured-light scanner or a swept laser
line profiler. The job's stages run with their defaults exactly as ``weldcell seam CLOUD`` runs them
(bilateral denoise + voxel grid, seam extraction, torch frames; camera positions passed where the
scanner records them). Scored against the part of each true seam the scan shows: precision / recall /
F1 at 1.5 mm, translation RMSE (perpendicular distance of the matched seam points) and RMS approach
error. Prints per-case lines and markdown tables per joint, scanner and placement; asserts nothing.
"""

from __future__ import annotations

import argparse
import math
import time
from collections import defaultdict

import numpy as np
from weldcell.plugins.scan_plan.stages import (
    BilateralDenoiser,
    BilateralSettings,
    EdgeSeamExtractor,
    EdgeSeamSettings,
)
from weldcell.sdk.cloud import PointCloud
from weldcell.testing.seam_cases import JOINT_KINDS, SeamCase, make_case, score_case


def run_method(case: SeamCase) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """The default denoise + seam stages on the case's cloud: [(points, approach, closed)]."""
    cloud = PointCloud(case.points, frame="base", viewpoints=case.viewpoints)
    clean = BilateralDenoiser(BilateralSettings())(cloud)
    ex = EdgeSeamExtractor(EdgeSeamSettings())(clean)
    return [(s.points, s.normals, s.closed) for s in ex.seams]


def evaluate_case(case: SeamCase) -> dict:
    t0 = time.perf_counter()
    try:
        found = run_method(case)
        error = ""
    except Exception as exc:  # a case the method cannot run on scores 0, with the reason printed
        found, error = [], f"{type(exc).__name__}: {exc}"
    dt = time.perf_counter() - t0
    sc = score_case(case, found)
    return dict(case=case, score=sc, seconds=dt, found=len(found), error=error)


def _agg(rows: list[dict]) -> str:
    f1 = [r["score"].f1 for r in rows]
    rm = [r["score"].rmse for r in rows if not math.isnan(r["score"].rmse)]
    ap = [r["score"].approach for r in rows if not math.isnan(r["score"].approach)]
    rmse = f"{1e3 * math.sqrt(np.mean(np.square(rm))):.2f}" if rm else "-"
    appr = f"{math.degrees(math.sqrt(np.mean(np.square(ap)))):.2f}" if ap else "-"
    return (
        f"{len(rows)} | {np.mean([r['score'].precision for r in rows]):.3f} | "
        f"{np.mean([r['score'].recall for r in rows]):.3f} | {np.mean(f1):.3f} | {min(f1):.3f} | "
        f"{sum(v < 0.8 for v in f1)} | {rmse} | {appr}"
    )


def table(rows: list[dict], key: str, title: str) -> list[str]:
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[key_of(r, key)].append(r)
    out = [
        f"| {title} | cases | precision | recall | F1 mean | F1 min | F1 < 0.8 | RMSE_p mm | approach deg |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    order = JOINT_KINDS if key == "joint" else sorted(groups)
    for g in order:
        if g in groups:
            out.append(f"| {g} | {_agg(groups[g])} |")
    out.append(f"| **all** | {_agg(rows)} |")
    return out


def key_of(r: dict, key: str) -> str:
    c = r["case"]
    if key == "placement":
        return c.placement.replace("-turned", "")
    return getattr(c, key)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=231, help="number of cases (231 = 7 per joint x scanner)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", type=int, nargs="*", help="run only these case indices")
    ap.add_argument("--joints", nargs="*", help="run only these joints")
    args = ap.parse_args()
    idx = args.only if args.only else range(args.cases)
    rows = []
    t_all = time.perf_counter()
    for i in idx:
        if args.joints and JOINT_KINDS[i % len(JOINT_KINDS)] not in args.joints:
            continue
        case = make_case(i, args.seed)
        r = evaluate_case(case)
        s = r["score"]
        rows.append(r)
        print(
            f"  {case.name}: {r['found']} seam(s), P {s.precision:.3f} R {s.recall:.3f} F1 {s.f1:.3f}, "
            f"RMSE {1e3 * s.rmse:.2f} mm, approach {math.degrees(s.approach):.2f} deg, shown "
            f"{1e3 * s.shown_length:.0f} mm, found {1e3 * s.found_length:.0f} mm, {len(case.points)} pts, "
            f"{r['seconds']:.1f} s {r['error']}",
            flush=True,
        )
    print(f"\n{len(rows)} cases, seed {args.seed}, {time.perf_counter() - t_all:.0f} s\n")
    for key, title in (("joint", "joint"), ("scanner", "scanner"), ("placement", "placement")):
        print("\n".join(table(rows, key, title)))
        print()


if __name__ == "__main__":
    main()
