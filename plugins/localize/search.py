"""Pose search for the localization (paper 002, §IV, "Optimization").

* :func:`paper_seeds`: the paper's seeds, within ±50 mm and ±20° of the edges' centre of mass and
  orientation (the pose that maps the template outline's centre and principal axis onto the edges').
* :func:`powell` / :class:`SeedRunner`: Powell's method (scipy) from each seed, on eq. (3) (through the
  Voronoi labels of the template's distance field) or on a robust loss of the same distances;
  :func:`polish`: the winner refined by Powell on the exact eq. (3); the seeds run in a reused process
  pool, or serially when the pool would cost more than it saves (measured: the first seed's run time
  against the pool's round trip).
* :func:`global_search`: a seed-free search of the whole window: every rotation step and translation step of
  the window scored at once on the template's distance transform (truncated distance), then the best
  distinct cells refined on a finer grid. Its result does not depend on lucky seeds.
"""

from __future__ import annotations

import atexit
import math
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from .cost import DistanceField, Eq3, Eq3Near, Segments, distances, field_for
from .pose import rot2, wrap


@dataclass
class SearchResult:
    pose: np.ndarray
    cost: float
    nfev: int = 0
    seed: int = -1
    merged: bool = False


def _principal_angle(xy: np.ndarray) -> tuple[np.ndarray, float, float]:
    c = xy.mean(axis=0)
    w, v = np.linalg.eigh(np.cov((xy - c).T))
    return c, math.atan2(v[1, 1], v[0, 1]), float(w[1] / max(w[0], 1e-18))


def paper_seeds(
    outline_xy: np.ndarray,
    center: np.ndarray,
    xy: np.ndarray,
    n: int,
    window_xy: float,
    window_theta: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """n seeds (x, y, theta): the first maps the outline's centre of mass and principal axis onto the edge
    points'; the others are drawn uniformly within ±window_xy, ±window_theta of it."""
    c_t, a_t, _ = _principal_angle(outline_xy)
    c_e, a_e, elong = _principal_angle(xy)
    dth = float(wrap(2 * (a_e - a_t)) / 2)  # an axis has no sign: modulo pi
    if elong < 1.5 or abs(dth) > window_theta:  # a round or poorly seen outline has no reliable axis
        dth = 0.0
    t0 = c_e - (rot2(dth) @ (c_t - center) + center)
    base = np.array([t0[0], t0[1], dth])
    seeds = [base]
    for _ in range(n - 1):
        seeds.append(base + rng.uniform(-1, 1, 3) * np.array([window_xy, window_xy, window_theta]))
    return np.array(seeds)


def robust_cost(d: np.ndarray, loss: str, scale: float) -> float:
    """Sum of the loss of the distances: 'linear' is eq. (3); 'cauchy', 'huber', 'truncated' are robust."""
    if loss == "linear":
        return float(d.sum())
    u = d / scale
    if loss == "cauchy":
        return float((0.5 * scale**2 * np.log1p(u * u)).sum())
    if loss == "huber":
        return float(np.where(u <= 1, 0.5 * d * d, scale * (d - 0.5 * scale)).sum())
    if loss == "truncated":
        return float(np.minimum(d, 3 * scale).sum())
    raise ValueError(f"unknown loss {loss!r}")


# Powell's tolerances, in the scaled units (1 unit = 1 mm of motion). The seeds only have to find the
# basin of the lowest minimum, so they stop at 0.3 mm / 1e-3 relative; the winner is then polished on the
# exact eq. (3) (:func:`polish`). Measured (benchmarks/localize_speed.py, with the basin merging below): the
# final pose is within 0.0064 mm / 0.0032 deg of a 1 µm-tolerance Powell on the exact eq. (3) from the same
# seeds, every seed run to its end (localization.md §4, §7.3).
SEED_OPTIONS = {"xtol": 0.3, "ftol": 1e-3, "maxfev": 3000}
POLISH_OPTIONS = {"xtol": 2e-3, "ftol": 1e-7, "maxfev": 3000}
POLISH_STEP = 0.1  # initial direction length (units): the polish starts within a fraction of a mm


def _units(radius: float) -> np.ndarray:
    return np.array([1e-3, 1e-3, 1e-3 / max(radius, 1e-3)])  # 1 mm of motion per unit in each direction


#: a seed whose best point comes within this (mm of motion, summed over x, y and the template's rim) of a
#: minimum already found, at a cost not below it, has joined that basin: it stops there (localization.md §4)
MERGE_DISTANCE = 3.0


class _Merged(Exception):
    """Raised inside Powell's objective when the seed's best point has joined a known basin."""


def powell(args, known: list[SearchResult] | None = None) -> SearchResult:
    """Powell's method from one seed. A picklable task ``(xy, segments (S,2,2), center, seed, loss, scale,
    radius, k, grid)``; ``grid`` = (res, margin, cap) of the Voronoi-label field (built once per process), or
    None for the all-pairs evaluation. The linear loss (eq. 3) goes through :class:`~.cost.Eq3`.

    ``known``: minima of the seeds already run; a seed whose best point so far (Powell's iterate) comes
    within :data:`MERGE_DISTANCE` of one of them at a cost not below it stops (``SearchResult.merged``): it
    has joined a basin whose minimum is known, so it would not become the lowest."""
    xy, seg_array, center, seed, loss, scale, radius, k, grid = args
    segs = Segments.from_array(seg_array, center)
    fld = field_for(seg_array, *grid) if grid is not None else None
    unit = _units(radius)
    if loss == "linear":
        eq3 = Eq3(xy, segs, fld)

        def f(p):
            return eq3(p * unit)
    else:

        def f(p):
            return robust_cost(distances(p * unit, xy, segs, fld), loss, scale)

    if not known:
        r = minimize(f, np.asarray(seed) / unit, method="Powell", options=SEED_OPTIONS)
        return SearchResult(np.asarray(r.x) * unit, float(r.fun), int(r.nfev), k)
    ref = [(np.asarray(m.pose) / unit, m.cost) for m in known]
    best = {"x": np.asarray(seed) / unit, "f": math.inf, "n": 0}

    def watched(p):  # Powell's iterate is its best point so far: stop once that has joined a known basin
        v = f(p)
        best["n"] += 1
        if v < best["f"]:
            best.update(x=np.array(p), f=v)
            for pr, c in ref:
                if v >= c and float(np.abs(p - pr).sum()) <= MERGE_DISTANCE:
                    raise _Merged
        return v

    try:
        r = minimize(watched, np.asarray(seed) / unit, method="Powell", options=SEED_OPTIONS)
    except _Merged:
        return SearchResult(best["x"] * unit, float(best["f"]), best["n"], k, True)
    return SearchResult(np.asarray(r.x) * unit, float(r.fun), int(r.nfev), k)


def polish(xy: np.ndarray, segs: Segments, pose, radius: float) -> SearchResult:
    """Powell's method on the exact eq. (3) (every point against every segment) from ``pose``: the final
    step of the paper's search, so that its answer is the minimum of the paper's cost as written."""
    unit = _units(radius)
    eq3 = Eq3Near(xy, segs, pose)  # exactly the all-pairs eq. (3), on each point's candidate segments
    opts = {**POLISH_OPTIONS, "direc": np.eye(3) * POLISH_STEP}
    r = minimize(lambda p: eq3(p * unit), np.asarray(pose) / unit, method="Powell", options=opts)
    return SearchResult(np.asarray(r.x) * unit, float(r.fun), int(r.nfev), -1)


def _noop(x):
    return x


_POOL: dict[str, object] = {}


def _pool(workers: int) -> tuple[ProcessPoolExecutor, float]:
    """The shared process pool and its measured round trip (s); created once (spawn: safe with threads)."""
    if "pool" not in _POOL:
        ex = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))
        list(ex.map(_noop, range(workers)))  # start the workers
        t0 = time.perf_counter()
        list(ex.map(_noop, range(workers)))
        _POOL.update(pool=ex, rtt=time.perf_counter() - t0, workers=workers)
        atexit.register(ex.shutdown, wait=False, cancel_futures=True)
    return _POOL["pool"], _POOL["rtt"]


def _serial(tasks: list[tuple], first: SearchResult | None = None) -> list[SearchResult]:
    """The seeds one after the other, each told the minima found so far (it stops when it joins one)."""
    out = [] if first is None else [first]
    for t in tasks[len(out) :]:
        out.append(powell(t, [r for r in out if not r.merged]))
    return out


class SeedRunner:
    """Runs Powell from several seeds; parallel in one reused process pool when that is faster."""

    def __init__(self, workers: int | None = None, parallel: str = "auto") -> None:
        self.workers = workers or max(1, min(7, os.cpu_count() or 1))
        self.parallel = parallel
        self.reason = ""

    def run(self, tasks: list[tuple]) -> list[SearchResult]:
        if not tasks:
            return []
        if self.parallel == "never" or self.workers < 2 or len(tasks) < 2:
            self.reason = "serial: one worker or one seed"
            return _serial(tasks)
        t0 = time.perf_counter()
        first = powell(tasks[0])
        t_seed = time.perf_counter() - t0
        rest = tasks[1:]
        have_pool = "pool" in _POOL
        if self.parallel == "auto" and not have_pool:
            self.reason = f"serial: no pool yet and the seeds take {t_seed * 1e3:.1f} ms each"
            if t_seed * len(rest) > 1.0:  # worth starting the pool (about 1 s once) for later calls
                try:
                    _pool(self.workers)
                except (RuntimeError, OSError):
                    pass
            return _serial(tasks, first)
        try:
            pool, rtt = _pool(self.workers)
        except (RuntimeError, OSError) as e:  # e.g. spawn from an unguarded __main__: stay correct, go serial
            self.reason = f"serial: the process pool could not start ({type(e).__name__})"
            return _serial(tasks, first)
        serial = t_seed * len(rest)
        parallel = rtt + serial / min(self.workers, len(rest))
        if self.parallel == "auto" and serial <= parallel:
            self.reason = f"serial: {serial * 1e3:.1f} ms serial <= {parallel * 1e3:.1f} ms in the pool"
            return _serial(tasks, first)
        self.reason = (
            f"process pool of {self.workers}: seed {t_seed * 1e3:.1f} ms, round trip {rtt * 1e3:.1f} ms"
        )
        return [first, *pool.map(powell, rest)]


# ---------------------------------------------------------------------------------------------- global
def global_search(
    field: DistanceField,
    xy: np.ndarray,
    center: np.ndarray,
    radius: float,
    window_xy: float,
    window_theta: float,
    step: float = 8e-3,
    keep: int = 6,
    max_points: int = 150,
) -> list[SearchResult]:
    """Score the whole window (rotation x translation grid) on the truncated distance field; return the
    ``keep`` best distinct poses after a finer local grid. Costs are mean truncated distances (m)."""
    rng = np.random.default_rng(0)
    pts = xy if len(xy) <= max_points else xy[rng.choice(len(xy), max_points, replace=False)]
    res = field.res
    cells = max(1, int(round(step / res)))  # translation step in whole cells
    step = cells * res
    dth = max(step / radius, 1e-3)
    thetas = np.arange(-window_theta, window_theta + 1e-12, dth)
    n = int(np.ceil(window_xy * math.sqrt(2) / step))
    si = np.arange(-n, n + 1) * cells
    h, w = field.field.shape
    flat = field.field.ravel()
    rel = pts - center
    offs = -(si[:, None] * w + si[None, :]).ravel()  # shift of the planned-frame points by -s
    sy, sx = np.meshgrid(si * res, si * res, indexing="ij")
    shift = np.stack([sx.ravel(), sy.ravel()], axis=1)
    best = []
    for ch in np.array_split(np.arange(len(thetas)), max(1, len(thetas) // 4)):
        th = thetas[ch]
        c, s = np.cos(th), np.sin(th)
        # planned-frame points for zero translation: R(-theta) (p - c) + c
        qx = c[:, None] * rel[:, 0] + s[:, None] * rel[:, 1] + center[0]
        qy = -s[:, None] * rel[:, 0] + c[:, None] * rel[:, 1] + center[1]
        base = field.lookup_flat(np.stack([qx, qy], axis=-1))  # (T, P)
        trans = [shift @ rot2(t).T for t in th]  # t = R(theta) s
        inside = [(np.abs(tr) <= window_xy + 1e-9).all(axis=1) for tr in trans]
        sel = np.flatnonzero(np.any(inside, axis=0))  # only the shifts inside the window for some theta
        idx = (base[:, None, :] + offs[sel][None, :, None]).astype(np.int32)
        cost = np.take(flat, idx, mode="clip").mean(axis=2)  # (T, len(sel))
        for ti, t in enumerate(th):
            cst = np.where(inside[ti][sel], cost[ti], np.inf)
            for k in np.argsort(cst)[:keep]:
                if np.isfinite(cst[k]):
                    best.append((float(cst[k]), trans[ti][sel[k], 0], trans[ti][sel[k], 1], float(t)))
    best.sort()
    out: list[SearchResult] = []
    for cst, x, y, t in best:
        p = np.array([x, y, t])
        if all(_pose_gap(p, o.pose, radius) > 3 * step for o in out):
            out.append(SearchResult(p, cst))
        if len(out) >= keep:
            break
    return [_polish(field, pts, center, radius, r, step, dth) for r in out]


def _polish(field, pts, center, radius, r: SearchResult, step, dth) -> SearchResult:
    """A finer 5x5x5 grid around a coarse cell (nearest-cell distances)."""
    g = np.linspace(-1, 1, 5)
    dx, dy, dt = np.meshgrid(g * step, g * step, g * dth, indexing="ij")
    poses = r.pose + np.stack([dx.ravel(), dy.ravel(), dt.ravel()], axis=1)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    rel = pts[None] - center - poses[:, None, :2]
    q = (
        np.stack(
            [
                c[:, None] * rel[..., 0] + s[:, None] * rel[..., 1],
                -s[:, None] * rel[..., 0] + c[:, None] * rel[..., 1],
            ],
            axis=-1,
        )
        + center
    )
    cost = field.field.ravel()[field.lookup_flat(q)].mean(axis=1)
    k = int(np.argmin(cost))
    return SearchResult(poses[k], float(cost[k]))


def _pose_gap(a: np.ndarray, b: np.ndarray, radius: float) -> float:
    """Largest displacement (m) between two poses of a template of ``radius``."""
    return float(np.hypot(a[0] - b[0], a[1] - b[1]) + radius * abs(wrap(a[2] - b[2])))


def seeds_to_tasks(xy, segs: Segments, seeds, loss, scale, radius, grid=None) -> list[tuple]:
    return [(xy, segs.array, segs.center, s, loss, scale, radius, k, grid) for k, s in enumerate(seeds)]
