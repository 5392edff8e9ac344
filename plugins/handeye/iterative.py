"""The iterative flange calibration of Algorithm 1: a pool of four point pairs kept optimal under a
verification cost, grown online one new pair at a time.

``search="published"`` is the listing's loop (the four single replacements per new pair).
``search="wide"`` adds, per new pair, up to ``budget`` further 4-subsets that contain it (all of
them while there are at most ``budget``, else a seeded random sample) and the four replacements of
the best pool found so far, while the published pool is carried along: its result is never worse
under the verifier than the published loop's on the same data. Near-collinear subsets (robot-side
s2/s1 < 0.05) are not tried by the wide search: their rotation about the line is noise, and a weak
verifier (the consensus one with few pairs seen) can accept them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import combinations
from math import comb
from typing import Literal

import numpy as np
from weldcell.plugins.handeye.verification import Cost, Verifier, compensate, translation_cost
from weldcell.sdk.errors import DataError
from weldcell.sdk.pointfit import rigid_fit_batch, scaled_svd_fit


@dataclass
class PoolResult:
    """Algorithm 1's output. ``H`` = Ĥ_optimal, ``e`` = e_optimal (None: +inf), ``pool`` = indices of
    the four pairs kept, ``history`` = cost after each collected pair (index k = pairs seen - 1),
    ``H_history`` = Ĥ_optimal after each pair, ``n_used`` = pairs consumed before stopping,
    ``n_verified`` = verifier calls made.
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
    timed_out: bool = False
    H_refit: np.ndarray | None = None
    refit_inliers: list[int] | None = None
    n_verified: int = 0


@dataclass
class _State:
    """A pool: pair indices, its fit Ĥ, verifier error e and cost."""

    pool: list[int]
    H: np.ndarray
    e: np.ndarray | None
    cost: float


class _Scorer:
    """Fits and verifies candidate pools, counting verifier calls."""

    def __init__(
        self, src: np.ndarray, dst: np.ndarray, verifier: Callable, cost: Cost, sees_count: bool
    ) -> None:
        self.src, self.dst, self.verifier, self.cost, self.sees = src, dst, verifier, cost, sees_count
        self.calls = 0

    def verify(self, H: np.ndarray, seen: int) -> np.ndarray | None:
        self.calls += 1
        return self.verifier(H, seen) if self.sees else self.verifier(H)

    def best_of(self, cand: np.ndarray, seen: int) -> _State:
        """The lowest-cost pool among the rows of ``cand`` (m, pool_size) (first one on ties)."""
        Hs = rigid_fit_batch(self.src[cand], self.dst[cand])
        es = [self.verify(H, seen) for H in Hs]
        costs = np.array([self.cost(e) for e in es])
        i = int(np.argmin(costs))
        return _State([int(p) for p in cand[i]], Hs[i], es[i], float(costs[i]))

    def rescore(self, s: _State, seen: int) -> _State:
        """``s`` re-verified (the consensus reference moved with the new data)."""
        e = self.verify(s.H, seen)
        return _State(s.pool, s.H, e, self.cost(e))


def _check_args(n: int, pool_size: int, inner: str, search: str, budget: int) -> None:
    if inner not in ("best", "sequential"):
        raise DataError(f"unknown inner loop '{inner}'", "use inner='best' or inner='sequential'")
    if search not in ("published", "wide"):
        raise DataError(f"unknown search '{search}'", "use search='published' or search='wide'")
    if isinstance(budget, bool) or not isinstance(budget, int | np.integer) or budget <= 0:
        raise DataError(f"budget = {budget!r}", "give budget as a positive integer (4-subsets per new pair)")
    if not isinstance(pool_size, int | np.integer) or pool_size < 3:
        raise DataError(
            f"pool_size = {pool_size!r}; a rigid fit needs 3 pairs", "use pool_size >= 3 (paper: 4)"
        )
    if n < pool_size:
        raise DataError(
            f"{n} pairs but pool_size = {pool_size}; Algorithm 1 starts from pool_size pairs",
            "collect more robot poses or lower pool_size",
        )


def _published_step(s: _State, nxt: int, sc: _Scorer, inner: str, events: list[str]) -> _State:
    """Steps 6-15 for the new pair ``nxt``: single replacements of the pool's slots."""
    k = len(s.pool)
    if inner == "best":
        cand = np.array([s.pool[:i] + [nxt] + s.pool[i + 1 :] for i in range(k)])
        c = sc.best_of(cand, nxt + 1)
        if c.cost < s.cost:
            events.append(f"pair {nxt} replaced slot {c.pool.index(nxt)}: cost {c.cost:.3g}")
            return c
        return s
    for i in range(k):  # steps 6-15 as listed
        c = sc.best_of(np.array([s.pool[:i] + [nxt] + s.pool[i + 1 :]]), nxt + 1)
        if c.cost < s.cost:  # step 9's test, else step 10 undoes the replacement
            s = c
            events.append(f"pair {nxt} replaced slot {i}: cost {s.cost:.3g}")
    return s


def _subsets_with(nxt: int, k: int, budget: int, rng: np.random.Generator) -> np.ndarray:
    """Up to ``budget`` k-subsets of pairs 0..nxt that contain ``nxt``: all of them while there are at
    most ``budget``, else ``budget`` seeded random draws (duplicates dropped)."""
    if comb(nxt, k - 1) <= budget:
        others = np.array(list(combinations(range(nxt), k - 1)), int).reshape(-1, k - 1)
    else:
        others = np.unique(np.sort(np.argsort(rng.random((budget, nxt)), 1)[:, : k - 1], 1), axis=0)
    return np.column_stack([others, np.full(len(others), nxt)])


#: the wide search skips subsets with s2/s1 below this (near-collinear: rotation about the line free)
MIN_SPREAD = 0.05


def _spread(P: np.ndarray) -> np.ndarray:
    """s2/s1 of the centred points of each subset (m, k, 3): ~0 for collinear subsets."""
    s = np.linalg.svd(P - P.mean(1, keepdims=True), compute_uv=False)
    return s[:, 1] / np.maximum(s[:, 0], 1e-300)


def _wide_step(
    best: _State, nxt: int, sc: _Scorer, budget: int, rng: np.random.Generator, events: list[str]
) -> _State:
    """The best of the four replacements of ``best`` and the subsets of :func:`_subsets_with`."""
    k = len(best.pool)
    repl = [best.pool[:i] + [nxt] + best.pool[i + 1 :] for i in range(k)]
    cand = np.unique(np.sort(np.vstack([repl, _subsets_with(nxt, k, budget, rng)]), 1), axis=0)
    cand = cand[_spread(sc.dst[cand]) >= MIN_SPREAD]
    if not len(cand):
        return best
    c = sc.best_of(cand, nxt + 1)
    if c.cost < best.cost:
        events.append(f"pair {nxt}: wide search took pool {c.pool}: cost {c.cost:.3g}")
        return c
    return best


@dataclass(frozen=True)
class PoolOptions:
    """Algorithm 1's options (see :func:`iterative_pool` for each one's meaning; paper defaults).

    The typed form of :func:`iterative_pool`'s keywords, for :func:`run_pool` (as Open3D passes an
    ``ICPConvergenceCriteria`` rather than loose numbers)."""

    e_required: float = 0.0
    k_max: int = 10_000
    pool_size: int = 4
    verifier_sees_count: bool = False
    inner: Literal["best", "sequential"] = "best"
    refit: float | None = None
    refit_floor: float = 0.0
    search: Literal["published", "wide"] = "published"
    budget: int = 64
    seed: int | np.random.Generator | None = 0
    time_limit: float | None = None
    max_verifications: int | None = None


# parameters: Algorithm 1's documented options as keywords with the paper's defaults (the public call
# form; they are gathered into a PoolOptions and run by run_pool); long docstring
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
    search: Literal["published", "wide"] = "published",
    budget: int = 64,
    seed: int | np.random.Generator | None = 0,
    time_limit: float | None = None,
    max_verifications: int | None = None,
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

    ``search="wide"`` (an improvement, not in the paper): per new pair also up to ``budget``
    pool-size subsets containing it (exhaustive while few enough, else random from ``seed``) and the
    replacements of the best pool so far are verified (near-collinear ones skipped); the published
    pool runs alongside, so the returned cost is never above the published loop's. Verifier calls
    per new pair ≤ ``budget`` + 2·``pool_size`` (+2 with ``verifier_sees_count``).

    ``refit`` (an improvement, not in the paper): after the loop, the residuals of every pair seen under
    Ĥ_optimal give a robust σ = 1.4826·sqrt(median r²); pairs with r <= max(refit·σ, refit_floor)
    are refitted together by eqs. 10-12 (``H_refit``), twice. The pool then acts as a RANSAC
    hypothesis chosen by the verifier, and the final transform averages the noise of all consistent
    pairs instead of four (§3.1 study in docs/methods/hand-eye.md).

    ``max_verifications``: no new pair is taken once the verifier has been called this many times
    (``timed_out``; the pool found so far is returned), so a slow verifier cannot hold a run
    indefinitely; the cut falls at the same pair on every run. ``time_limit`` (s) is the same cut by
    wall-clock time, the one deliberate exception to repeatability: where it cuts depends on the
    host's speed and load, so it is off by default.
    """
    options = PoolOptions(
        e_required=e_required,
        k_max=k_max,
        pool_size=pool_size,
        verifier_sees_count=verifier_sees_count,
        inner=inner,
        refit=refit,
        refit_floor=refit_floor,
        search=search,
        budget=budget,
        seed=seed,
        time_limit=time_limit,
        max_verifications=max_verifications,
    )
    return run_pool(src, dst, verifier, cost, options)


def run_pool(
    src: np.ndarray,
    dst: np.ndarray,
    verifier: Verifier | Callable[[np.ndarray, int], np.ndarray | None],
    cost: Cost = translation_cost,
    options: PoolOptions | None = None,
) -> PoolResult:
    """Algorithm 1 (:func:`iterative_pool`) with its options as one :class:`PoolOptions`."""
    o = options or PoolOptions()
    src = np.asarray(src, float).reshape(-1, 3)
    dst = np.asarray(dst, float).reshape(-1, 3)
    _check_args(len(src), o.pool_size, o.inner, o.search, o.budget)
    run = _PoolRun(_Scorer(src, dst, verifier, cost, o.verifier_sees_count), o)
    while run.takes_another(len(src)):
        run.add_pair()
    return run.result()


class _PoolRun:
    """One run of Algorithm 1: the published pool, the best pool (the same unless ``search="wide"``),
    the per-pair history, and the stop conditions."""

    def __init__(self, sc: _Scorer, o: PoolOptions) -> None:
        self.sc, self.o = sc, o
        self.rng = np.random.default_rng(o.seed)
        # steps 1-3: the first pool_size pairs form S_0
        self.pub = self.best = sc.best_of(np.arange(o.pool_size)[None], o.pool_size)
        self.history = [np.inf] * (o.pool_size - 1) + [self.best.cost]
        self.H_hist = [np.full((4, 4), np.nan)] * (o.pool_size - 1) + [self.best.H]
        self.k = 0
        self.nxt = o.pool_size
        self.events: list[str] = []
        self.t0, self.timed_out = time.monotonic(), False

    def takes_another(self, n: int) -> bool:
        """Step 4's test, then the time and verification limits (``timed_out``, with an event)."""
        o = self.o
        if not (self.best.cost > o.e_required and self.k <= o.k_max and self.nxt < n):
            return False
        if o.time_limit is not None and time.monotonic() - self.t0 > o.time_limit:
            self.events.append(f"time limit {o.time_limit:g} s reached after {self.nxt} pairs")
        elif o.max_verifications is not None and self.sc.calls >= o.max_verifications:
            self.events.append(f"verification limit {o.max_verifications} reached after {self.nxt} pairs")
        else:
            return True
        self.timed_out = True
        return False

    def add_pair(self) -> None:
        """Steps 5-15 for the next pair (and the wide search's subsets), then its history entry."""
        o, sc, nxt = self.o, self.sc, self.nxt
        if o.verifier_sees_count and np.isfinite(self.best.cost):
            self.pub = sc.rescore(self.pub, nxt + 1)
            self.best = self.pub if self.best.pool == self.pub.pool else sc.rescore(self.best, nxt + 1)
        self.pub = _published_step(self.pub, nxt, sc, o.inner, self.events)
        if o.search == "wide":
            wide = _wide_step(self.best, nxt, sc, o.budget, self.rng, self.events)
            self.best = min(self.best, self.pub, wide, key=lambda s: s.cost)
        else:
            self.best = self.pub
        self.history.append(self.best.cost)
        self.H_hist.append(self.best.H)
        self.nxt += 1
        self.k += 1

    def result(self) -> PoolResult:
        """The pool found, with the consensus refit when asked."""
        best, o, nxt = self.best, self.o, self.nxt
        H_refit = refit_idx = None
        if o.refit is not None:
            H_refit, refit_idx = _consensus_refit(
                best.H, self.sc.src[:nxt], self.sc.dst[:nxt], o.refit, o.refit_floor
            )
        return PoolResult(
            H=best.H,
            e=best.e,
            cost=best.cost,
            pool=best.pool,
            history=np.asarray(self.history),
            H_history=np.asarray(self.H_hist),
            n_used=nxt,
            converged=bool(best.cost <= o.e_required),
            H_compensated=None if best.e is None else compensate(best.H, best.e),
            events=self.events,
            timed_out=self.timed_out,
            H_refit=H_refit,
            refit_inliers=refit_idx,
            n_verified=self.sc.calls,
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
