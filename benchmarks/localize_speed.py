"""Paper 002, §IV: speed of one localization (edge points of one inspection), and the effect of the fast cost.

Run:  .venv/bin/python benchmarks/localize_speed.py [--trials 5] [--repeats 3]

For each workpiece (ladder, truss, spaceframe) and inspection plan (zig-zag, spiral), ``--trials`` placements
of the Table 1 protocol (benchmarks/localize_table1.py: ±15 mm / ±20°, members off CAD by up to 2 mm,
the optoNCDT 1402 model), scanned along ``synth``'s plans; the edge extraction of each scan is timed
(readings per CPU second, median of ``--repeats`` runs); on each one's edge points:

* ``paper7 serial``: the paper's method, 7 seeds of Powell on eq. (3), in this process (no pool);
* ``paper7 auto``: the same with the process pool when it pays (``Localization.parallel``);
* ``robust``: the default pipeline (global search + robust Gauss-Newton + members + welds).

Each is run ``--repeats`` times (the template's distance field is built once per process, outside the
timing, as in a cell that localizes one workpiece after another); the median over all runs of the CPU time
of this process (``time.process_time``; the pool's workers are not in it) and of the wall time, for the
whole ``localize`` call, and the CPU of the paper's search itself (``timings["powell_cpu"]``: 7 seeds +
exact polish, without the member fits and weld re-plan that follow).

Accuracy of the fast path: the paper's search as it runs (seeds on eq. 3 through the template's Voronoi
labels, 0.3 mm tolerance, a seed stopped once it joins the basin of a minimum already found, then Powell on
the exact eq. 3 -- on each point's candidate segments, provably the all-pairs value -- from the winner)
against a reference of the same seeds on the exact eq. 3 (every point against every segment, every seed to
its end) at 1 µm tolerance: the largest pose difference and the largest relative difference of the eq. (3)
value. The load average is printed beside the times.
Prints markdown; nothing is asserted.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time

import numpy as np
from scipy.optimize import minimize
from weldcell.plugins.localize.cost import Eq3, Segments
from weldcell.plugins.localize.edges import extract_edges
from weldcell.plugins.localize.fit import LocalizeSettings, localize
from weldcell.plugins.localize.pose import transform_template
from weldcell.plugins.localize.search import paper_seeds
from weldcell.plugins.localize.synth import (
    SensorModel,
    apply_variations,
    member_variations,
    scan_lines,
    spiral_plan,
    zigzag_plan,
)
from weldcell.plugins.localize.workpieces import WORKPIECES, make_workpiece

CASES = {
    "paper7 serial": LocalizeSettings(method="paper", seeds=7, parallel="never"),
    "paper7 auto": LocalizeSettings(method="paper", seeds=7),
    "robust": LocalizeSettings(),
}


def reference(tpl, xy) -> tuple[np.ndarray, float]:
    """The paper's 7 seeds on the exact eq. (3) at 1 µm tolerance: lowest minimum (pose, value)."""
    segs = Segments.of(tpl)
    eq3 = Eq3(xy, segs, None, exact=True)
    unit = np.array([1e-3, 1e-3, 1e-3 / tpl.radius])
    outline = np.concatenate([m.outline for m in tpl.members])
    seeds = paper_seeds(outline, tpl.centroid, xy, 7, 0.05, math.radians(20), np.random.default_rng(0))
    opts = {"xtol": 1e-3, "ftol": 1e-10, "maxfev": 6000}
    best = min(
        (minimize(lambda p: eq3(p * unit), s / unit, method="Powell", options=opts) for s in seeds),
        key=lambda r: r.fun,
    )
    return np.asarray(best.x) * unit, float(best.fun)


def placements(tpl, lines, n, rng, sensor, rates: list[float], repeats: int = 3):
    """The edge points of ``n`` placements; appends each scan's edge-extraction rate (readings per CPU
    second, the median of ``repeats`` runs) to ``rates``."""
    for _ in range(n):
        pose = np.array(
            [rng.uniform(-0.015, 0.015), rng.uniform(-0.015, 0.015), math.radians(rng.uniform(-20, 20))]
        )
        var = member_variations(tpl, rng, 2e-3)
        placed = transform_template(apply_variations(tpl, var), pose, tpl.centroid)
        scan = scan_lines(placed, lines, rng, sensor)
        cpu = []
        for _ in range(repeats):
            c0 = time.process_time()
            edges = extract_edges(scan, tpl)
            cpu.append(time.process_time() - c0)
        rates.append(len(scan) / max(statistics.median(cpu), 1e-9))
        yield edges


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-reference", action="store_true", help="skip the exact-cost reference")
    args = ap.parse_args()
    sensor = SensorModel()
    times = {k: {"cpu": [], "wall": [], "search_cpu": []} for k in CASES}
    dev, rel, npts, loads, par, rates = [], [], [], [], set(), []
    for wp in WORKPIECES:
        tpl = make_workpiece(wp)
        for plan in ("zigzag", "spiral"):
            lines = zigzag_plan(tpl, 0.02, 0.2) if plan == "zigzag" else spiral_plan(tpl, pitch=0.012)
            rng = np.random.default_rng(args.seed)
            for edges in placements(tpl, lines, args.trials, rng, sensor, rates, args.repeats):
                npts.append(len(edges))
                localize(tpl, edges, CASES["robust"])  # warm-up: the field of this template, once
                for name, s in CASES.items():
                    for _ in range(args.repeats):
                        loads.append(os.getloadavg()[0])
                        t0, c0 = time.perf_counter(), time.process_time()
                        loc = localize(tpl, edges, s)
                        times[name]["cpu"].append(time.process_time() - c0)
                        times[name]["wall"].append(time.perf_counter() - t0)
                        times[name]["search_cpu"].append(loc.timings.get("powell_cpu", math.nan))
                        if name == "paper7 auto":
                            par.add(loc.parallel.split(":")[0])
                        if name == "paper7 serial":
                            paper_pose = loc.pose
                if not args.no_reference:
                    ref_pose, ref_val = reference(tpl, edges.xy)
                    d = np.abs(paper_pose - ref_pose)
                    dev.append([d[0] * 1e3, d[1] * 1e3, math.degrees(d[2])])
                    val = Eq3(edges.xy, Segments.of(tpl), None, exact=True)(paper_pose)
                    rel.append(val / ref_val - 1.0)
    n = len(npts)
    print(
        f"{n} inspections (3 workpieces x 2 plans x {args.trials}), median {statistics.median(npts):.0f} "
        f"edge points, {args.repeats} runs each; load average during the runs: median "
        f"{statistics.median(loads):.1f} (min {min(loads):.1f}, max {max(loads):.1f}) "
        f"on {os.cpu_count()} cores\n"
    )
    print("| localization | median CPU ms | median wall ms | of which Powell (seeds + polish) CPU ms |")
    print("|---|---|---|---|")
    for name, t in times.items():
        print(
            f"| {name} | {statistics.median(t['cpu']) * 1e3:.1f} | {statistics.median(t['wall']) * 1e3:.1f} "
            f"| {statistics.median(t['search_cpu']) * 1e3:.1f} |"
        )
    print(f"\npaper7 auto ran: {', '.join(sorted(par))}")
    print(
        f"\nedge extraction ({len(rates)} whole scans): median {statistics.median(rates) / 1e6:.2f} M "
        f"readings per CPU second (min {min(rates) / 1e6:.2f} M)"
    )
    if dev:
        dev = np.array(dev)
        print(
            "\nfast path vs exact eq. (3) at 1 µm tolerance (same seeds): pose difference max "
            f"{dev[:, 0].max():.4f} / {dev[:, 1].max():.4f} mm / {dev[:, 2].max():.4f} deg, median "
            f"{np.median(dev[:, 0]):.4f} / {np.median(dev[:, 1]):.4f} mm / {np.median(dev[:, 2]):.4f} deg; "
            f"eq. (3) value higher by at most {max(rel) * 100:.4f} % (median {np.median(rel) * 100:.4f} %)"
        )


if __name__ == "__main__":
    main()
