"""§3.1 simulation protocol: all-data SVD (eqs. 9-12) vs the iterative method (Algorithm 1), Figs. 9-10.

    /work/venv/bin/python benchmarks/handeye_simulation.py            # 6 noise levels x 20 realizations
    /work/venv/bin/python benchmarks/handeye_simulation.py --full     # 50 levels (0.2..10 mm) x 100

Protocol (paper §3.1, details from the authors' published scripts, see simulation.py): eq. 19 camera,
75 flange centres on the 5 x 5 x 3 grid x 0.45-0.75, y ±0.15, z 0.2-0.4 m, noise N(0, σ) added to
the camera points only (eq. 20), a fresh noise draw and a fresh pair order per realization, all-data
= eqs. 10-12 without the scale c on all 75 pairs, Algorithm 1 = a 4-pair pool grown over all 75
pairs with the ground-truth verifier e = inv(Ĥ) H_true, cost ‖δt‖₂ and e_required = 0 (so the pool
sees every pair, as in Figs. 9-10). Errors: δt, δrpy of inv(Ĥ) H_true (translation = displacement
of the camera origin, the paper's measure) and, beside it, the RMS displacement of the 75 grid points
(the error in the work volume).

Prints markdown tables: (1) std of the errors vs σ and the growth rates (slope of std vs σ);
(2) std vs number of samples at σ = 1 mm (Fig. 10); (3) variants at σ = 1 mm: noise model, the
listing's sequential inner loop, the radius cost, the consensus refit, and 3 outliers with the
consensus verifier (no ground truth).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from weldcell.plugins.handeye.iterative import iterative_pool
from weldcell.plugins.handeye.pointfit import robust_point_fit, scaled_svd_fit
from weldcell.plugins.handeye.simulation import PAPER_SIGMAS, simulate_cell, workspace_error
from weldcell.plugins.handeye.verification import (
    ConsensusVerifier,
    GroundTruthVerifier,
    error_components,
    radius_cost,
)
from weldcell.sdk.geometry import invert


def errs(H: np.ndarray, cell) -> np.ndarray:
    """[δx, δy, δz (mm), δroll, δpitch, δyaw (°), workspace rms (mm)] of H against the truth."""
    e = error_components(invert(H) @ cell.T_base_camera)
    return np.r_[
        np.array([e["dx"], e["dy"], e["dz"]]) * 1e3,
        np.degrees([e["droll"], e["dpitch"], e["dyaw"]]),
        workspace_error(H, cell.T_base_camera, cell.p_cam_true) * 1e3,
    ]


def f3(v, fmt="{:.3f}") -> str:
    return ", ".join(fmt.format(x) for x in v)


def fig9(sigmas: np.ndarray, nreal: int) -> None:
    rows = []
    for sigma in sigmas:
        A, It = [], []
        for k in range(nreal):
            rng = np.random.default_rng(1000 * k + int(round(sigma * 1e5)))
            cell = simulate_cell(rng=rng)
            c = cell.noisy_p_cam(sigma, rng)
            A.append(errs(scaled_svd_fit(c, cell.p_base).T, cell))
            It.append(errs(iterative_pool(c, cell.p_base, GroundTruthVerifier(cell.T_base_camera)).H, cell))
        A, It = np.array(A), np.array(It)
        rows.append((sigma * 1e3, A, It))
    print(f"## Fig. 9: error vs noise (75 poses, {nreal} realizations per level)\n")
    print(
        "| σ (mm) | all-data std δx, δy, δz (mm) | Alg. 1 std δx, δy, δz (mm) | all-data std δr, δp, δy (°) "
        "| Alg. 1 std δr, δp, δy (°) | mean ‖δt‖ all / Alg. 1 (mm) | work-volume rms all / Alg. 1 (mm) |"
    )
    print("|---|---|---|---|---|---|---|")
    for s, A, It in rows:
        na, ni = np.linalg.norm(A[:, :3], axis=1).mean(), np.linalg.norm(It[:, :3], axis=1).mean()
        print(
            f"| {s:.1f} | {f3(A[:, :3].std(0))} | {f3(It[:, :3].std(0))} | {f3(A[:, 3:6].std(0))} "
            f"| {f3(It[:, 3:6].std(0))} | {na:.3f} / {ni:.3f} "
            f"| {A[:, 6].mean():.3f} / {It[:, 6].mean():.3f} |"
        )
    S = np.array([r[0] for r in rows])

    def slope(y) -> float:
        return float(np.polyfit(S, np.asarray(y), 1)[0])

    print("\n| growth per mm of σ | all-data | Alg. 1 | ratio Alg. 1 / all-data |")
    print("|---|---|---|---|")
    for name, fn in (
        ("std δx", lambda M: M[:, 0].std()),
        ("std δy", lambda M: M[:, 1].std()),
        ("std δz", lambda M: M[:, 2].std()),
        ("mean of std δx, δy", lambda M: M[:, :2].std(0).mean()),
        ("mean ‖δt‖", lambda M: np.linalg.norm(M[:, :3], axis=1).mean()),
        ("std δyaw (° per mm)", lambda M: M[:, 5].std()),
        ("work-volume rms", lambda M: M[:, 6].mean()),
    ):
        a, i = slope([fn(r[1]) for r in rows]), slope([fn(r[2]) for r in rows])
        print(f"| {name} | {a:.4f} | {i:.4f} | {i / a:.3f} |")
    print("\n(paper: the growth of the translational std is reduced to 1/7 = 0.143)\n")


def fig10(nreal: int) -> None:
    ks = [4, 5, 10, 15, 20, 30, 50, 75]
    hist = []
    for k in range(nreal):
        rng = np.random.default_rng(77 + k)
        cell = simulate_cell(rng=rng)
        c = cell.noisy_p_cam(0.001, rng)
        pr = iterative_pool(c, cell.p_base, GroundTruthVerifier(cell.T_base_camera))
        hist.append([errs(pr.H_history[n - 1], cell) for n in ks])
    hist = np.array(hist)
    print(f"## Fig. 10: Algorithm 1 vs samples collected, σ = 1 mm ({nreal} realizations)\n")
    print("| samples | std δx, δy, δz (mm) | std δroll, δpitch, δyaw (°) | work-volume rms (mm) |")
    print("|---|---|---|---|")
    for j, n in enumerate(ks):
        sd = hist[:, j].std(0)
        print(f"| {n} | {f3(sd[:3])} | {f3(sd[3:6])} | {hist[:, j, 6].mean():.3f} |")
    print("\n(paper Fig. 10: std < 1 mm within 10 samples, 0.2 mm within 20)\n")


def variants(nreal: int) -> None:
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
        pc = iterative_pool(
            c, cell.p_base, ConsensusVerifier(c, cell.p_base), verifier_sees_count=True, refit=3.0
        )
        add("outliers: Alg. 1, consensus verifier", pc.H, cell)
        add("outliers: Alg. 1, consensus verifier + refit", pc.H_refit, cell)
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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--full", action="store_true", help="all 50 noise levels x 100 realizations (paper)")
    ap.add_argument("--realizations", type=int, default=None)
    a = ap.parse_args()
    sigmas = PAPER_SIGMAS if a.full else np.array([0.2, 1, 2, 4, 7, 10]) * 1e-3
    nreal = a.realizations or (100 if a.full else 20)
    t0 = time.time()
    fig9(sigmas, nreal)
    fig10(max(nreal, 100))
    variants(max(nreal, 50))
    print(f"({time.time() - t0:.1f} s)")


if __name__ == "__main__":
    main()
