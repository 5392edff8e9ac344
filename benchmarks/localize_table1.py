"""Paper 002, Table 1: localization accuracy and failure rate over placement trials, via `weldcell study`.

Run:  .venv/bin/python benchmarks/localize_table1.py [--trials 150] [--methods robust,paper7,paper1]
          [--workpieces ladder,truss,spaceframe] [--plans zigzag,spiral] [--workers N] [-o OUT_DIR [--reuse]]

(``--reuse``: summarize the rows whose study.json is already in OUT_DIR -- e.g. rows run by several
processes into one folder -- instead of running them.)

Every row (workpiece x plan x method) is one study of ``profiles/cell3-localize-table1-sim.toml`` (the
``localize-and-weld`` job with ``scope = "localize"``: template, the simulated worker's placement, the job's
own inspection plan scanned by the optoNCDT 1402 sensor model, edges, localization, errors against the truth;
no robot motion, projector or weld), run by ``weldcell.sdk.scale.study.run_study`` -- the API of
``weldcell study`` -- with the row's values and the placement drawn per trial. The exact command of each row
is printed, e.g.::

    weldcell study profiles/cell3-localize-table1-sim.toml --trials 150 --seed 0 \\
        --vary 'job.settings.worker.placement_x=uniform(-15 mm, 15 mm)' \\
        --vary 'job.settings.worker.placement_y=uniform(-15 mm, 15 mm)' \\
        --vary 'job.settings.worker.placement_theta=uniform(-20 deg, 20 deg)' \\
        --vary 'job.settings.template=choice(ladder)' --vary 'job.settings.plan.plan=choice(local)' ...

Protocol (§V): ±15 mm in X and Y and ±20° in θ, uniform; every member off CAD by up to ±2 mm (a shift and a
rotation about its centre, its farthest point moved by uniform [0, 2] mm); the sensor model: 0.288 mm depth
noise, the 0.4 mm robot-sensor coupling (0.2 mm per axis, constant along each line), shearing within 0.2 mm
of a drop (half the readings lost), 1.5 kHz at 0.2 m/s (0.13 mm spacing). Plans (the job's, §III-C):
``zigzag`` = local, legs 20 mm apart, 40 mm beyond each member; ``spiral`` = global, rings 12 mm apart along
the principal axes, 40 mm beyond the part, with the serpentine core (default); ``spiral-paper`` = the paper's
spiral alone (``spiral_core = "none"``). Methods: ``robust`` (default pipeline: global search + robust
Gauss-Newton + ambiguity + members + weld re-plan), ``paper7`` / ``paper1`` (Powell from 7 / 1 seeds on eq. 3,
2.5 mm mean-error check; each weld moved by M alone, as in the paper).

Reported per row: σ of the pose error X, Y, θ against three references (study statistics): the pose a
perfect measurement of the as-built part along the plan would return (``pose_error_vs_asbuilt``, the
localization's own error), the placement (``error_vs_truth``, the paper's definition, which includes the
members' deviations from CAD) and the best rigid match of the CAD outlines to the as-built ones
(``pose_error_vs_asbuilt_outline``; plugins/localize/reference.py); the references themselves (crossings,
the as-built part's RMS about its best pose, how much the two as-built references differ, the bias); σ of
the weld points' X and Y error against the true welds, pooled over the ok trials (from each trial's mean and
RMS: ``welds_vs_truth`` for robust, ``welds_rigid_vs_truth`` for the paper's methods); failed % (the study's
failure rate: failed, ambiguous, refused plan); uncertain welds % (robust: welds its members did not place,
not claimed); wrong answers (ok but a claimed weld > 2.5 mm off); the median CPU ms of the localization in
the trial. Prints markdown; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

PROFILE = Path(__file__).resolve().parents[1] / "profiles" / "cell3-localize-table1-sim.toml"
PLACEMENT = [
    "job.settings.worker.placement_x=uniform(-15 mm, 15 mm)",
    "job.settings.worker.placement_y=uniform(-15 mm, 15 mm)",
    "job.settings.worker.placement_theta=uniform(-20 deg, 20 deg)",
]
PLANS = {
    "zigzag": ["job.settings.plan.plan=choice(local)", "job.settings.plan.spacing=choice(20 mm)"],
    "spiral": ["job.settings.plan.plan=choice(global)", "job.settings.plan.spacing=choice(12 mm)"],
    "spiral-paper": [
        "job.settings.plan.plan=choice(global)",
        "job.settings.plan.spacing=choice(12 mm)",
        "job.settings.plan.spiral_core=choice(none)",
    ],
}
METHODS = {
    "robust": ["stages.localize.settings.method=choice(robust)"],
    "paper7": ["stages.localize.settings.method=choice(paper)", "stages.localize.settings.seeds=choice(7)"],
    "paper1": ["stages.localize.settings.method=choice(paper)", "stages.localize.settings.seeds=choice(1)"],
}


def row_vary(workpiece: str, plan: str, method: str) -> list[str]:
    return [*PLACEMENT, f"job.settings.template=choice({workpiece})", *PLANS[plan], *METHODS[method]]


def command(trials: int, seed: int, vary: list[str], out: Path) -> str:
    v = " ".join(f"--vary '{x}'" for x in vary)
    return f"weldcell study {PROFILE.relative_to(Path.cwd())} --trials {trials} --seed {seed} {v} -o {out}"


def pooled(trials: list[dict], key: str) -> tuple[float, float]:
    """σ of the weld points' X and Y error over all ok trials, from each trial's count, mean and RMS."""
    n = sx = sy = qx = qy = 0.0
    for t in trials:
        f = t["figures"]
        k = f.get(f"{key}.points", 0.0)
        n += k
        sx += k * f[f"{key}.mean_x_mm"]
        sy += k * f[f"{key}.mean_y_mm"]
        qx += k * f[f"{key}.rms_x_mm"] ** 2
        qy += k * f[f"{key}.rms_y_mm"] ** 2
    if not n:
        return math.nan, math.nan
    return math.sqrt(max(qx / n - (sx / n) ** 2, 0.0)), math.sqrt(max(qy / n - (sy / n) ** 2, 0.0))


def summarize(study: dict, method: str) -> dict:
    trials = list(study["trials"].values())
    ok = [t for t in trials if t["status"] == "ok"]
    st = study["statistics"]
    key = "welds_vs_truth" if method == "robust" else "welds_rigid_vs_truth"

    def sd(k):
        return st[k]["std"] if k in st else math.nan

    wx, wy = pooled(ok, key)
    fig = [t["figures"] for t in ok]
    return {
        "n": len(trials),
        "ok": ok,
        "pose": (
            sd("localization.error_vs_truth.x_mm"),
            sd("localization.error_vs_truth.y_mm"),
            sd("localization.error_vs_truth.theta_deg"),
        ),
        "asbuilt": tuple(
            sd(f"localization.pose_error_vs_asbuilt.{k}") for k in ("x_mm", "y_mm", "theta_deg")
        ),
        "outline": tuple(
            sd(f"localization.pose_error_vs_asbuilt_outline.{k}") for k in ("x_mm", "y_mm", "theta_deg")
        ),
        "weld": (wx, wy),
        "failed": 100.0 * study["failure_rate"],
        "uncertain": 100.0 * statistics.fmean(f.get(f"{key}.uncertain_fraction", 0.0) for f in fig)
        if fig
        else 0,
        "wrong": int(sum(f.get(f"{key}.wrong", 0.0) for f in fig)),
        "points": statistics.median(f["edge_points"] for f in fig) if fig else math.nan,
        "cpu": statistics.median(f["timings_ms.localize"] for f in fig) if fig else math.nan,
        "lost": study["counts"]["lost"],
        "errors": sorted(
            {(t.get("error") or {}).get("line", "")[:120] for t in trials if t["status"] != "ok"}
        ),
        "reference": _reference_figures(fig),
    }


def _reference_figures(fig: list[dict]) -> dict:
    """The as-built references themselves: crossings per trial, the as-built part's RMS about its best rigid
    pose, the σ of the difference of the two references (how much the definition matters), and the mean
    (bias) of the pose error against the crossing reference."""
    key = "asbuilt_reference"
    sel = [f for f in fig if f.get(f"{key}.crossings.x") is not None]
    if len(sel) < 2:
        return {}
    diff = [[(f[f"{key}.crossings.{a}"] - f[f"{key}.outline.{a}"]) * 1e3 for a in ("x", "y")] for f in sel]
    return {
        "crossings": statistics.median(f[f"{key}.n_crossings"] for f in sel),
        "rms_mm": statistics.median(f[f"{key}.rms_mm"] for f in sel),
        "ref_diff_sd": tuple(statistics.stdev(d[i] for d in diff) for i in (0, 1)),
        "bias": tuple(
            statistics.fmean(f[f"localization.pose_error_vs_asbuilt.{a}"] for f in sel)
            for a in ("x_mm", "y_mm")
        ),
    }


def _rms(values) -> float:
    """Root mean square of the rows' σ (the rows have equal trial counts): the σ of all their trials."""
    return math.sqrt(statistics.fmean(v**2 for v in values))


def _triple(v) -> str:
    return f"{v[0]:.3f} / {v[1]:.3f} / {v[2]:.3f}"


def main() -> None:
    from weldcell.sdk.scale.cluster import ClusterOptions
    from weldcell.sdk.scale.study import run_study

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--trials", type=int, default=150)
    ap.add_argument("--workpieces", default="ladder,truss,spaceframe")
    ap.add_argument("--plans", default="zigzag,spiral")
    ap.add_argument("--methods", default="robust")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=None, help="local worker processes (0: in this process)")
    ap.add_argument("-o", "--out", type=Path, default=None, help="keep the studies here (resumable)")
    ap.add_argument("--reuse", action="store_true", help="summarize a row's finished study.json in OUT as is")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="localize-table1-"))
    opts = ClusterOptions(workers=args.workers)
    print(
        f"{args.trials} trials per row, seed {args.seed}, studies in {out}; load {os.getloadavg()[0]:.1f}\n"
    )
    rows, cmds = [], []
    head = (
        "| workpiece | plan | method | edge pts | σX / σY / σθ pose vs as-built (mm, mm, deg) "
        "| σX / σY / σθ pose vs placement | σX / σY / σθ pose vs as-built outline | σX weld (mm) "
        "| σY weld (mm) | failed % | uncertain welds % | wrong ok | median localize cpu ms |"
    )
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for wp in args.workpieces.split(","):
        for plan in args.plans.split(","):
            for m in args.methods.split(","):
                vary = row_vary(wp, plan, m)
                dest = out / f"{wp}-{plan}-{m}"
                cmds.append(command(args.trials, args.seed, vary, dest))
                t0 = time.perf_counter()
                done = dest / "study.json"
                if args.reuse and done.is_file():
                    study = json.loads(done.read_text(encoding="utf-8"))
                else:
                    study = run_study(PROFILE, args.trials, vary, dest, opts, seed=args.seed)
                r = summarize(study, m)
                r.update(wp=wp, plan=plan, method=m, wall=time.perf_counter() - t0)
                rows.append(r)
                print(
                    f"| {wp} | {plan} | {m} | {r['points']:.0f} | {_triple(r['asbuilt'])} | "
                    f"{_triple(r['pose'])} | {_triple(r['outline'])} | "
                    f"{r['weld'][0]:.3f} | {r['weld'][1]:.3f} | {r['failed']:.1f} | {r['uncertain']:.1f} | "
                    f"{r['wrong']} | {r['cpu']:.0f} |",
                    flush=True,
                )
    print("\n| method | plans | figure | σX (mm) | σY (mm) | σθ (deg) | failed % | wrong ok |")
    print("|---|---|---|---|---|---|---|---|")
    print("| paper (Table 1, real cell) | both | pose | 0.31 | 0.43 | 0.36 | < 13 | ? |")
    for m in args.methods.split(","):
        for plans in [args.plans, *args.plans.split(",")] if "," in args.plans else [args.plans]:
            sel = [r for r in rows if r["method"] == m and r["plan"] in plans.split(",")]
            fail = statistics.fmean(r["failed"] for r in sel)
            wrong = sum(r["wrong"] for r in sel)
            for name, key in (
                ("pose vs as-built", "asbuilt"),
                ("pose vs placement", "pose"),
                ("pose vs as-built outline", "outline"),
                ("weld points", "weld"),
            ):
                v = [_rms(r[key][i] for r in sel) for i in range(len(sel[0][key]))]
                th = f"{v[2]:.3f}" if len(v) > 2 else ""
                print(f"| {m} | {plans} | {name} | {v[0]:.3f} | {v[1]:.3f} | {th} | {fail:.1f} | {wrong} |")
    print(
        "\n| workpiece | plan | method | crossings | as-built RMS about its best pose (mm) "
        "| σX / σY crossings ref − outline ref (mm) | mean pose error vs as-built X / Y (mm) |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        g = r["reference"]
        if g:
            dx, dy = g["ref_diff_sd"]
            bx, by = g["bias"]
            print(
                f"| {r['wp']} | {r['plan']} | {r['method']} | {g['crossings']:.0f} | {g['rms_mm']:.3f} | "
                f"{dx:.3f} / {dy:.3f} | {bx:+.3f} / {by:+.3f} |"
            )
    for r in rows:
        if r["errors"] or r["lost"]:
            print(f"\n{r['wp']} {r['plan']} {r['method']}: {r['lost']} lost; failures: {r['errors']}")
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}; the rows as commands:")
    for c in cmds:
        print("   ", c)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
