"""The iterative flange calibration of Algorithm 1: a pool of four point pairs kept optimal under a
verification cost, grown online one new pair at a time."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from weldcell.plugins.handeye.pointfit import rigid_fit_batch, scaled_svd_fit
from weldcell.plugins.handeye.verification import Cost, Verifier, compensate, translation_cost
from weldcell.sdk.errors import DataError


@dataclass
class PoolResult:
    """Algorithm 1's output. ``H`` = Ĥ_optimal, ``e`` = e_optimal (None: +inf), ``pool`` = indices of
    the four pairs kept, ``history`` = cost after each collected pair (index k = pairs seen - 1),
    ``H_history`` = Ĥ_optimal after each pair, ``n_used`` = pairs consumed before stopping.
    With ``refit``: ``H_refit`` = least squares (eqs. 10-12) on every pair seen that agrees with Ĥ_optimal,
    ``refit_inliers`` = their indices."""

    H: np.ndarray
    e: np.ndarray | None
    cost: float
    pool: list[int]
    history: np.ndarray
    H_history: np.ndarray
    n_used: int
    converged: bool
    H_compensated: np.ndarray | None = None
    events: list[str] = field(default_factory=list)
    H_refit: np.ndarray | None = None
    refit_inliers: list[int] | None = None


def iterative_pool(
    src: np.ndarray,
    dst: np.ndarray,
    verifier: Verifier | Callable[[np.ndarray, int], np.ndarray | None],
    cost: Cost = translation_cost,
    e_required: float = 0.0,
    k_max: int = 10_000,
    pool_size: int = 4,
    verifier_sees_count: bool = False,
    inner: Literal["best", "sequential"] = "best",
    refit: float | None = None,
    refit_floor: float = 0.0,
) -> PoolResult:
    """Run Algorithm 1 over pairs ``src[i] -> dst[i]`` in the order given (the collection order).

    Steps 1-3: the first ``pool_size`` pairs form S_0; Ĥ from eqs. 10-12, e_icp from ``verifier(H)``.
    Steps 4-16: while ``cost(e_optimal) > e_required`` and ``k <= k_max`` a new pair is taken; each of
    the four replacements is tried and the best one is kept if it lowers the cost (the paper's inner
    loop tries them in turn; taking the best of the four gives the same pool whenever one replacement
    wins and never puts the new pair into two slots). With ``verifier_sees_count`` the verifier is
    called as ``verifier(H, n_seen)`` (used by the consensus verifier that grows with the data).

    ``inner="sequential"`` runs steps 6-15 literally as listed: slot i = 1..4 in turn, each accepted
    replacement kept before the next slot is tried, so the new pair can end up in several slots
    (the pool then holds fewer than four distinct pairs, weighting the new one more).

    ``refit`` (an improvement, not in the paper): after the loop, the residuals of every pair seen under
    Ĥ_optimal give a robust σ = 1.4826·sqrt(median r²); pairs with r <= max(refit·σ, refit_floor)
    are refitted together by eqs. 10-12 (``H_refit``), twice. The pool then acts as a RANSAC
    hypothesis chosen by the verifier, and the final transform averages the noise of all consistent
    pairs instead of four (§3.1 study in docs/methods/hand-eye.md).
    """
    if inner not in ("best", "sequential"):
        raise DataError(f"unknown inner loop '{inner}'", "use inner='best' or inner='sequential'")
    src = np.asarray(src, float).reshape(-1, 3)
    dst = np.asarray(dst, float).reshape(-1, 3)
    n = len(src)
    if n < pool_size:
        raise DataError(f"{n} pairs; Algorithm 1 starts from {pool_size}", "collect more robot poses")

    def verify(H: np.ndarray, seen: int):
        return verifier(H, seen) if verifier_sees_count else verifier(H)

    pool = list(range(pool_size))
    H = rigid_fit_batch(src[None, pool], dst[None, pool])[0]
    e = verify(H, pool_size)
    best = cost(e)
    history = [np.inf] * (pool_size - 1) + [best]
    H_hist = [np.full((4, 4), np.nan)] * (pool_size - 1) + [H]
    k = 0
    nxt = pool_size
    events: list[str] = []
    while best > e_required and k <= k_max and nxt < n:
        if verifier_sees_count and np.isfinite(best):
            best = cost(e := verify(H, nxt + 1))  # the reference moved with the new data
        if inner == "best":
            cand = np.array([pool[:i] + [nxt] + pool[i + 1 :] for i in range(pool_size)])
            Hs = rigid_fit_batch(src[cand], dst[cand])
            es = [verify(Hc, nxt + 1) for Hc in Hs]
            costs = np.array([cost(ec) for ec in es])
            i = int(np.argmin(costs))
            if costs[i] < best:
                pool = list(cand[i])
                H, e, best = Hs[i], es[i], float(costs[i])
                events.append(f"pair {nxt} replaced slot {i}: cost {best:.3g}")
        else:
            for i in range(pool_size):  # steps 6-15 as listed
                trial = pool[:i] + [nxt] + pool[i + 1 :]
                Hc = rigid_fit_batch(src[None, trial], dst[None, trial])[0]
                ec = verify(Hc, nxt + 1)
                if cost(ec) < best:  # step 9's test, else step 10 undoes the replacement
                    pool, H, e, best = trial, Hc, ec, cost(ec)
                    events.append(f"pair {nxt} replaced slot {i}: cost {best:.3g}")
        history.append(best)
        H_hist.append(H)
        nxt += 1
        k += 1
    H_refit = refit_idx = None
    if refit is not None:
        H_refit, refit_idx = _consensus_refit(H, src[:nxt], dst[:nxt], refit, refit_floor)
    return PoolResult(
        H=H,
        e=e,
        cost=best,
        pool=[int(p) for p in pool],
        history=np.asarray(history),
        H_history=np.asarray(H_hist),
        n_used=nxt,
        converged=bool(best <= e_required),
        H_compensated=None if e is None else compensate(H, e),
        events=events,
        H_refit=H_refit,
        refit_inliers=refit_idx,
    )


def _consensus_refit(
    H: np.ndarray, src: np.ndarray, dst: np.ndarray, n_sigma: float, floor: float
) -> tuple[np.ndarray, list[int]]:
    """Eqs. 10-12 on the pairs within ``max(n_sigma·σ, floor)`` of ``H`` (σ robust, from the median)."""
    T, keep = H, np.ones(len(src), bool)
    for _ in range(2):
        r = np.linalg.norm(src @ T[:3, :3].T + T[:3, 3] - dst, axis=1)
        thr = max(n_sigma * 1.4826 * float(np.sqrt(np.median(r**2))), floor)
        keep = r <= thr
        if keep.sum() < 3:
            return H, [int(i) for i in np.flatnonzero(keep)]
        T = scaled_svd_fit(src[keep], dst[keep]).T
    return T, [int(i) for i in np.flatnonzero(keep)]
