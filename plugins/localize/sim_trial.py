"""``localize-and-weld`` with ``scope = "localize"``: only the localization part of the job, in the simulated
cell, for Monte-Carlo studies (``weldcell study``; the Table 1 protocol of paper 002, §V).

What runs: the template; the simulated worker's placement (rigid error drawn per run, or fixed by
``[job.settings.worker] placement_x / placement_y / placement_theta``, which ``weldcell study --vary`` draws)
with members off CAD; the job's own inspection plan (:func:`~.plans.make_plan`, refused by
:func:`~.plans.check_constraints` as in the full job); the part scanned along the plan's lines by the laser
sensor model of :mod:`.synth` (the optoNCDT 1402's noise, the robot-sensor coupling, shearing and dropouts at
edges, at the sensor's rate and the plan's speed) instead of moving the simulated robot; the edge and
localize stages of the profile; the job's failure checks. No projector, no robot motion, no weld: a trial
takes about a second instead of a minute.

Figures (``result.json``, the columns of ``weldcell study``): ``localization`` (status, pose, fit error,
sigma, ``error_vs_truth`` {x_mm, y_mm, theta_deg} against the placement, ``pose_error_vs_asbuilt`` against
the pose a perfect measurement of the as-built part along the plan would return and
``pose_error_vs_asbuilt_outline`` against the best rigid match of the CAD outlines to the as-built ones --
:mod:`.reference`, ground truth only; the references themselves in ``asbuilt_reference``),
``welds_vs_truth`` (the welds the job would weld, each re-planned from its members, against the true
welds: per-trial mean and RMS of the X and Y error of the weld points, the largest error of a weld claimed
``ok``, the share of welds reported ``uncertain``, ``wrong`` = 1 when the localization said ok but a claimed
weld is more than 2.5 mm off), ``welds_rigid_vs_truth`` (the same with the CAD welds moved by M alone, as in
the paper), ``plan``, ``edge_points``, ``timings_ms``. A localization that is not ``ok`` fails the run
(JobError), as in the full job: the study counts it in its failure rate.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
from pydantic import Field
from weldcell.plugins.localize.plans import check_constraints, make_plan
from weldcell.plugins.localize.pose import transform_template, wrap
from weldcell.plugins.localize.reference import asbuilt_pose_crossings, asbuilt_pose_outline
from weldcell.plugins.localize.synth import (
    SensorModel,
    apply_variations,
    member_variations,
    scan_lines,
    true_welds,
)
from weldcell.sdk.errors import JobError, UsageError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Frequency, Length

#: a claimed weld point farther than this from the truth is a wrong answer (benchmarks/localize_table1.py)
WRONG = 2.5e-3


class SimScanSettings(Settings):
    """The laser sensor model of ``scope = "localize"`` (simulated cell only): optoNCDT 1402 + robot."""

    noise: Length = Field(0.288e-3, ge=0, description="depth noise sigma [m] (the 1402's accuracy, §II)")
    coupling: Length = Field(
        0.2e-3, ge=0, description="robot-sensor XY error per axis, constant along a line [m] (0.4 mm, §II)"
    )
    shear: Length = Field(0.2e-3, ge=0, description="radius around a drop with unreadable heights [m]")
    shear_dropout: float = Field(0.5, ge=0, le=1, description="share of sheared readings out of range")
    dropout: float = Field(1e-3, ge=0, le=1, description="share of random out-of-range readings")
    rate: Frequency = Field(1500.0, gt=0, description="measuring rate [Hz]")


@dataclass(frozen=True)
class PoseError:
    """A found pose minus a reference pose (x, y, theta about the template's centroid), in mm and degrees;
    theta wrapped to (-180, 180]: a turn by 2 pi is the same pose."""

    x_mm: float
    y_mm: float
    theta_deg: float

    @classmethod
    def of(cls, found, reference) -> PoseError:
        d = np.asarray(found, float) - np.asarray(reference, float)
        return cls(float(d[0] * 1e3), float(d[1] * 1e3), float(np.degrees(wrap(d[2]))))

    def to_json(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class AsBuiltTruth:
    """The references of the pose error besides the placement (:mod:`.reference`; ground truth only):
    ``crossings`` the pose a perfect measurement along the plan would return, ``outline`` the best rigid
    match of the CAD outlines to the as-built ones; ``crossings`` is None when the plan crosses fewer than
    three visible edges."""

    crossings: np.ndarray | None
    outline: np.ndarray
    n_crossings: int
    rms_mm: float

    def to_json(self) -> dict:
        c = self.crossings
        return {
            "crossings": None if c is None else {"x": c[0], "y": c[1], "theta": c[2]},
            "outline": {"x": self.outline[0], "y": self.outline[1], "theta": self.outline[2]},
            "n_crossings": self.n_crossings,
            "rms_mm": self.rms_mm,
        }


def asbuilt_truth(template, pose, variations, lines) -> AsBuiltTruth:
    """Both as-built references of this trial (never the localizer's output nor the sensor's errors)."""
    outline = asbuilt_pose_outline(template, pose, variations)
    try:
        ref = asbuilt_pose_crossings(template, pose, variations, lines)
    except ValueError:
        return AsBuiltTruth(None, outline.pose, 0, float("nan"))
    return AsBuiltTruth(ref.pose, outline.pose, ref.points, ref.rms * 1e3)


def placement(w, rng: np.random.Generator) -> np.ndarray:
    """The worker's rigid error (dx, dy, dtheta): the fixed values given, the others uniform in the ranges."""
    if w.placement is not None:
        return np.asarray(w.placement, float)
    drawn = rng.uniform(-1.0, 1.0, 3) * np.array([w.placement_offset, w.placement_offset, w.placement_angle])
    fixed = (w.placement_x, w.placement_y, w.placement_theta)
    return np.array([d if f is None else float(f) for d, f in zip(drawn, fixed, strict=True)])


def weld_errors(found: list[np.ndarray], truth: list[np.ndarray], claimed: list[bool], ok: bool) -> dict:
    """Per-trial figures of weld points (XY) against the truth; pooled over trials by the benchmark."""
    err = np.concatenate([f - t for f, t in zip(found, truth, strict=True)]) * 1e3
    worst = max(
        (
            float(np.linalg.norm(f - t, axis=1).max())
            for f, t, c in zip(found, truth, claimed, strict=True)
            if c
        ),
        default=0.0,
    )
    return {
        "points": int(len(err)),
        "mean_x_mm": float(err[:, 0].mean()),
        "mean_y_mm": float(err[:, 1].mean()),
        "rms_x_mm": float(np.sqrt((err[:, 0] ** 2).mean())),
        "rms_y_mm": float(np.sqrt((err[:, 1] ** 2).mean())),
        "max_claimed_mm": worst * 1e3,
        "uncertain_fraction": 1.0 - float(np.mean(claimed)) if claimed else 0.0,
        "wrong": int(ok and worst > WRONG),
    }


def run(ctx) -> dict:
    """The localization part of the job on the simulated cell (module docstring)."""
    from weldcell.plugins.localize.job import read_template, require_every_member, sensor_height

    s = ctx.settings
    if not _simulated(ctx):
        raise UsageError(
            "[job.settings] scope = 'localize' runs in the simulated cell only (it scans a simulated part)",
            "use scope = 'full' on hardware",
        )
    with ctx.step("template"):
        template = read_template(ctx, s)
        template.validate()
        template.save(ctx.path("template_planned.json"))
    rng = np.random.default_rng([ctx.profile.cell.seed, 1002])
    pose = placement(s.worker, rng)
    var = member_variations(template, rng, s.worker.member_variation)
    truth = transform_template(apply_variations(template, var), pose, template.centroid)
    ctx.figures["true_placement"] = {"x": pose[0], "y": pose[1], "theta": pose[2]}
    with ctx.step("inspection plan"):
        plan = make_plan(template, s.plan, sensor_height(ctx, template, s))
        plan.constraints = check_constraints(plan, template, s.plan)
    ctx.figures["plan"] = {"kind": plan.kind, "lines": len(plan.lines), "length_m": round(plan.length, 3)}
    t = {}
    with ctx.step("inspect (sensor model, no motion)"):
        c0 = time.process_time()
        m = s.sim_scan
        sensor = SensorModel(m.noise, m.coupling, m.shear, m.shear_dropout, m.dropout, m.rate, s.plan.speed)
        scan = scan_lines(truth, plan.lines, rng, sensor)
        t["scan"] = time.process_time() - c0
    with ctx.step("edges"):
        c0 = time.process_time()
        edges = ctx.stage("edges")(scan, template)
        t["edges"] = time.process_time() - c0
    with ctx.step("localize"):
        c0 = time.process_time()
        loc = ctx.stage("localize")(template, edges)
        t["localize"] = time.process_time() - c0
        require_every_member(loc, s)
        doc = loc.to_json()
        ctx.write_json("localization.json", doc)
    fig = {k: doc[k] for k in ("status", "message", "method", "x", "y", "theta", "fit_error_mean", "sigma")}
    fig["error_vs_truth"] = PoseError.of(loc.pose, pose).to_json()  # against the placement
    ref = asbuilt_truth(template, pose, var, plan.lines)
    ctx.figures["asbuilt_reference"] = ref.to_json()
    if ref.crossings is not None:
        fig["pose_error_vs_asbuilt"] = PoseError.of(loc.pose, ref.crossings).to_json()
    fig["pose_error_vs_asbuilt_outline"] = PoseError.of(loc.pose, ref.outline).to_json()
    ctx.figures["localization"] = fig
    ctx.figures["readings"] = len(scan)
    ctx.figures["edge_points"] = len(edges)
    ctx.figures["timings_ms"] = {k: v * 1e3 for k, v in t.items()}  # CPU of this process
    if loc.ok:
        real = true_welds(template, pose, var)
        found = [np.asarray(w["points"], float)[:, :2] for w in loc.welds]
        claimed = [w.get("status", "ok") == "ok" for w in loc.welds]
        ctx.figures["welds_vs_truth"] = weld_errors(found, real, claimed, True)
        M = loc.M
        rigid = [w.points[:, :2] @ M[:2, :2].T + M[:2, 3] for w in template.welds]
        ctx.figures["welds_rigid_vs_truth"] = weld_errors(rigid, real, [True] * len(rigid), True)
    if not loc.ok:
        raise JobError(
            loc.message, "no weld was started: weld this workpiece by hand, or re-place it and run again"
        )
    return {"status": loc.status, "scope": "localize"}


def _simulated(ctx) -> bool:
    from weldcell.hal.sim import world_of

    return world_of(ctx) is not None
