"""§3.1 simulation protocol: all-data SVD (eqs. 9-12) vs the iterative method (Algorithm 1), Figs. 9-10.

    .venv/bin/python benchmarks/handeye_simulation.py            # 6 noise levels x 20 realizations
    .venv/bin/python benchmarks/handeye_simulation.py --full     # 50 levels (0.2..10 mm) x 100
    .venv/bin/python benchmarks/handeye_simulation.py --only icp   # realistic verifier, ~13 min

Protocol (paper §3.1, details from the authors' published scripts, see simulation.py): eq. 19 camera,
75 flange centres on the 5 x 5 x 3 grid x 0.45-0.75, y ±0.15, z 0.2-0.4 m, noise N(0, σ) added to
the camera points only (eq. 20), a fresh noise draw and a fresh pair order per realization, all-data
= eqs. 10-12 without the scale c on all 75 pairs, Algorithm 1 = a 4-pair pool grown over all 75
pairs with the ground-truth verifier e = inv(Ĥ) H_true, cost ‖δt‖₂ and e_required = 0 (so the pool
sees every pair, as in Figs. 9-10). Errors: δt, δrpy of inv(Ĥ) H_true (translation = displacement
of the camera origin, the paper's measure) and, beside it, the RMS displacement of the 75 grid points
(the error in the work volume).

Prints markdown tables: (1) ``fig9``: std of the errors vs σ and the growth rates (slope of std vs σ)
for all-data, published Algorithm 1, the wide search (``search="wide"``) and the Cramér–Rao bound of
the pairs alone; (2) ``fig10``: std vs number of samples at σ = 1 mm; (3) ``budget``: the wide
search's budget against the paper's two claims; (4) ``variants`` at σ = 1 mm: noise model, the
listing's sequential inner loop, the radius cost, the consensus refit, and 3 outliers with the
consensus verifier (no ground truth); (5) ``icp``: the realistic verifier of eq. 13 (ICP of the flange
model against a simulated verification scan with the same per-point σ) instead of the oracle; run
only with ``--only icp``.

Fig. 9 runs as one ``weldcell study`` of the trial function ``handeye_simulation:fig9_trial`` (one trial =
one realization at one σ; ``sigma=cycle(...)``, statistics per σ with ``--by sigma``) on Dask
(``--workers``, ``--scheduler``; ``--workers 0``: in this process), seeded as before, so its numbers are
those of the earlier loop. The other sections still loop here.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from weldcell.plugins.handeye.iterative import iterative_pool
from weldcell.plugins.handeye.pointfit import robust_point_fit, scaled_svd_fit
from weldcell.plugins.handeye.simulation import (
    PAPER_SIGMAS,
    crlb_workspace_rms,
    pairs_crlb,
    scan_verifier,
    simulate_cell,
    workspace_error,
)
from weldcell.plugins.handeye.verification import (
    ConsensusVerifier,
    GroundTruthVerifier,
    error_components,
    radius_cost,
)
from weldcell.sdk.geometry import invert

SECTIONS = ("fig9", "fig10", "budget", "variants", "icp")


def errs(H: np.ndarray, cell) -> np.ndarray:
    """[δx, δy, δz (mm), δroll, δpitch, δyaw (°), workspace rms (mm)] of H against the truth."""
    e = error_components(invert(H) @ cell.T_base_camera)
    return np.r_[
        np.array([e["dx"], e["dy"], e["dz"]]) * 1e3,
        np.degrees([e["droll"], e["dpitch"], e["dyaw"]]),
        workspace_error(H, cell.T_base_camera, cell.p_cam_true) * 1e3,
    ]


def crlb_row(cov: np.ndarray, cell) -> np.ndarray:
    """The Cramér–Rao bound in the layout of :func:`errs` (stds; last = sqrt E[rms²])."""
    sd = np.sqrt(np.diag(cov))
    return np.r_[sd[:3] * 1e3, np.degrees(sd[3:]), crlb_workspace_rms(cov, cell.p_cam_true) * 1e3]


def f3(v, fmt="{:.3f}") -> str:
    return ", ".join(fmt.format(x) for x in v)


def slope(S: np.ndarray, y) -> float:
    """Growth rate: slope of a straight line fitted to ``y`` against σ (mm)."""
    return float(np.polyfit(S, np.asarray(y, float), 1)[0])


ERR_KEYS = ("dx", "dy", "dz", "droll", "dpitch", "dyaw", "ws")
FIG9_METHODS = ("all", "pub", "wide")


def realization(sigma: float, k: int):
    """Realization ``k`` at noise ``sigma`` (m): (cell, noisy camera points), seeded as before."""
    rng = np.random.default_rng(1000 * k + int(round(sigma * 1e5)))
    cell = simulate_cell(rng=rng)
    return cell, cell.noisy_p_cam(sigma, rng)


def fig9_trial(values: dict, seed: int, trial: int) -> dict:
    """One Fig. 9 realization (study trial function): ``values`` sigma (m), levels (how many sigmas are
    cycled: trial i is realization i // levels), budget. Figures: ``{method: {dx, ..., ws}}``, the
    :func:`errs` of all-data, Algorithm 1 and the wide search (mm, deg)."""
    sigma, k = float(values["sigma"]), trial // int(values.get("levels", 1))
    cell, c = realization(sigma, k)
    gt = GroundTruthVerifier(cell.T_base_camera)
    H = {
        "all": scaled_svd_fit(c, cell.p_base).T,
        "pub": iterative_pool(c, cell.p_base, gt).H,
        "wide": iterative_pool(c, cell.p_base, gt, search="wide", budget=int(values["budget"]), seed=k).H,
    }
    return {m: dict(zip(ERR_KEYS, errs(H[m], cell).tolist(), strict=True)) for m in FIG9_METHODS}


def fig9(sigmas: np.ndarray, nreal: int, budget: int, options=None, out: Path | None = None) -> None:
    """Fig. 9 through ``weldcell study``: ``nreal`` x len(sigmas) trials of :func:`fig9_trial`."""
    from weldcell.sdk.scale.cluster import ClusterOptions
    from weldcell.sdk.scale.progress import TaskProgress
    from weldcell.sdk.scale.study import run_study

    levels = ", ".join(repr(float(s)) for s in sigmas)
    study = run_study(
        None,
        nreal * len(sigmas),
        [f"sigma=cycle({levels})", f"levels=choice({len(sigmas)})", f"budget=choice({budget})"],
        out or Path(tempfile.mkdtemp(prefix="weldcell-fig9-")),
        options or ClusterOptions(),
        progress=TaskProgress(True),
        function="handeye_simulation:fig9_trial",
        by="sigma",
    )
    trials = sorted(study["trials"].values(), key=lambda t: t["trial"])
    lost = [t for t in trials if t["status"] != "ok"]
    if lost:
        raise SystemExit(f"{len(lost)} realizations did not finish: {lost[0].get('error', {}).get('line')}")
    rows = []
    for sigma in sigmas:
        mine = [t["figures"] for t in trials if t["values"]["sigma"] == float(sigma)]
        M = {m: np.array([[f[f"{m}.{k}"] for k in ERR_KEYS] for f in mine]) for m in FIG9_METHODS}
        cell, _ = realization(float(sigma), nreal - 1)
        rows.append((sigma * 1e3, M, crlb_row(pairs_crlb(cell.p_cam_true, sigma), cell)))
    print(f"## Fig. 9: error vs noise (75 poses, {nreal} realizations per level, wide budget {budget})\n")
    print(
        "| σ (mm) | std δx, δy, δz (mm): all-data | Alg. 1 | wide search | CR bound "
        "| std δyaw (°) all / Alg. 1 / wide / CR | work-volume rms (mm) all / Alg. 1 / wide / CR |"
    )
    print("|---|---|---|---|---|---|---|")
    for s, M, cr in rows:
        sd = {key: v.std(0) for key, v in M.items()}
        yaw = " / ".join(f"{x:.3f}" for x in (sd["all"][5], sd["pub"][5], sd["wide"][5], cr[5]))
        ws = " / ".join(
            f"{x:.3f}" for x in (M["all"][:, 6].mean(), M["pub"][:, 6].mean(), M["wide"][:, 6].mean())
        )
        print(
            f"| {s:.1f} | {f3(sd['all'][:3])} | {f3(sd['pub'][:3])} | {f3(sd['wide'][:3])} | {f3(cr[:3])} "
            f"| {yaw} | {ws} / {cr[6]:.3f} |"
        )
    S = np.array([r[0] for r in rows])
    print(
        "\n| growth per mm of σ | all-data | Alg. 1 | wide | CR bound | Alg. 1 / all-data | wide / all-data |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, fn, cfn in (
        ("std δx", lambda M: M[:, 0].std(), lambda cr: cr[0]),
        ("std δy", lambda M: M[:, 1].std(), lambda cr: cr[1]),
        ("std δz", lambda M: M[:, 2].std(), lambda cr: cr[2]),
        ("mean of std δx, δy", lambda M: M[:, :2].std(0).mean(), lambda cr: cr[:2].mean()),
        ("mean ‖δt‖", lambda M: np.linalg.norm(M[:, :3], axis=1).mean(), lambda cr: np.nan),
        ("std δyaw (° per mm)", lambda M: M[:, 5].std(), lambda cr: cr[5]),
        ("work-volume rms", lambda M: M[:, 6].mean(), lambda cr: cr[6]),
    ):
        a, i, w = (slope(S, [fn(r[1][key]) for r in rows]) for key in ("all", "pub", "wide"))
        c = slope(S, [cfn(r[2]) for r in rows])
        print(f"| {name} | {a:.4f} | {i:.4f} | {w:.4f} | {c:.4f} | {i / a:.3f} | {w / a:.3f} |")
    print("\n(paper: the growth of the translational std is reduced to 1/7 = 0.143)\n")


def fig10(nreal: int, budget: int) -> None:
    ks = [4, 5, 10, 15, 20, 30, 50, 75]
    R: dict[str, list] = {"pub": [], "wide": [], "all": []}
    crv = []
    for k in range(nreal):
        rng = np.random.default_rng(77 + k)
        cell = simulate_cell(rng=rng)
        c = cell.noisy_p_cam(0.001, rng)
        gt = GroundTruthVerifier(cell.T_base_camera)
        for key, pr in (
            ("pub", iterative_pool(c, cell.p_base, gt)),
            ("wide", iterative_pool(c, cell.p_base, gt, search="wide", budget=budget, seed=k)),
        ):
            R[key].append([errs(pr.H_history[n - 1], cell) for n in ks])
        R["all"].append([errs(scaled_svd_fit(c[:n], cell.p_base[:n]).T, cell) for n in ks])
        crv.append([crlb_row(pairs_crlb(cell.p_cam_true[:n], 0.001), cell) ** 2 for n in ks])
    H = {key: np.array(v) for key, v in R.items()}
    cr = np.sqrt(np.mean(crv, axis=0))  # rms over the realizations' pair orders
    print(f"## Fig. 10: error vs samples collected, σ = 1 mm ({nreal} realizations, wide budget {budget})\n")
    print(
        "| samples | std δx, δy, δz (mm): Alg. 1 | wide search | all-data on these | CR bound "
        "| std δyaw (°) Alg. 1 / wide | work-volume rms (mm) Alg. 1 / wide / all-data |"
    )
    print("|---|---|---|---|---|---|---|")
    for j, n in enumerate(ks):
        sd = {key: v[:, j].std(0) for key, v in H.items()}
        ws = " / ".join(f"{H[key][:, j, 6].mean():.3f}" for key in ("pub", "wide", "all"))
        print(
            f"| {n} | {f3(sd['pub'][:3])} | {f3(sd['wide'][:3])} | {f3(sd['all'][:3])} | {f3(cr[j, :3])} "
            f"| {sd['pub'][5]:.3f} / {sd['wide'][5]:.3f} | {ws} |"
        )
    print("\n(paper Fig. 10: std < 1 mm within 10 samples, 0.2 mm within 20)\n")


def budget_sweep(nreal: int, budgets: tuple[int, ...] = (4, 16, 64, 256)) -> None:
    R: dict[object, list] = {b: [] for b in ("all", "published", *budgets)}
    calls: dict[object, list] = {b: [] for b in ("published", *budgets)}
    secs: dict[object, float] = dict.fromkeys(("published", *budgets), 0.0)
    for k in range(nreal):
        rng = np.random.default_rng(4000 + k)
        cell = simulate_cell(rng=rng)
        c = cell.noisy_p_cam(0.001, rng)
        gt = GroundTruthVerifier(cell.T_base_camera)
        R["all"].append(errs(scaled_svd_fit(c, cell.p_base).T, cell))
        for b in ("published", *budgets):
            t0 = time.perf_counter()
            if b == "published":
                pr = iterative_pool(c, cell.p_base, gt)
            else:
                pr = iterative_pool(c, cell.p_base, gt, search="wide", budget=int(b), seed=k)
            secs[b] += time.perf_counter() - t0
            calls[b].append(pr.n_verified)
            R[b].append([errs(pr.H_history[19], cell), errs(pr.H, cell)])
    a = np.array(R["all"])
    cr = crlb_row(pairs_crlb(cell.p_cam_true, 0.001), cell)[:2].mean()
    print(f"## Wide search budget at σ = 1 mm, ground-truth verifier ({nreal} realizations)\n")
    print(
        "| search | std δx, δy at 75 / all-data's / CR bound (paper: growth 1/7 = 0.143) "
        "| std δx, δy, δz at 20 samples (paper ≤ 0.2) | std δx, δy, δz at 75 | work-volume rms at 75 (mm) "
        "| verifier calls per run | time per run (s) |"
    )
    print("|---|---|---|---|---|---|---|")
    for b in ("published", *budgets):
        v = np.array(R[b])
        sd = v[:, 1, :2].std(0).mean()
        name = "published" if b == "published" else f"wide, budget {b}"
        print(
            f"| {name} | {sd / a[:, :2].std(0).mean():.3f} / {sd / cr:.3f} | {f3(v[:, 0, :3].std(0))} "
            f"| {f3(v[:, 1, :3].std(0))} | {v[:, 1, 6].mean():.3f} | {np.mean(calls[b]):.0f} "
            f"| {secs[b] / nreal:.3f} |"
        )
    print(f"\n(all-data: std δx, δy, δz {f3(a[:, :3].std(0))} mm, work-volume rms {a[:, 6].mean():.3f} mm)\n")


def variants(nreal: int, budget: int) -> None:
    out: dict[str, list] = {}

    def add(name, H, cell):
        out.setdefault(name, []).append(errs(H, cell))

    for k in range(nreal):
        for model in ("isotropic", "ray"):
            rng = np.random.default_rng(5000 + k)
            cell = simulate_cell(rng=rng)
            c = cell.noisy_p_cam(0.001, rng, model=model)
            gt = GroundTruthVerifier(cell.T_base_camera)
            add(f"{model}: all-data (eqs. 10-12)", scaled_svd_fit(c, cell.p_base).T, cell)
            pr = iterative_pool(c, cell.p_base, gt, refit=3.0)
            add(f"{model}: Alg. 1, best replacement (default)", pr.H, cell)
            if model == "isotropic":
                seq = iterative_pool(c, cell.p_base, gt, inner="sequential")
                add(f"{model}: Alg. 1, listing's sequential loop", seq.H, cell)
                rad = iterative_pool(c, cell.p_base, gt, radius_cost(0.3))
                add(f"{model}: Alg. 1, radius cost r = 0.3 m (§4.2)", rad.H, cell)
                wide = iterative_pool(c, cell.p_base, gt, search="wide", budget=budget, seed=k)
                add(f"{model}: Alg. 1, wide search (budget {budget})", wide.H, cell)
            add(f"{model}: Alg. 1 + consensus refit (3σ)", pr.H_refit, cell)
        # 3 false measurements (10-30 mm), no ground truth: the consensus verifier of calibrate()
        rng = np.random.default_rng(9000 + k)
        cell = simulate_cell(rng=rng)
        c = cell.noisy_p_cam(0.001, rng)
        bad = rng.choice(75, 3, replace=False)
        d = rng.normal(size=(3, 3))
        c[bad] += d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.01, 0.03, (3, 1))
        add("outliers: all-data", scaled_svd_fit(c, cell.p_base).T, cell)
        add("outliers: robust `flange` (LMedS + inlier LS)", robust_point_fit(c, cell.p_base).T, cell)
        cv = ConsensusVerifier(c, cell.p_base)
        pc = iterative_pool(c, cell.p_base, cv, verifier_sees_count=True, refit=3.0)
        add("outliers: Alg. 1, consensus verifier", pc.H, cell)
        add("outliers: Alg. 1, consensus verifier + refit", pc.H_refit, cell)
        pw = iterative_pool(
            c, cell.p_base, cv, verifier_sees_count=True, refit=3.0, search="wide", budget=budget, seed=k
        )
        add(f"outliers: Alg. 1, consensus verifier, wide search (budget {budget})", pw.H, cell)
        add("outliers: Alg. 1, consensus verifier, wide search + refit", pw.H_refit, cell)
        for name, kw in (
            ("", {}),
            (f", wide search (budget {budget})", {"search": "wide", "budget": budget}),
        ):
            pr = iterative_pool(c, cell.p_base, cv, radius_cost(0.3), verifier_sees_count=True, seed=k, **kw)
            add(f"outliers: Alg. 1, consensus verifier, radius cost r = 0.3 m{name}", pr.H, cell)
        po = iterative_pool(c, cell.p_base, GroundTruthVerifier(cell.T_base_camera))
        add("outliers: Alg. 1, ground-truth verifier", po.H, cell)
    print(f"## Variants at σ = 1 mm ({nreal} realizations)\n")
    print(
        "| data: method | std δx, δy, δz (mm) | std δroll, δpitch, δyaw (°) | mean ‖δt‖ (mm) "
        "| work-volume rms (mm) |"
    )
    print("|---|---|---|---|---|")
    for name, v in out.items():
        v = np.array(v)
        print(
            f"| {name} | {f3(v[:, :3].std(0))} | {f3(v[:, 3:6].std(0))} | "
            f"{np.linalg.norm(v[:, :3], axis=1).mean():.3f} | {v[:, 6].mean():.3f} |"
        )
    print()


def icp_runs(sigma: float, nreal: int, budget: int) -> tuple[dict[str, np.ndarray], np.ndarray, int]:
    """All-data, the scan alone and Algorithm 1 (published / wide, bare and with eq. 21) against the
    ICP verifier of a simulated verification scan with per-point N(0, σ); errors as :func:`errs`,
    plus Alg. 1's Ĥ after 10 and 20 samples. Returns (errors by method, CR bound row, ICP failures)."""
    R: dict[str, list] = {}
    fails = 0
    for k in range(nreal):
        rng = np.random.default_rng(7000 + k + int(round(sigma * 1e5)))
        cell = simulate_cell(rng=rng)
        c = cell.noisy_p_cam(sigma, rng)
        v = scan_verifier(cell, sigma, rng)
        A = scaled_svd_fit(c, cell.p_base).T
        e_a = v(A)
        fails += e_a is None
        found = {"all-data": A, "scan alone (all-data + eq. 21)": A if e_a is None else A @ e_a}
        for name, kw in (("published", {}), (f"wide, budget {budget}", {"search": "wide", "budget": budget})):
            pr = iterative_pool(c, cell.p_base, v, seed=k, **kw)
            found[f"Alg. 1 {name}"] = pr.H
            found[f"Alg. 1 {name} + eq. 21"] = pr.H if pr.H_compensated is None else pr.H_compensated
            found[f"Alg. 1 {name}, 10 samples"] = pr.H_history[9]
            found[f"Alg. 1 {name}, 20 samples"] = pr.H_history[19]
        for name, H in found.items():
            R.setdefault(name, []).append(errs(H, cell))
    return (
        {key: np.array(x) for key, x in R.items()},
        crlb_row(pairs_crlb(cell.p_cam_true, sigma), cell),
        fails,
    )


def icp(sigmas: tuple[float, ...], nreal: int, budget: int) -> None:
    runs = {s: icp_runs(s * 1e-3, nreal, budget) for s in sigmas}
    print(
        f"## Realistic verifier (eq. 13): ICP of the flange model against a simulated verification scan, "
        f"per-point σ = the pairs' σ ({nreal} realizations per level)\n"
    )
    print("| σ (mm) | method | std δx, δy, δz (mm) | std δroll, δpitch, δyaw (°) | work-volume rms (mm) |")
    print("|---|---|---|---|---|")
    for s, (R, cr, fails) in runs.items():
        for name, v in R.items():
            print(
                f"| {s:g} | {name} | {f3(v[:, :3].std(0))} | {f3(v[:, 3:6].std(0))} | {v[:, 6].mean():.3f} |"
            )
        print(f"| {s:g} | CR bound, pairs only | {f3(cr[:3])} | {f3(cr[3:6])} | {cr[6]:.3f} (√E rms²) |")
        if fails:
            print(f"| {s:g} | ICP failed on the all-data Ĥ in {fails} of {nreal} | | | |")
    S = np.array(sigmas, float)
    names = [n for n in next(iter(runs.values()))[0] if "samples" not in n]
    print("\n| growth per mm of σ | " + " | ".join(names) + " | CR bound |")
    print("|---" * (len(names) + 2) + "|")
    for label, fn, ci in (
        ("mean of std δx, δy", lambda v: v[:, :2].std(0).mean(), slice(0, 2)),
        ("std δz", lambda v: v[:, 2].std(), slice(2, 3)),
        ("work-volume rms", lambda v: v[:, 6].mean(), slice(6, 7)),
    ):
        g = [slope(S, [fn(runs[s][0][n]) for s in sigmas]) for n in names]
        c = slope(S, [runs[s][1][ci].mean() for s in sigmas])
        print(f"| {label} | " + " | ".join(f"{x:.3f}" for x in g) + f" | {c:.3f} |")
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--full", action="store_true", help="all 50 noise levels x 100 realizations (paper)")
    ap.add_argument("--realizations", type=int, default=None, help="per noise level (default 20, --full 100)")
    ap.add_argument("--budget", type=int, default=64, help="wide search: 4-subsets per new pair (default 64)")
    ap.add_argument("--icp-realizations", type=int, default=10, help="per level in the ICP section")
    ap.add_argument("--icp-budget", type=int, default=16, help="wide search budget with the ICP verifier")
    ap.add_argument("--only", choices=SECTIONS, action="append", help="run only these (icp: only so)")
    ap.add_argument("--workers", type=int, default=None, help="fig9: local Dask workers (0: in this process)")
    ap.add_argument("--scheduler", default=None, help="fig9: an existing Dask scheduler address")
    a = ap.parse_args()
    if a.budget <= 0 or a.icp_budget <= 0 or a.icp_realizations <= 0 or (a.realizations or 1) <= 0:
        ap.error("budgets and realization counts must be positive integers")
    sigmas = PAPER_SIGMAS if a.full else np.array([0.2, 1, 2, 4, 7, 10]) * 1e-3
    nreal = a.realizations or (100 if a.full else 20)
    run = set(a.only or SECTIONS[:-1])  # the ICP section (~13 min) only on request
    t0 = time.time()
    if "fig9" in run:
        from weldcell.sdk.scale.cluster import ClusterOptions

        fig9(
            sigmas,
            nreal,
            a.budget,
            ClusterOptions(workers=None if a.scheduler else a.workers, scheduler=a.scheduler),
        )
    if "fig10" in run:
        fig10(max(nreal, 100), a.budget)
    if "budget" in run:
        budget_sweep(max(nreal, 50))
    if "variants" in run:
        variants(max(nreal, 50), a.budget)
    if "icp" in run:
        icp((1.0, 2.0, 5.0), a.icp_realizations, a.icp_budget)
    print(f"({time.time() - t0:.1f} s)")


if __name__ == "__main__":
    main()
