"""One entry point for every configuration and method: :func:`calibrate`.

Every configuration of §2.1.1 reduces to one of two kinds of sub-problem:

* **fixed camera** (eye-on-base eq. 4; eye-on-arm with the marker on the flange, eq. 8, in the
  {Arm} frame; co-manipulation eq. 6b): the feature rides on a carrier with known poses ``P_i``
  (``T_frame_flange``); unknown ``T_frame_camera``; flange method: ``P_i f = X c_i``.
* **moving camera** (eye-in-hand eq. 1; eye-on-arm with the marker fixed in the cell, eq. 7;
  co-manipulation eq. 6a): the camera rides on the carrier ``P_i`` (``T_base_carrier``); unknown
  ``T_carrier_camera``; flange method: ``P_i X c_i = g`` i.e. ``X c_i = inv(P_i) g``.

Co-manipulation is decomposed as eq. 6: (a) a moving-camera problem for robot 1 with robot 2 parked,
(b) a fixed-camera problem for robot 2 with robot 1 parked, (c) ``T_base1_base2 = T_base1_flange1
T_flange1_camera inv(T_base2_camera)``.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
from weldcell.plugins.handeye import classical, diagnostics
from weldcell.plugins.handeye.circle import PAPER_E_D, PAPER_E_R, PAPER_K_MAX, PAPER_RADIUS
from weldcell.plugins.handeye.flange_method import (  # noqa: F401  (measure_flange_centre re-exported)
    measure_flange_centre,
    solve_flange,
)
from weldcell.sdk.errors import DataError, UsageError
from weldcell.sdk.geometry import invert, rotation_angle
from weldcell.sdk.handeye_files import CONFIGS, HandEyeResult, HandEyeSample, config_name

FLANGE_METHODS = ("flange", "flange-svd", "flange-iterative")
METHODS = FLANGE_METHODS + classical.HAND_EYE_METHODS + classical.ROBOT_WORLD_METHODS

DEFAULTS: dict = {
    "feature": "tcp",  # fixed camera: the feature in the flange frame ("tcp" = [0,0,0], xyz, or "estimate")
    "feature_base": "origin",  # moving camera: the fixed feature in the base ("origin", xyz, or "estimate")
    "allow_coplanar": False,
    # feature estimated: weight of the centre's component along its face normal (sample meta "normal",
    # camera frame, or the circle fit's) against the in-plane ones; 1 = plain point fit (featurefit)
    "normal_weight": 1.0,
    "min_samples": 4,
    "inlier_threshold": None,  # m; None = robust (n_sigma x MAD-based sigma)
    "n_sigma": 3.0,
    "min_threshold": 0.0003,  # m; floor of the automatic inlier threshold (scanner precision)
    "cloud_units": "m",
    "circle": {"radius": PAPER_RADIUS, "e_d": PAPER_E_D, "e_r": PAPER_E_R, "k_max": PAPER_K_MAX},
    "segment": {},
    "verifier": "consensus",  # Algorithm 1: "consensus", "icp" (with "verification"), or a callable
    "verification": None,
    "cost": "translation",  # or "radius" (§4.2, with work_radius)
    "work_radius": 0.3,
    "e_required": 0.0,
    "k_max": 10_000,
    "compensate": False,
    "inner": "best",  # Algorithm 1 inner loop: "best" of the four replacements, or "sequential" (as listed)
    "search": "published",  # Algorithm 1 pool search: "published", or "wide" (+ `budget` 4-subsets a pair)
    "budget": 64,
    "refit": None,  # after Algorithm 1: refit on the pairs within refit x the pool's residual scale (3.0)
    "resolve_translation": False,  # target-based: re-solve the translation once the rotation is fixed
    "bootstrap": 100,
    "backend": "auto",
    "board": None,
    "intrinsics": None,  # (K, dist) for board photos
    "calibrate_intrinsics": False,  # no intrinsics: calibrate them from the board photos (Zhang)
    "seed": 0,
    # Algorithm 1 takes no new pair after this many verifier calls (bounded run time, repeatable)
    "max_verifications": 2000,
    "time_limit": None,  # s: the same cut by wall-clock time (not repeatable: depends on the host's load)
}


def _settings(user: dict) -> dict:
    unknown = set(user) - set(DEFAULTS)
    if unknown:
        raise UsageError(
            f"unknown hand-eye settings {sorted(unknown)}", f"known settings: {', '.join(DEFAULTS)}"
        )
    s = {**DEFAULTS, **user}
    s["circle"] = {**DEFAULTS["circle"], **(user.get("circle") or {})}
    return s


def _solve(
    kind: str,
    P: np.ndarray | None,
    samples: list[HandEyeSample],
    method: str,
    s: dict,
    p_base: np.ndarray | None = None,
) -> dict:
    """Solve one fixed-camera or moving-camera sub-problem; returns X, residuals, inliers, extra."""
    if method in FLANGE_METHODS:
        return solve_flange(kind, P, samples, method, s, p_base)
    return _solve_target(kind, P, samples, method, s)


def _solve_target(
    kind: str, P: np.ndarray | None, samples: list[HandEyeSample], method: str, s: dict
) -> dict:
    """The target-based methods (a calibration board): AX=XB or AX=YB on the board's poses."""
    from weldcell.plugins.handeye.board import board_poses

    warnings: list[str] = []
    metrics: dict = {}
    C = board_poses(samples, s, metrics)
    if P is None:
        raise DataError("target-based methods need robot poses", "give T_base_flange for every sample")
    seen = np.all(np.isfinite(C.reshape(len(C), -1)), axis=1)
    if not seen.all():
        warnings += [f"board not found, sample skipped: {m}" for m in metrics.get("board_not_found", [])]
        P, C = P[seen], C[seen]
    diagnostics.check_finite("robot poses", P)
    diagnostics.check_finite("board poses", C)
    diagnostics.check_units("robot positions", P[:, :3, 3])
    diagnostics.check_units("board positions", C[:, :3, 3])
    warnings += diagnostics.check_rotation_diversity(P[:, :3, :3])
    cfg = "eye-on-base" if kind == "fixed" else "eye-in-hand"
    solver = classical.solve_hand_eye if method in classical.HAND_EYE_METHODS else classical.solve_robot_world
    X, info = solver(P, C, cfg, method, backend=s["backend"], resolve_translation=s["resolve_translation"])
    res = info.pop("residuals")
    metrics["backend"] = info.pop("backend")
    if s["bootstrap"]:
        metrics["bootstrap"] = diagnostics.bootstrap(
            lambda i: solver(
                P[i], C[i], cfg, method, backend=s["backend"], resolve_translation=s["resolve_translation"]
            )[0],
            len(P),
            min(s["bootstrap"], 50),
            s["seed"],
        )
    res_full = np.full(len(seen), np.nan)
    res_full[seen] = res
    return {
        "X": X,
        "residuals": res_full,
        "inliers": seen.copy(),
        "extra": info,
        "metrics": metrics,
        "warnings": warnings,
    }


def _poses(samples, attr) -> np.ndarray | None:
    vals = [getattr(x, attr) for x in samples]
    if all(v is None for v in vals):
        return None
    if any(v is None for v in vals):
        raise DataError(f"some samples lack {attr}", f"give {attr} for every sample or for none")
    return np.array(vals, float)


def calibrate(samples, config: str | None = None, method: str = "flange", **settings) -> HandEyeResult:
    """Hand-eye calibration for ``config`` in {eye-on-base, eye-in-hand, eye-on-arm, co-manipulation}.

    ``method``: "flange" (flange centres, outlier-proof least-median fit refined by eqs. 10-12 on the
    inliers — the default), "flange-svd" (eqs. 9-12 on all samples, the paper's Table 1 baseline),
    "flange-iterative" (Algorithm 1), "tsai"/"park"/"horaud"/"andreff"/"daniilidis" (AX=XB) or
    "shah"/"li" (AX=YB) from board poses or images. ``samples``: a list of
    :class:`HandEyeSample` or a SampleSet (its config is used when ``config`` is None). Settings and
    defaults: :data:`DEFAULTS`. Raises DataError for unusable data (too few, NaN, mixed units,
    coplanar/collinear, rotation-poor), UsageError for wrong settings.
    """
    if hasattr(samples, "samples"):
        config = config or samples.config
        samples = samples.samples
    config = config_name(config or "eye-on-base")
    method = method.lower()
    if method not in METHODS:
        raise UsageError(f"unknown hand-eye method '{method}'", f"use one of {', '.join(METHODS)}")
    s = _settings(settings)
    samples = list(samples)
    if not samples:
        raise DataError("no samples", "collect robot poses with flange scans or board views")
    name = CONFIGS[config][0]
    if config == "co-manipulation":
        return _co_manipulation(samples, method, s, name)
    r = _solve_config(config, samples, method, s)
    res = np.asarray(r["residuals"], float)
    inl = np.asarray(r["inliers"], bool)
    metrics = dict(r["metrics"])
    ok = np.isfinite(res)
    if inl.any():
        metrics["rms_inliers_m"] = float(np.sqrt(np.mean(res[inl] ** 2)))
        metrics["max_inlier_m"] = float(np.max(res[inl]))
    metrics["mean_all_m"] = float(np.mean(res[ok])) if ok.any() else float("nan")
    metrics["n_samples"], metrics["n_inliers"] = len(samples), int(inl.sum())
    return HandEyeResult(
        T=r["X"],
        name=name,
        config=config,
        method=method,
        residuals=res,
        inliers=inl,
        metrics=metrics,
        settings=_public(s),
        extra=r["extra"],
        warnings=r["warnings"],
    )


def _co_manipulation(samples: list[HandEyeSample], method: str, s: dict, name: str) -> HandEyeResult:
    """Eq. 6: phase a (robot 1 moves, robot 2 parked) and phase b (robot 1 parked, robot 2 moves) solved
    apart, then chained through robot 1's parked flange."""
    config = "co-manipulation"
    a = [x for x in samples if x.phase == "a"]
    b = [x for x in samples if x.phase == "b"]
    if not a or not b:
        raise DataError(
            f"co-manipulation needs phase 'a' and 'b' samples (got {len(a)} and {len(b)})",
            "phase a: robot 1 moves, robot 2 parked; phase b: robot 1 parked, robot 2 moves (eq. 6)",
        )
    if method in FLANGE_METHODS and s["feature_base"] == "origin":
        s["feature_base"] = "estimate"  # robot 2's parked flange is not at robot 1's base origin
    ra = _solve("moving", _poses(a, "T_base_flange"), a, method, s)
    rb = _solve("fixed", _poses(b, "T_base2_flange2"), b, method, s)
    P1 = _poses(b, "T_base_flange")
    if P1 is None:
        raise DataError("phase b samples need robot 1's parked T_base_flange", "record it with every sample")
    moved = max(rotation_angle(invert(P1[0]) @ p) for p in P1)
    if moved > 1e-3 or np.ptp(P1[:, :3, 3], axis=0).max() > 1e-4:
        raise DataError("robot 1 moved during phase b", "park robot 1 while robot 2 moves (eq. 6b)")
    T_f1c, T_b2c = ra["X"], rb["X"]
    X = P1[0] @ T_f1c @ invert(T_b2c)  # eq. 6c
    return HandEyeResult(
        T=X,
        name=name,
        config=config,
        method=method,
        residuals=np.r_[ra["residuals"], rb["residuals"]],
        inliers=np.r_[ra["inliers"], rb["inliers"]],
        metrics={"phase_a": ra["metrics"], "phase_b": rb["metrics"]},
        settings=_public(s),
        extra={
            "T_flange1_camera": T_f1c,
            "T_base2_camera": T_b2c,
            **{f"a_{k}": v for k, v in ra["extra"].items()},
            **{f"b_{k}": v for k, v in rb["extra"].items()},
        },
        warnings=ra["warnings"] + rb["warnings"],
    )


def _solve_config(config: str, samples: list[HandEyeSample], method: str, s: dict) -> dict:
    """The one sub-problem of eye-on-base, eye-in-hand and eye-on-arm (eqs. 7-8)."""
    G = _poses(samples, "T_base_flange")
    if config == "eye-on-base":
        r = _solve("fixed", G, samples, method, s, p_base=_poses(samples, "p_base"))
    elif config == "eye-in-hand":
        if G is None:
            raise DataError("eye-in-hand needs T_base_flange for every sample", "record the flange poses")
        r = _solve("moving", G, samples, method, s)
    else:  # eye-on-arm
        A = _poses(samples, "T_base_arm")
        if A is None:
            raise DataError(
                "eye-on-arm needs T_base_arm (pose of the camera link) for every sample",
                "read it from the robot's forward kinematics",
            )
        if G is not None:  # eq. 8: marker on the flange, seen from the arm link
            r = _solve("fixed", np.einsum("nij,njk->nik", np.linalg.inv(A), G), samples, method, s)
        else:  # eq. 7: marker fixed in the cell
            r = _solve("moving", A, samples, method, s)
    return r


def _public(s: dict) -> dict:
    out = {}
    for k, v in s.items():
        if k == "verifier" and callable(v):
            out[k] = type(v).__name__
        elif k in ("verification", "intrinsics"):
            out[k] = None if v is None else "given"
        elif k == "board" and v is not None and not isinstance(v, dict):
            out[k] = asdict(v)
        else:
            out[k] = v
    return out
