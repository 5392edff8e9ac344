"""Diagnostics for hand-eye data and results: input checks (NaN, units, too few samples, coplanar
or collinear points, rotation/translation spread), residuals, and bootstrap confidence."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.handeye_files import MIN_MEDIAN_DISTANCE, check_units  # noqa: F401 (re-exported)


def check_finite(name: str, arr: np.ndarray) -> None:
    """DataError naming the samples with NaN/inf values."""
    a = np.asarray(arr, float)
    bad = ~np.all(np.isfinite(a.reshape(len(a), -1)), axis=1)
    if bad.any():
        raise DataError(
            f"{name} has NaN or infinite values in samples {np.flatnonzero(bad).tolist()[:10]}",
            "drop those samples (failed flange detection or robot read-out) and run again",
        )


def point_spread(points: np.ndarray) -> dict:
    """Extent (m) and planarity of a point set: singular values of the centred points (RMS along
    principal axes), ``planarity = s3/s1`` and ``linearity = s2/s1``."""
    P = np.asarray(points, float).reshape(-1, 3)
    s = np.linalg.svd(P - P.mean(0), compute_uv=False) / np.sqrt(max(len(P), 1))
    s = np.r_[s, np.zeros(3 - len(s))]
    return {
        "extent": float(np.max(np.ptp(P, axis=0))) if len(P) else 0.0,
        "rms_axes": s.tolist(),
        "linearity": float(s[1] / s[0]) if s[0] > 0 else 0.0,
        "planarity": float(s[2] / s[0]) if s[0] > 0 else 0.0,
    }


def rotation_spread(R: np.ndarray) -> float:
    """Largest angle (rad) between any two of the rotations (n, 3, 3) (exact for n <= 200, sampled
    against the extreme ones beyond)."""
    rot = Rotation.from_matrix(np.asarray(R).reshape(-1, 3, 3))
    q = rot.as_quat()
    dots = np.abs(q @ q.T)
    return float(2 * np.arccos(np.clip(dots.min(), -1, 1)))


def check_point_diversity(
    points: np.ndarray,
    min_samples: int = 4,
    min_extent: float = 0.02,
    min_linearity: float = 0.05,
    min_planarity: float = 0.02,
    allow_coplanar: bool = False,
    what: str = "flange positions",
) -> list[str]:
    """Checks for a point-based fit (eq. 9): enough samples, spread, not collinear, not coplanar
    (the paper's "at least four non-coplanar points"). Returns warnings; raises DataError."""
    P = np.asarray(points, float).reshape(-1, 3)
    if len(P) < min_samples:
        raise DataError(
            f"{len(P)} samples; the flange fit needs at least {min_samples} (non-coplanar)",
            "collect more robot poses spread over the work volume",
        )
    sp = point_spread(P)
    if sp["extent"] < min_extent:
        raise DataError(
            f"the {what} span only {sp['extent'] * 1e3:.1f} mm",
            f"move the robot over at least {min_extent * 1e3:.0f} mm (ideally the whole work volume)",
        )
    if sp["linearity"] < min_linearity:
        raise DataError(
            f"the {what} are collinear (spread ratio {sp['linearity']:.3f}); rotation about the "
            "line is undetermined",
            "add poses off that line, in all three directions",
        )
    warnings = []
    if sp["planarity"] < min_planarity:
        msg = (
            f"the {what} are nearly coplanar (thickness/extent {sp['planarity']:.4f}); the rotation is "
            "weakly determined"
        )
        if not allow_coplanar:
            raise DataError(
                msg,
                "add poses at other heights (the paper asks for non-coplanar points), "
                "or pass allow_coplanar=True to accept a plane-only data set",
            )
        warnings.append(msg)
    return warnings


def check_rotation_diversity(
    R: np.ndarray, min_angle: float = np.radians(5), warn_angle: float = np.radians(20), min_samples: int = 3
) -> list[str]:
    """Checks for the AX=XB / AX=YB solvers: at least ``min_samples`` poses and a rotation spread of
    ``min_angle`` (DataError) / ``warn_angle`` (warning) between the robot poses."""
    R = np.asarray(R, float).reshape(-1, 3, 3)
    if len(R) < min_samples:
        raise DataError(
            f"{len(R)} poses; AX=XB solvers need at least {min_samples}",
            "collect more poses with different orientations",
        )
    spread = rotation_spread(R)
    if spread < min_angle:
        raise DataError(
            f"the robot orientations differ by at most {np.degrees(spread):.2f} deg",
            f"rotate the flange by more than {np.degrees(min_angle):.0f} deg about two axes between poses",
        )
    if spread < warn_angle:
        return [f"small rotation spread ({np.degrees(spread):.1f} deg): the rotation estimate will be noisy"]
    return []


def bootstrap(
    fit: Callable[[np.ndarray], np.ndarray],
    n: int,
    n_boot: int = 100,
    rng: np.random.Generator | int | None = 0,
) -> dict:
    """Bootstrap confidence of a 4x4 fit: ``fit(indices)`` on ``n_boot`` resamples (with
    replacement) of ``n`` samples; std of the translation (m, per axis and norm) and rotation (rad)
    about the mean."""
    rng = np.random.default_rng(rng)
    Ts = []
    for _ in range(n_boot):
        idx = rng.integers(0, n, n)
        try:
            Ts.append(fit(idx))
        except Exception:  # noqa: BLE001 - a degenerate resample is skipped
            continue
    if len(Ts) < 3:
        return {"n": len(Ts)}
    Ts = np.asarray(Ts)
    t = Ts[:, :3, 3]
    rot = Rotation.from_matrix(Ts[:, :3, :3])
    ang = (rot.mean().inv() * rot).magnitude()
    return {
        "n": len(Ts),
        "t_std": np.std(t, axis=0).tolist(),
        "t_std_norm": float(np.sqrt(np.sum(np.var(t, axis=0)))),
        "rot_std": float(np.sqrt(np.mean(ang**2))),
    }


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def point_fit_covariance(src: np.ndarray, dst: np.ndarray, T: np.ndarray) -> dict:
    """First-order covariance of a rigid point fit ``dst ≈ T src`` (eqs. 10-12) from its own residuals.

    With ``y_i = T src_i``, centroid ``ȳ`` and ``q_i = y_i - ȳ``, a small rotation δθ and a shift δc
    of the centroid move ``y_i`` by ``δθ × q_i + δc``; with isotropic noise σ (estimated as
    ``Σ|r|² / (3n - 6)``) the information is ``Σ(|q|² I - q qᵀ) / σ²`` for δθ and ``n / σ²`` for δc
    (uncorrelated because Σq = 0). The translation of ``T`` (the camera origin) sits at lever arm
    ``d = t - ȳ``: ``Cov(t) = [d]× Cov(θ) [d]×ᵀ + σ²/n I``. Unlike a bootstrap this stays honest for
    few or coplanar/clustered samples, where resamples that miss the one off-line sample are
    degenerate. Returns std of t (m, per axis and norm), rotation std (rad, RMS angle), σ, dof and the
    least-determined rotation axis (base frame) with its std."""
    src = np.asarray(src, float).reshape(-1, 3)
    dst = np.asarray(dst, float).reshape(-1, 3)
    n = len(src)
    dof = 3 * n - 6
    if n < 3 or dof <= 0:
        return {"n": n}
    y = src @ T[:3, :3].T + T[:3, 3]
    r = y - dst
    s2 = float(np.sum(r**2) / dof)
    q = y - y.mean(0)
    A = np.sum(np.einsum("ni,ni->n", q, q)) * np.eye(3) - q.T @ q
    if np.linalg.cond(A) > 1e12:
        return {"n": n, "sigma": float(np.sqrt(s2)), "degenerate": True}
    C_rot = s2 * np.linalg.inv(A)
    D = _skew(T[:3, 3] - y.mean(0))
    C_t = D @ C_rot @ D.T + s2 / n * np.eye(3)
    w, V = np.linalg.eigh(C_rot)
    return {
        "n": n,
        "sigma": float(np.sqrt(s2)),
        "dof": dof,
        "t_std": np.sqrt(np.diag(C_t)).tolist(),
        "t_std_norm": float(np.sqrt(np.trace(C_t))),
        "rot_std": float(np.sqrt(np.trace(C_rot))),
        "weak_axis": V[:, -1].tolist(),
        "weak_rot_std": float(np.sqrt(w[-1])),
    }


def leave_one_out(fit: Callable[[np.ndarray], np.ndarray], T: np.ndarray, n: int) -> list[float | None]:
    """How far the camera origin moves (m) when each sample is left out: ``fit(indices)`` on the other
    n-1; None where that fit fails (the rest is degenerate)."""
    out: list[float | None] = []
    for i in range(n):
        try:
            Ti = fit(np.r_[0:i, i + 1 : n])
            out.append(float(np.linalg.norm(Ti[:3, 3] - T[:3, 3])))
        except Exception:  # noqa: BLE001 - a degenerate subset has no fit
            out.append(None)
    return out


#: below this many samples, or with a spread ratio under these, a bootstrap is not trusted
BOOTSTRAP_MIN_SAMPLES = 15
BOOTSTRAP_MIN_PLANARITY = 0.05
BOOTSTRAP_MIN_LINEARITY = 0.2


def point_confidence(
    src: np.ndarray,
    dst: np.ndarray,
    T: np.ndarray,
    fit: Callable[[np.ndarray], np.ndarray],
    n_boot: int = 100,
    rng: np.random.Generator | int | None = 0,
) -> dict:
    """The confidence of a point fit: the analytic covariance (:func:`point_fit_covariance`) always,
    the leave-one-out shifts, and a bootstrap only where it is meaningful (at least
    :data:`BOOTSTRAP_MIN_SAMPLES` samples spread in 3-D). ``method`` says which one the summary
    quotes and ``why``; ``bootstrap`` is kept when it ran."""
    dst = np.asarray(dst, float).reshape(-1, 3)
    n = len(dst)
    out = {"analytic": point_fit_covariance(src, dst, T), "leave_one_out_m": leave_one_out(fit, T, n)}
    sp = point_spread(dst)
    reasons = []
    if n < BOOTSTRAP_MIN_SAMPLES:
        reasons.append(f"{n} samples")
    if sp["planarity"] < BOOTSTRAP_MIN_PLANARITY:
        reasons.append(f"coplanar (thickness/extent {sp['planarity']:.3f})")
    if sp["linearity"] < BOOTSTRAP_MIN_LINEARITY:
        reasons.append(f"clustered near a line (spread ratio {sp['linearity']:.3f})")
    if n_boot and not reasons:
        out["bootstrap"] = bootstrap(fit, n, n_boot, rng)
    use_boot = "t_std" in out.get("bootstrap", {}) and "t_std" in out["analytic"]
    if use_boot:  # the larger of the two: the bootstrap also sees non-Gaussian noise
        use_boot = out["bootstrap"]["t_std_norm"] >= out["analytic"]["t_std_norm"]
    out["method"] = "bootstrap" if use_boot else "analytic"
    out["why"] = (
        "bootstrap over well-spread samples"
        if use_boot
        else "first-order covariance from the residuals"
        + (f" (bootstrap unreliable: {', '.join(reasons)})" if reasons else "")
    )
    return out


def spread_back(values: list, idx_in: np.ndarray, n_samples: int, keep: list[int]) -> list:
    """Per-inlier values put back at their sample positions (None elsewhere)."""
    out: list = [None] * n_samples
    for j, v in zip(idx_in, values, strict=True):
        out[keep[j]] = v
    return out


def influence_warnings(conf: dict, ids: list[str]) -> list[str]:
    """A warning when leaving one sample out moves the camera by more than 3 sigma of the analytic
    confidence: the answer rests on that sample alone (e.g. the only pose off a line)."""
    a = conf.get("analytic", {})
    loo = conf.get("leave_one_out_m", [])
    if "t_std_norm" not in a:
        return []
    big = [(i, v) for i, v in enumerate(loo) if v is None or v > max(3 * a["t_std_norm"], 1e-3)]
    if not big:
        return []
    i, v = max(big, key=lambda p: np.inf if p[1] is None else p[1])
    moved = "leaves a degenerate set" if v is None else f"moves the camera by {v * 1e3:.1f} mm"
    return [
        f"the result rests on few samples: leaving out sample {ids[i]} {moved} "
        f"(1 sigma {a['t_std_norm'] * 1e3:.2f} mm); add poses away from the others"
    ]
