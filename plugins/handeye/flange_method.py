"""The flange methods of :func:`~weldcell.plugins.handeye.calibrate.calibrate` (``flange``, ``flange-svd``,
``flange-iterative``): flange centres measured in the camera (segmentation + RANSAC circle) fitted against
the feature's position, known or estimated too, with Algorithm 1's pool search, plausibility checks and
the fit's confidence (leave-one-out, bootstrap).
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
from weldcell.plugins.handeye import diagnostics
from weldcell.plugins.handeye.circle import ransac_circle
from weldcell.plugins.handeye.featurefit import fit_with_unknown_point
from weldcell.plugins.handeye.iterative import PoolOptions, run_pool
from weldcell.plugins.handeye.segmentation import SegmentSettings, segment_flange
from weldcell.plugins.handeye.verification import (
    ConsensusVerifier,
    IcpVerifier,
    radius_cost,
    translation_cost,
)
from weldcell.sdk.cloud import UNIT_SCALE, read_cloud
from weldcell.sdk.errors import DataError, UsageError
from weldcell.sdk.handeye_files import HandEyeSample, sample_id
from weldcell.sdk.pointfit import robust_point_fit, scaled_svd_fit


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


def solve_flange(
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


def _algorithm1(kind: str, P, c: np.ndarray, dst: np.ndarray, s: dict):
    """Algorithm 1 with the configured verifier (ICP falling back to consensus when eq. 13 cannot
    verify); returns X, residuals, inliers (the pool) and the metrics (with ``warnings``)."""
    cost = translation_cost if s["cost"] == "translation" else radius_cost(float(s["work_radius"]))
    verifier, sees = _algorithm1_verifier(kind, c, dst, s)
    warnings: list[str] = []
    used = "consensus" if sees else ("icp" if isinstance(verifier, IcpVerifier) else "callable")
    if isinstance(verifier, IcpVerifier):  # can eq. 13 verify even the best estimate there is?
        H0 = robust_point_fit(c, dst, n_sigma=s["n_sigma"], min_threshold=s["min_threshold"], rng=s["seed"]).T
        if verifier(H0) is None:
            warnings.append(_icp_failed(verifier, "even at the all-pairs fit"))
            verifier, sees, used = ConsensusVerifier(c, dst), True, "consensus (ICP failed)"
    pr = run_pool(c, dst, verifier, cost, _pool_options(s, sees))
    if not np.isfinite(pr.cost) and isinstance(verifier, IcpVerifier):
        warnings.append(_icp_failed(verifier, "for any pool"))
        pr = run_pool(c, dst, ConsensusVerifier(c, dst), cost, _pool_options(s, True))
        used = "consensus (ICP failed)"
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


def _algorithm1_verifier(kind: str, c: np.ndarray, dst: np.ndarray, s: dict):
    """(verifier, whether it is called with the number of pairs seen) for ``s["verifier"]``: the
    consensus one, eq. 13's ICP against the flange model (fixed camera only), or a callable."""
    v = s["verifier"]
    if v == "consensus":
        return ConsensusVerifier(c, dst), True
    if v == "icp":
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
        return verifier, False
    if callable(v):
        return v, False
    raise UsageError(f"unknown verifier {v!r}", "use 'consensus', 'icp' or a callable H -> e")


def _pool_options(s: dict, sees_count: bool) -> PoolOptions:
    """Algorithm 1's options from the calibrate settings. A verifier that sees the pair count but is
    not the configured consensus one (the ICP fallback) runs to the end of the data (e_required 0)."""
    return PoolOptions(
        e_required=float(s["e_required"]) if not sees_count or s["verifier"] == "consensus" else 0.0,
        k_max=int(s["k_max"]),
        verifier_sees_count=sees_count,
        inner=s["inner"],
        refit=s["refit"],
        search=s["search"],
        budget=int(s["budget"]),
        seed=s["seed"],
        time_limit=s["time_limit"],
        max_verifications=s["max_verifications"],
    )


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
