"""Paper 004 Table IV in simulation as a study trial function (``weldcell study --function``).

One trial relocalizes a simulated second visit against a prior map of a 40 x 30 m site: the visit lies at
a random place (up to 8 m from the site centre, up to 3 m more for its origin) and heading, and the
priors of its ``priors`` value are drawn around the truth:

* ``gnss``: position = truth + N(0, 1 m) per axis, stated sigma 2 m; ``imu``: yaw = truth + N(0, 3 deg),
  stated sigma 5 deg; ``gnss+imu``: both; ``neither``: none (global registration);
* ``other-site``: both priors, but the prior map is another site's (must fail: a success is wrong);
* ``imu90+gnss``: a magnetometer disturbed by steel, 90 deg off with a stated 5 deg, and GNSS.

Figures: ``success`` (ok and within 5 cm / 0.5 deg), ``failed`` (status failed), ``wrong_ok`` (ok but wrong:
must stay 0), ``cpu_s`` (process CPU time of the relocalization), ``wall_s``, the overlap split by outcome,
and the error of an ok result. The prior map is prepared once per worker process and kept (as a robot does
when it loads its prior map); that time is not in the trial's figures.

    weldcell study --function weldcell.plugins.relocalize.table4:trial --trials 400 --by priors \\
        --vary 'priors=cycle(gnss, imu, gnss+imu, neither)' -o table4/
"""

from __future__ import annotations

import functools
import math
import time
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.plugins.relocalize import synth
from weldcell.plugins.relocalize.relocalize import PriorMap, Priors, RelocalizeSettings, relocalize
from weldcell.sdk.errors import UsageError

SIZE = (40.0, 30.0)
SITE_SEED, OTHER_SITE_SEED = 0, 17
ROWS = ("gnss", "imu", "gnss+imu", "neither", "other-site", "imu90+gnss")
TOLERANCE = (0.05, 0.5)  # m, deg


def error(T_true: np.ndarray, T: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) of ``T`` against ``T_true``."""
    E = np.linalg.inv(T_true) @ T
    return float(np.linalg.norm(E[:3, 3])), math.degrees(Rotation.from_matrix(E[:3, :3]).magnitude())


@functools.cache
def prior_map(site_seed: int, method: str) -> PriorMap:
    """The site's prior map, prepared once per process (NDT cells, KD-tree, registration target)."""
    return PriorMap(synth.site_cloud(site_seed, SIZE), RelocalizeSettings(method=method).ndt).warm(
        RelocalizeSettings(method=method)
    )


def draw(rng: np.random.Generator, site: np.ndarray, priors: str) -> tuple[np.ndarray, np.ndarray, Priors]:
    """(true T_prior_current, the current map, its priors) of one visit."""
    yaw = rng.uniform(-math.pi, math.pi)
    c = np.array([20.0, 15.0]) + rng.uniform(-8, 8, 2)
    T = synth.pose(*(c + rng.uniform(-3, 3, 2) - [20, 15]), rng.uniform(-0.3, 0.3), yaw)
    cur = synth.visit(site, tuple(c), 9.0, T, seed=int(rng.integers(1 << 30)))
    pr = Priors()
    if "gnss" in priors or priors == "other-site":
        pr.position, pr.position_sigma = T[:3, 3] + rng.normal(scale=1.0, size=3), 2.0
    if priors in ("imu", "gnss+imu", "other-site"):
        pr.yaw, pr.yaw_sigma = yaw + math.radians(rng.normal(scale=3.0)), math.radians(5.0)
    if priors == "imu90+gnss":  # magnetometer disturbed by steel: 90 deg off, stated 5 deg
        pr.yaw, pr.yaw_sigma = yaw + math.pi / 2, math.radians(5.0)
    return T, cur, pr


def trial(values: dict[str, Any], seed: int, trial: int = 0) -> dict[str, float]:
    """One Table IV relocalization; ``values``: ``priors`` (one of :data:`ROWS`), optional ``method``."""
    priors = str(values.get("priors", "gnss+imu"))
    method = str(values.get("method", "gicp"))
    if priors not in ROWS:
        raise UsageError(f"priors={priors!r} is not a Table IV row", f"use one of {', '.join(ROWS)}")
    rng = np.random.default_rng(seed)
    site = prior_map(SITE_SEED, method)
    T, cur, pr = draw(rng, site.points, priors)
    against = prior_map(OTHER_SITE_SEED, method) if priors == "other-site" else site
    c0 = time.process_time()
    res = relocalize(against, cur, pr, RelocalizeSettings(method=method))
    cpu = time.process_time() - c0
    ok = res.status == "ok"
    t_err, r_err = error(T, res.T_prior_current)
    correct = priors != "other-site" and t_err < TOLERANCE[0] and r_err < TOLERANCE[1]
    out = {
        "success": float(ok and correct),
        "failed": float(not ok),
        "wrong_ok": float(ok and not correct),
        "cpu_s": cpu,
        "wall_s": res.seconds,
        "overlap_ok" if ok else "overlap_failed": res.overlap,
    }
    if ok:
        out.update(t_err_m=t_err, r_err_deg=r_err)
    return out
