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

from dataclasses import asdict, fields
from pathlib import Path

import numpy as np
from weldcell.plugins.handeye import classical, diagnostics
from weldcell.plugins.handeye.circle import PAPER_E_D, PAPER_E_R, PAPER_K_MAX, PAPER_RADIUS, ransac_circle
from weldcell.plugins.handeye.featurefit import fit_with_unknown_point
from weldcell.plugins.handeye.iterative import iterative_pool
from weldcell.plugins.handeye.segmentation import SegmentSettings, segment_flange
from weldcell.plugins.handeye.verification import (
    ConsensusVerifier,
    IcpVerifier,
    radius_cost,
    translation_cost,
)
from weldcell.sdk.cloud import UNIT_SCALE, read_cloud
from weldcell.sdk.errors import DataError, UsageError
from weldcell.sdk.geometry import invert, rotation_angle
from weldcell.sdk.handeye_files import CONFIGS, HandEyeResult, HandEyeSample, config_name, sample_id
from weldcell.sdk.pointfit import robust_point_fit, scaled_svd_fit

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


def _point(value, default_name: str) -> np.ndarray | str:
    if isinstance(value, str):
        if value == "estimate":
            return "estimate"
        if value in ("tcp", "origin"):
            return np.zeros(3)
        raise UsageError(
            f"{default_name}: unknown value '{value}'", "give [x, y, z] in metres, 'estimate' or the default"
        )
    p = np.asarray(value, float).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise UsageError(f"{default_name} must be 3 numbers in metres", "e.g. [0, 0, 0.012]")
    return p


def measure_flange_centre(cloud, s: dict) -> tuple[np.ndarray, dict]:
    """Flange centre in the camera (m) from a raw scan: segmentation then RANSAC circle."""
    if isinstance(cloud, str | Path):
        pts = read_cloud(cloud, units=s["cloud_units"], frame="camera").points
    else:
        pts = np.asarray(getattr(cloud, "points", cloud), float) * UNIT_SCALE[s["cloud_units"]]
    seg_fields = {f.name for f in fields(SegmentSettings)}
    bad = set(s["segment"]) - seg_fields
    if bad:
        raise UsageError(f"unknown segment settings {sorted(bad)}", f"known: {', '.join(sorted(seg_fields))}")
    seg = segment_flange(pts, SegmentSettings(**s["segment"]))
    circ = ransac_circle(seg.face, rng=s["seed"], **s["circle"])
    return circ.center, {
        "normal": circ.normal.tolist(),
        "segment": seg.report,
        "radius": circ.radius,
        "circle_rms": circ.rms,
        "support": circ.stats["support"],
    }


def _p_cam(samples: list[HandEyeSample], s: dict) -> tuple[np.ndarray, list[int], list[str], list[dict]]:
    pts, keep, warns, reports = [], [], [], []
    for i, smp in enumerate(samples):
        if smp.p_cam is not None:
            pts.append(np.asarray(smp.p_cam, float))
            keep.append(i)
            reports.append({})
            continue
        if smp.cloud is None:
            raise DataError(f"sample {i} has neither p_cam nor a cloud", "give the flange centre or the scan")
        ss = dict(s)
        ss["cloud_units"] = smp.meta.get("cloud_units", s["cloud_units"])
        try:
            c, rep = measure_flange_centre(smp.cloud, ss)
        except DataError as e:
            warns.append(f"sample {i}: flange not found, sample skipped ({e.message})")
            continue
        pts.append(c)
        keep.append(i)
        reports.append(rep)
    if not pts:
        raise DataError("the flange was not found in any scan", "check the segmentation and circle settings")
    return np.array(pts), keep, warns, reports


def _normals(samples: list[HandEyeSample], keep: list[int], reports: list[dict]) -> np.ndarray:
    """Face normals (camera frame) of the kept samples: their meta "normal" or the circle fit's."""
    out = [samples[i].meta.get("normal", rep.get("normal")) for i, rep in zip(keep, reports, strict=True)]
    missing = [keep[j] for j, v in enumerate(out) if v is None]
    if missing:
        raise DataError(
            f"normal_weight needs each sample's face normal; samples {missing[:10]} have none",
            "give meta['normal'] (camera frame) or a cloud for every sample, or set normal_weight = 1",
        )
    return np.asarray(out, float)


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
        return _solve_flange(kind, P, samples, method, s, p_base)
    return _solve_target(kind, P, samples, method, s)


def _solve_flange(
    kind: str, P: np.ndarray | None, samples: list[HandEyeSample], method: str, s: dict, p_base
) -> dict:
    """The flange methods: centres in the camera against the feature's position (known, or estimated
    too), with the fit's confidence (leave-one-out, bootstrap)."""
    warnings: list[str] = []
    metrics: dict = {}
    c, keep, w, reports = _p_cam(samples, s)
    warnings += w
    metrics["skipped_samples"] = [i for i in range(len(samples)) if i not in keep]
    if any(reports):
        metrics["flange_detection"] = reports
    diagnostics.check_finite("p_cam", c)
    diagnostics.check_units("p_cam", c)
    q = _point(
        s["feature"] if kind == "fixed" else s["feature_base"],
        "feature" if kind == "fixed" else "feature_base",
    )
    if P is not None:
        P = P[keep]
        diagnostics.check_finite("robot poses", P)
        diagnostics.check_units("robot positions", P[:, :3, 3])
    dst = None
    if isinstance(q, str):  # estimate the feature position too
        X, res, inl, extra, refit = _fit_unknown_feature(kind, P, c, samples, keep, reports, method, s)
    else:
        dst = _reference_points(kind, P, q, p_base, keep)
        X, res, inl, extra, refit = _fit_known_feature(kind, P, c, dst, method, s, metrics, warnings)
    n_in = int(np.sum(inl))
    warnings += _implausible_residuals(res[inl], q, kind)
    idx_in = np.flatnonzero(inl)
    if method != "flange-iterative" and not isinstance(q, str) and n_in >= 4:
        conf = diagnostics.point_confidence(
            c[idx_in], dst[idx_in], X, lambda i: refit(idx_in[i]), s["bootstrap"], s["seed"]
        )
        loo = conf["leave_one_out_m"]
        conf["leave_one_out_m"] = diagnostics.spread_back(loo, idx_in, len(samples), keep)
        metrics["confidence"] = conf
        if "bootstrap" in conf:
            metrics["bootstrap"] = conf["bootstrap"]
        warnings += diagnostics.influence_warnings(conf, [sample_id(x, k) for k, x in enumerate(samples)])
    elif s["bootstrap"] and n_in >= 5 and method != "flange-iterative":
        metrics["bootstrap"] = diagnostics.bootstrap(
            lambda i: refit(idx_in[i]), n_in, s["bootstrap"], s["seed"]
        )
    resid_full = np.full(len(samples), np.nan)
    inl_full = np.zeros(len(samples), bool)
    resid_full[keep], inl_full[keep] = res, inl
    return {
        "X": X,
        "residuals": resid_full,
        "inliers": inl_full,
        "extra": extra,
        "metrics": metrics,
        "warnings": warnings,
    }


def _fit_unknown_feature(
    kind: str, P, c: np.ndarray, samples, keep: list[int], reports, method: str, s: dict
):
    """``X`` and the feature's position together (:func:`fit_with_unknown_point`); returns X, residuals,
    inliers, extra and the refit used by the confidence."""
    if method == "flange-iterative":
        raise UsageError(
            "Algorithm 1 needs a known reference point", "give feature=[x,y,z] or use method 'flange'"
        )
    if P is None:
        raise DataError("estimating the feature needs robot poses, not only positions", "give T_base_flange")
    B = P if kind == "fixed" else np.linalg.inv(P)
    diagnostics.check_point_diversity(
        c, max(5, s["min_samples"]), allow_coplanar=s["allow_coplanar"], what="camera points"
    )
    N = _normals(samples, keep, reports) if s["normal_weight"] != 1.0 else None
    w = s["normal_weight"]
    ff = fit_with_unknown_point(
        c,
        B,
        robust=(method == "flange"),
        n_sigma=s["n_sigma"],
        min_threshold=s["min_threshold"],
        rng=s["seed"],
        normals=N,
        normal_weight=w,
    )
    extra = {"feature_flange" if kind == "fixed" else "feature_base": ff.q}

    def refit(idx):
        n_idx = None if N is None else N[idx]
        return fit_with_unknown_point(c[idx], B[idx], robust=False, normals=n_idx, normal_weight=w).T

    return ff.T, ff.residuals, ff.inliers, extra, refit


def _reference_points(kind: str, P, q: np.ndarray, p_base, keep: list[int]) -> np.ndarray:
    """The known feature in the frame the camera points are fitted to, one per kept sample."""
    if kind == "fixed":
        return p_base[keep] if P is None else P[:, :3, :3] @ q + P[:, :3, 3]
    Pi = np.linalg.inv(P)
    return Pi[:, :3, :3] @ q + Pi[:, :3, 3]


def _fit_known_feature(
    kind: str, P, c: np.ndarray, dst: np.ndarray, method: str, s: dict, metrics: dict, warnings: list[str]
):
    """``X`` from camera points ``c`` and reference points ``dst`` by the method (scaled SVD, robust fit or
    Algorithm 1); adds to ``metrics`` and ``warnings``. Returns X, residuals, inliers, extra, refit."""
    diagnostics.check_finite("reference points", dst)
    diagnostics.check_units("reference points", dst)
    warnings += diagnostics.check_point_diversity(dst, s["min_samples"], allow_coplanar=s["allow_coplanar"])
    full = scaled_svd_fit(c, dst)
    metrics["svd_scale"] = full.scale
    if abs(np.log10(max(full.scale, 1e-12))) > 1.5:
        raise DataError(
            f"camera and robot points differ in scale by {full.scale:.4g}x (mixed mm and m)",
            "declare the units of p_cam, clouds and robot poses so all are converted to metres",
        )
    if method == "flange-svd":
        X, res, inl = full.T, full.residuals, np.ones(len(c), bool)
        metrics["reflection_guarded"] = full.reflection_guarded
    elif method == "flange":
        rf = robust_point_fit(
            c,
            dst,
            threshold=s["inlier_threshold"],
            n_sigma=s["n_sigma"],
            min_threshold=s["min_threshold"],
            rng=s["seed"],
        )
        X, res, inl = rf.T, rf.residuals, rf.inliers
        metrics["inlier_threshold"] = rf.threshold
        metrics["robust_sigma"] = rf.sigma
    else:
        X, res, inl, m2 = _algorithm1(kind, P, c, dst, s)
        warnings += m2.pop("warnings")
        metrics.update(m2)

    def refit(idx):
        return scaled_svd_fit(c[idx], dst[idx]).T

    return X, res, inl, {}, refit


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


def _algorithm1(kind: str, P, c: np.ndarray, dst: np.ndarray, s: dict):
    cost = translation_cost if s["cost"] == "translation" else radius_cost(float(s["work_radius"]))
    v = s["verifier"]
    sees = False
    if v == "consensus":
        verifier, sees = ConsensusVerifier(c, dst), True
    elif v == "icp":
        ver = s["verification"] or {}
        if kind != "fixed" or not {"cloud", "T_base_flange", "model"} <= set(ver):
            raise UsageError(
                "the ICP verifier needs verification={'cloud', 'T_base_flange', 'model'} (fixed camera)",
                "give a verification scan, its robot pose and a flange model (flange_model module)",
            )
        cloud = ver["cloud"]
        if isinstance(cloud, str | Path):
            cloud = read_cloud(cloud, units=s["cloud_units"], frame="camera").points
        verifier = IcpVerifier(
            np.asarray(ver["model"], float),
            np.asarray(ver["T_base_flange"], float),
            np.asarray(cloud, float),
            **ver.get("icp", {}),
        )
    elif callable(v):
        verifier = v
    else:
        raise UsageError(f"unknown verifier {v!r}", "use 'consensus', 'icp' or a callable H -> e")
    warnings: list[str] = []
    used = "consensus" if sees else ("icp" if isinstance(verifier, IcpVerifier) else "callable")
    if isinstance(verifier, IcpVerifier):  # can eq. 13 verify even the best estimate there is?
        H0 = robust_point_fit(c, dst, n_sigma=s["n_sigma"], min_threshold=s["min_threshold"], rng=s["seed"]).T
        if verifier(H0) is None:
            warnings.append(_icp_failed(verifier, "even at the all-pairs fit"))
            verifier, sees, used = ConsensusVerifier(c, dst), True, "consensus (ICP failed)"

    def run(ver, sees_count: bool):
        return iterative_pool(
            c,
            dst,
            ver,
            cost,
            float(s["e_required"]) if not sees_count or v == "consensus" else 0.0,
            int(s["k_max"]),
            verifier_sees_count=sees_count,
            inner=s["inner"],
            refit=s["refit"],
            search=s["search"],
            budget=int(s["budget"]),
            seed=s["seed"],
            time_limit=s["time_limit"],
            max_verifications=s["max_verifications"],
        )

    pr = run(verifier, sees)
    if not np.isfinite(pr.cost) and isinstance(verifier, IcpVerifier):
        warnings.append(_icp_failed(verifier, "for any pool"))
        pr, used = run(ConsensusVerifier(c, dst), True), "consensus (ICP failed)"
    if pr.timed_out:
        warnings.append(
            f"Algorithm 1 stopped at its limit ({pr.events[-1]}) after {pr.n_used} of {len(c)} "
            "pairs; the pool is the best found so far (raise max_verifications/time_limit or thin the "
            "flange model)"
        )
    X = pr.H_compensated if (s["compensate"] and pr.H_compensated is not None) else pr.H
    if pr.H_refit is not None:
        X = pr.H_refit
    res = np.linalg.norm(c @ X[:3, :3].T + X[:3, 3] - dst, axis=1)
    inl = np.zeros(len(c), bool)
    inl[pr.pool] = True
    m = {
        "pool": pr.pool,
        "cost": pr.cost,
        "converged": pr.converged,
        "pairs_used": pr.n_used,
        "cost_history": pr.history.tolist(),
        "compensated": bool(s["compensate"] and pr.H_compensated is not None),
        "e_optimal": None if pr.e is None else pr.e,
        "refit_inliers": pr.refit_inliers,
        "verifier_used": used,
        "timed_out": pr.timed_out,
        "warnings": warnings,
    }
    return X, res, inl, m


def _icp_failed(verifier: IcpVerifier, when: str) -> str:
    return (
        f"the eq. 13 ICP verifier never matched the flange model to the verification scan {when} "
        f"({verifier.diagnosis()}); Algorithm 1 used the consensus verifier instead. Check the flange "
        "model (units, the face, its size against --flange-d1) and the verification sample"
    )


PLAUSIBLE_RMS = 0.005  # m: a 3-D scanner's flange centres agree with a right model far better than this


def _implausible_residuals(res: np.ndarray, q, kind: str) -> list[str]:
    """A warning when the fit's inlier residuals are far above any 3-D scanner's noise: the model
    (configuration, feature position, units) does not describe the data."""
    rms = float(np.sqrt(np.mean(res**2))) if len(res) else 0.0
    if rms <= PLAUSIBLE_RMS:
        return []
    where = "feature (flange frame)" if kind == "fixed" else "feature_base (the fixed feature in the base)"
    told = "estimated" if isinstance(q, str) else f"{np.round(np.asarray(q) * 1e3, 1).tolist()} mm"
    return [
        f"inlier residuals {rms * 1e3:.1f} mm rms, far above a scanner's noise: check the configuration, "
        f"the units and the {where}, now {told}"
    ]


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
