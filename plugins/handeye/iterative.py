"""The iterative flange calibration of Algorithm 1: a pool of four point pairs kept optimal under a
verification cost, grown online one new pair at a time."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from weldcell.plugins.handeye.pointfit import rigid_fit_batch
from weldcell.plugins.handeye.verification import Cost, Verifier, compensate, translation_cost
from weldcell.sdk.errors import DataError


@dataclass
class PoolResult:
    """Algorithm 1's output. ``H`` = Ĥ_optimal, ``e`` = e_optimal (None: +inf), ``pool`` = indices of
    the four pairs kept, ``history`` = cost after each collected pair (index k = pairs seen - 1),
    ``H_history`` = Ĥ_optimal after each pair, ``n_used`` = pairs consumed before stopping."""

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


def iterative_pool(
    src: np.ndarray,
    dst: np.ndarray,
    verifier: Verifier | Callable[[np.ndarray, int], np.ndarray | None],
    cost: Cost = translation_cost,
    e_required: float = 0.0,
    k_max: int = 10_000,
    pool_size: int = 4,
    verifier_sees_count: bool = False,
) -> PoolResult:
    """Run Algorithm 1 over pairs ``src[i] -> dst[i]`` in the order given (the collection order).

    Steps 1-3: the first ``pool_size`` pairs form S_0; Ĥ from eqs. 10-12, e_icp from ``verifier(H)``.
    Steps 4-16: while ``cost(e_optimal) > e_required`` and ``k <= k_max`` a new pair is taken; each of
    the four replacements is tried and the best one is kept if it lowers the cost (the paper's inner
    loop tries them in turn; taking the best of the four gives the same pool whenever one replacement
    wins and never puts the new pair into two slots). With ``verifier_sees_count`` the verifier is
    called as ``verifier(H, n_seen)`` (used by the consensus verifier that grows with the data).
    """
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
        cand = np.array([pool[:i] + [nxt] + pool[i + 1 :] for i in range(pool_size)])
        Hs = rigid_fit_batch(src[cand], dst[cand])
        es = [verify(Hc, nxt + 1) for Hc in Hs]
        costs = np.array([cost(ec) for ec in es])
        if verifier_sees_count and np.isfinite(best):
            best = cost(e := verify(H, nxt + 1))  # the reference moved with the new data
        i = int(np.argmin(costs))
        if costs[i] < best:
            pool = list(cand[i])
            H, e, best = Hs[i], es[i], float(costs[i])
            events.append(f"pair {nxt} replaced slot {i}: cost {best:.3g}")
        history.append(best)
        H_hist.append(H)
        nxt += 1
        k += 1
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
    )
