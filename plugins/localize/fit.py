"""Localization of a flat weldment from edge points against its CAD template (paper 002, §IV).

``localize(template, edges, settings) -> Localization`` (``weldcell/localization@1``).

* ``method="paper"``: the paper's method: eq. (3) fit error, Powell's method from ``seeds`` seeds within
  ±50 mm / ±20° of the edges' centre of mass and orientation, run in a process pool, lowest error wins,
  a mean error above 2.5 mm is a failure.
* ``method="robust"`` (default, beyond the paper): a global search of the whole window on the template's
  distance transform (no lucky seeds), robust (Cauchy) Gauss-Newton on exact point-to-segment distances
  from the best distinct candidates, ambiguity when two distinct poses fit almost equally, the covariance
  of (x, y, theta), each member's own offset, and welds re-planned from the members they join. A result
  that cannot be trusted (few inliers, at the window's edge, under-constrained, mean error > 2.5 mm) is
  ``failed``, never an answer.

The pose is (x, y, theta) about the template's centroid c: ``P_found = M @ P_planned``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import Field
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Length

from .cost import Segments, distances, field_for
from .pose import inverse_xy, pose_matrix, rot2, wrap
from .refine import Refined, _jacobian, cauchy_weights, covariance, gauss_newton, member_fits, replan_welds
from .search import SeedRunner, _pose_gap, global_search, paper_seeds, polish, seeds_to_tasks
from .template import Template

SCHEMA = "weldcell/localization@1"
HAND_WELD = "weld this workpiece by hand (or re-place it and inspect again)"


class LocalizeSettings(Settings):
    """Localization (§IV) and its robust extensions."""

    method: Literal["robust", "paper"] = Field("robust", description="'paper': Powell multi-seed only")
    seeds: int = Field(7, ge=1, le=64, description="Powell seeds of the paper's search")
    seed_window_xy: Length = Field(
        0.05, description="seeds within this of the edges' centre of mass (paper: 50 mm)"
    )
    seed_window_theta: Angle = Field(
        math.radians(20), description="seeds within this of their orientation (20 deg)"
    )
    window_xy: Length = Field(
        0.05, description="global search: translation window around the planned position"
    )
    window_theta: Angle = Field(math.radians(25), description="global search: rotation window")
    window_center: Literal["planned", "both"] = Field(
        "both", description="search around the planned position, or also around the edges' estimate (§IV)"
    )
    max_mean_error: Length = Field(
        2.5e-3, description="mean fit error above this is a failure (paper: 2.5 mm)"
    )
    loss_scale: Length = Field(2e-3, description="initial Cauchy scale; shrinks to the data's own")
    min_scale: Length = Field(0.1e-3, description="smallest Cauchy scale")
    inlier_distance: Length = Field(1.5e-3, description="an edge point within this of the fit is an inlier")
    min_inlier_fraction: float = Field(0.6, gt=0, le=1, description="fewer inliers: failed")
    min_points: int = Field(20, ge=4, description="fewer edge points: failed")
    ambiguity_margin: float = Field(0.25, ge=0, description="2nd pose within this relative cost: ambiguous")
    ambiguity_distance: Length = Field(3e-3, description="poses closer than this are the same")
    max_sigma_xy: Length = Field(0.5e-3, description="larger position sigma: under-constrained, failed")
    max_sigma_theta: Angle = Field(math.radians(0.1), description="larger rotation sigma: failed")
    member_tolerance: Length = Field(2e-3, description="member offset (at its ends) beyond this is reported")
    grid_resolution: Length = Field(1e-3, description="distance transform cell of the global search")
    coarse_step: Length = Field(8e-3, description="translation step of the global search")
    candidates: int = Field(6, ge=1, description="distinct global candidates refined")
    workers: int = Field(2, ge=1, description="process pool size for the seeds")
    parallel: Literal["auto", "always", "never"] = Field("auto", description="seed pool use")


@dataclass
class Localization:
    """The localization result (``weldcell/localization@1``); see :func:`localize`."""

    status: str
    message: str
    pose: np.ndarray
    center: np.ndarray
    fit_error_mean: float
    covariance: np.ndarray
    members: list = field(default_factory=list)
    welds: list = field(default_factory=list)
    alternatives: list = field(default_factory=list)
    n_points: int = 0
    inlier_fraction: float = float("nan")
    fit_error_mean_all: float = float("nan")
    method: str = "robust"
    scale: float = float("nan")
    timings: dict = field(default_factory=dict)
    parallel: str = ""

    @property
    def M(self) -> np.ndarray:
        return pose_matrix(self.pose, self.center)

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_json(self) -> dict:
        """``weldcell/localization@1`` (metres, radians; no NaN or Infinity: unknowns are null)."""
        x, y, th = (float(v) for v in self.pose)
        return _clean(
            {
                "schema": SCHEMA,
                "status": self.status,
                "message": self.message,
                "frame": "base",
                "units": "m",
                "method": self.method,
                "M": self.M,
                "x": x,
                "y": y,
                "theta": th,
                "center": self.center,
                "fit_error_mean": self.fit_error_mean,
                "fit_error_mean_all": self.fit_error_mean_all,
                "inlier_fraction": self.inlier_fraction,
                "n_points": self.n_points,
                "covariance": self.covariance,
                "sigma": {
                    "x": _sd(self.covariance, 0),
                    "y": _sd(self.covariance, 1),
                    "theta": _sd(self.covariance, 2),
                },
                "members": [
                    {
                        "id": m.id,
                        "status": m.status,
                        "points": m.points,
                        "rms": m.rms,
                        "offset": m.offset,
                        "dtheta": m.dtheta,
                        "observed": {
                            "along": bool(m.observed[0]),
                            "across": bool(m.observed[1]),
                            "theta": bool(m.observed[2]),
                        },
                    }
                    for m in self.members
                ],
                "welds": self.welds,
                "alternatives": self.alternatives,
                "timings": self.timings,
                "parallel": self.parallel,
            }
        )


def _sd(cov: np.ndarray, i: int):
    v = float(cov[i, i])
    return math.sqrt(v) if math.isfinite(v) and v >= 0 else None


def _clean(obj):
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _as_xy(edges) -> np.ndarray:
    xy = edges.xy if hasattr(edges, "xy") else edges
    return np.asarray(xy, dtype=float).reshape(-1, 2)


def localize(template: Template, edges, settings: LocalizeSettings | None = None) -> Localization:
    """Find the placement of ``template`` that explains ``edges`` (EdgePoints or (N, 2) XY, base frame)."""
    s = settings or LocalizeSettings()
    xy = _as_xy(edges)
    xy = xy[np.isfinite(xy).all(axis=1)]
    segs = Segments.of(template)
    center = template.centroid
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if len(xy) < s.min_points:
        return _too_few_points(template, len(xy), s)
    runner = SeedRunner(s.workers, s.parallel)
    cap = max(4 * s.coarse_step, 0.02)
    grid = (s.grid_resolution, cap + 0.02, cap)
    fld = field_for(segs.array, *grid)
    timings["distance_field"] = time.perf_counter() - t0
    if s.method == "paper":
        ref, cands = _paper_search(template, xy, segs, runner, grid, s, timings)
        centres = None
    else:
        ref, cands, centres = _windowed_search(template, xy, segs, fld, s, timings)
    out = _judge(template, xy, segs, ref, cands, s, centres)
    t1 = time.perf_counter()
    out.members = member_fits(template, ref, xy, segs, center, _inlier(ref, s), s.member_tolerance)
    if out.status == "ok":  # a pose we cannot trust re-plans no weld (the members stay, for diagnosis)
        out.welds = replan_welds(template, ref.pose, center, out.members, prior=s.member_tolerance / 2)
    timings["members_welds"] = time.perf_counter() - t1
    if out.status == "ok":
        _member_notes(out)
    timings["total"] = time.perf_counter() - t0
    out.timings, out.parallel = timings, runner.reason
    return out


def _too_few_points(template: Template, n: int, s: LocalizeSettings) -> Localization:
    """The failed result of a scan that did not cross the workpiece's edges."""
    return Localization(
        "failed",
        f"only {n} edge points (need {s.min_points}): the scan did not "
        f"cross the workpiece's edges; check the inspection plan, then {HAND_WELD}",
        np.zeros(3),
        template.centroid,
        float("nan"),
        np.full((3, 3), np.nan),
        n_points=n,
        method=s.method,
    )


def _paper_search(template: Template, xy, segs, runner, grid, s: LocalizeSettings, timings: dict):
    """The paper's search: Powell from seeds in the ±50 mm / ±20° window, polished by exact eq. (3);
    the result at that pose without refinement. (result, candidates)"""
    t1, c1 = time.perf_counter(), time.process_time()
    center, radius = template.centroid, template.radius
    rng = np.random.default_rng(0)
    outline = np.concatenate([m.outline for m in template.members])
    seeds = paper_seeds(outline, center, xy, s.seeds, s.seed_window_xy, s.seed_window_theta, rng)
    results = runner.run(seeds_to_tasks(xy, segs, seeds, "linear", 1.0, radius, grid))
    best = polish(xy, segs, min(results, key=lambda r: r.cost).pose, radius)  # exact eq. (3)
    best.pose[2] = wrap(best.pose[2])  # Powell may have turned by 2 pi: the same pose
    timings["powell"] = time.perf_counter() - t1
    timings["powell_cpu"] = time.process_time() - c1  # this process only (not the pool's workers)
    ref = _at(best.pose, xy, segs, center, s)
    return ref, [ref]


def _windowed_search(template: Template, xy, segs, fld, s: LocalizeSettings, timings: dict):
    """Global search in each window (its own frame, then composed), a few Gauss-Newton iterations for
    every candidate, the full refinement for the distinct ones still in contention.
    (best, candidates, window centres)"""
    center, radius = template.centroid, template.radius
    t1 = time.perf_counter()
    centres = _window_centres(template, xy, s)
    found = []
    for cp in centres:  # search each window in its own frame, then compose (t_c + R_c t, th_c + th)
        local = global_search(
            fld,
            inverse_xy(cp, center, xy),
            center,
            radius,
            s.window_xy,
            s.window_theta,
            s.coarse_step,
            s.candidates,
        )
        for r in local:
            r.pose = np.array([*(cp[:2] + rot2(cp[2]) @ r.pose[:2]), cp[2] + r.pose[2]])
        found += local
    found.sort(key=lambda r: r.cost)
    found = found[: s.candidates]
    timings["global"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    # a few iterations for every candidate; the full refinement only for those still in contention
    quick = [gauss_newton(c.pose, xy, segs, center, s.loss_scale, s.loss_scale, 4, fld=fld) for c in found]
    quick.sort(key=lambda q: q.cost)
    keep: list = []
    for q in quick:  # distinct poses still in contention
        if q.cost <= 2.0 * quick[0].cost + 1e-12 and all(
            _pose_gap(q.pose, k.pose, radius) > s.ambiguity_distance for k in keep
        ):
            keep.append(q)
    cands = [gauss_newton(q.pose, xy, segs, center, s.loss_scale, s.min_scale, fld=fld) for q in keep]
    timings["refine"] = time.perf_counter() - t1
    cands.sort(key=lambda c: c.cost)
    return cands[0], cands, centres


def _at(pose, xy, segs, center, s: LocalizeSettings) -> Refined:
    """Residuals and normal matrix at a fixed pose (the paper's result; no refinement)."""
    r, J, j = _jacobian(pose, xy, segs, center)
    w = np.ones_like(r)
    return Refined(np.asarray(pose, float), r, w, j, s.inlier_distance, J.T @ J, float(r.mean()), 0)


def _inlier(ref: Refined, s: LocalizeSettings) -> float:
    return max(s.inlier_distance, 3 * ref.scale)


def _window_centres(tpl: Template, xy: np.ndarray, s: LocalizeSettings) -> list[np.ndarray]:
    """Where the global search looks: the planned position, and (``window_center="both"``) the paper's
    estimate from the edges' centre of mass and orientation when it lies near or beyond that window's edge."""
    centres = [np.zeros(3)]
    if s.window_center == "both":
        outline = np.concatenate([m.outline for m in tpl.members])
        est = paper_seeds(outline, tpl.centroid, xy, 1, 0.0, s.window_theta, np.random.default_rng(0))[0]
        if max(abs(est[0]), abs(est[1])) > 0.8 * s.window_xy or abs(est[2]) > 0.8 * s.window_theta:
            centres.append(est)
    return centres


def _in_window(pose, centres, s: LocalizeSettings) -> bool:
    for c in centres:
        d = rot2(-c[2]) @ (np.asarray(pose[:2]) - c[:2])
        if max(abs(d[0]), abs(d[1])) <= s.window_xy and abs(wrap(pose[2] - c[2])) <= s.window_theta:
            return True
    return False


def _judge(tpl, xy, segs, ref: Refined, cands: list[Refined], s: LocalizeSettings, centres=None):
    center, radius = tpl.centroid, tpl.radius
    d = np.abs(ref.r)
    inl = d <= _inlier(ref, s)
    frac = float(inl.mean())
    cov = covariance(ref)
    mean_all = float(d.mean())
    mean_in = float(d[inl].mean()) if inl.any() else float("nan")
    paper = s.method == "paper"
    mean = mean_all if paper else mean_in
    loc = Localization(
        "ok",
        "",
        ref.pose,
        center,
        mean,
        cov,
        n_points=len(xy),
        inlier_fraction=frac,
        fit_error_mean_all=mean_all,
        method=s.method,
        scale=ref.scale,
    )
    why = []
    if not math.isfinite(mean) or mean > s.max_mean_error:
        why.append(f"mean fit error {mean * 1e3:.2f} mm > {s.max_mean_error * 1e3:.1f} mm")
    if not paper:
        x, y, th = ref.pose
        if not _in_window(ref.pose, centres or [np.zeros(3)], s):
            why.append(
                f"the best fit (x {x * 1e3:.1f} mm, y {y * 1e3:.1f} mm, theta {math.degrees(th):.1f} deg) "
                f"is outside the search window (±{s.window_xy * 1e3:.0f} mm, "
                f"±{math.degrees(s.window_theta):.0f} deg around the planned position"
                + (" or the edges' estimate" if len(centres or []) > 1 else "")
                + "): the part may be placed beyond it"
            )
        if frac < s.min_inlier_fraction:
            why.append(
                f"only {frac:.0%} of the {len(xy)} edge points fit (need {s.min_inlier_fraction:.0%}): "
                "the part differs from CAD, is placed outside the window, or the scan shows clutter"
            )
        sx, sy, st = (_sd(cov, i) for i in range(3))
        if None in (sx, sy, st) or max(sx, sy) > s.max_sigma_xy or st > s.max_sigma_theta:
            why.append(
                "the edge points do not constrain the pose (sigma x/y/theta "
                + "/".join(
                    "inf" if v is None else f"{v * (1e3 if k < 2 else 180 / math.pi):.3g}"
                    for k, v in enumerate((sx, sy, st))
                )
                + " mm/mm/deg): add scan lines across the members' ends or neighbours (Fig. 10)"
            )
    if why:
        loc.status = "failed"
        loc.message = "localization failed: " + "; ".join(why) + f"; {HAND_WELD}"
        return loc
    alts = [c for c in cands[1:] if _pose_gap(c.pose, ref.pose, radius) > s.ambiguity_distance]
    if alts and not paper:
        rho = _cost_at_scale(alts[0], ref.scale)
        if rho <= _cost_at_scale(ref, ref.scale) * (1 + s.ambiguity_margin):
            a = alts[0].pose
            loc.status = "ambiguous"
            loc.alternatives = [{"x": float(a[0]), "y": float(a[1]), "theta": float(a[2]), "cost": rho}]
            loc.message = (
                "ambiguous: two distinct placements fit almost equally "
                f"(x/y/theta {ref.pose[0] * 1e3:.1f}/{ref.pose[1] * 1e3:.1f} mm/"
                f"{math.degrees(ref.pose[2]):.1f} deg"
                f" and {a[0] * 1e3:.1f}/{a[1] * 1e3:.1f} mm/{math.degrees(a[2]):.1f} deg; the part looks "
                "symmetric to this scan): mark the part or scan a distinguishing feature, or " + HAND_WELD
            )
            return loc
    loc.message = (
        f"localized: x {ref.pose[0] * 1e3:.2f} mm, y {ref.pose[1] * 1e3:.2f} mm, "
        f"theta {math.degrees(ref.pose[2]):.3f} deg, mean error {mean * 1e3:.3f} mm"
    )
    return loc


def _cost_at_scale(ref: Refined, scale: float) -> float:
    r = ref.r
    return float((0.5 * scale**2 * np.log1p((r / scale) ** 2)).mean())


def _member_notes(loc: Localization) -> None:
    bad = [m for m in loc.members if m.status == "outside_tolerance"]
    unseen = [m for m in loc.members if m.status == "not_observed"]
    if bad:
        loc.message += "; members outside tolerance: " + ", ".join(
            f"{m.id} ({np.linalg.norm(m.offset) * 1e3:.1f} mm, {math.degrees(m.dtheta):.2f} deg)" for m in bad
        )
    if unseen:
        loc.message += "; members not observed (missing or not scanned): " + ", ".join(m.id for m in unseen)
    vague = [w["id"] for w in loc.welds if w.get("status") == "uncertain"]
    if vague:
        loc.message += (
            "; welds the scan does not place to within the member tolerance (re-scan across their members, "
            "or weld them by hand): " + ", ".join(vague)
        )


__all__ = ["LocalizeSettings", "Localization", "localize", "distances", "cauchy_weights", "wrap"]
