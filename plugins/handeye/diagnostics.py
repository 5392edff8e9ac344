"""Diagnostics for hand-eye data and results: input checks (NaN, units, too few samples, coplanar
or collinear points, rotation/translation spread), residuals, and bootstrap confidence."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError


def check_finite(name: str, arr: np.ndarray) -> None:
    """DataError naming the samples with NaN/inf values."""
    a = np.asarray(arr, float)
    bad = ~np.all(np.isfinite(a.reshape(len(a), -1)), axis=1)
    if bad.any():
        raise DataError(
            f"{name} has NaN or infinite values in samples {np.flatnonzero(bad).tolist()[:10]}",
            "drop those samples (failed flange detection or robot read-out) and run again",
        )


def check_units(name: str, points: np.ndarray, units: str = "m", max_range: float = 20.0) -> None:
    """Refuse points that cannot be metres (a camera or robot coordinate beyond ``max_range`` m), and
    columns where some samples are ~1000x the others (a mm/m mix within one data set)."""
    P = np.asarray(points, float).reshape(-1, 3)
    norms = np.linalg.norm(P, axis=1)
    if units == "m" and np.any(norms > max_range):
        big = np.flatnonzero(norms > max_range)
        if len(big) == len(P):
            raise DataError(
                f"{name} is up to {norms.max():.4g} units from the origin; that is millimetres, not metres",
                "declare units 'mm' (the reader scales to metres) or divide by 1000",
            )
        raise DataError(
            f"{name}: samples {big.tolist()[:10]} are ~1000x farther than the others (mixed mm and m)",
            "convert those samples to metres (divide by 1000) or re-export them in one unit",
        )
    med = float(np.median(norms)) if len(norms) else 0.0
    if med > 0:
        ratio = norms / med
        odd = np.flatnonzero((ratio > 100) | (ratio < 0.01))
        if len(odd):
            raise DataError(
                f"{name}: samples {odd.tolist()[:10]} differ from the median distance by >100x (mixed units)",
                "convert every sample to one unit (metres) before calibrating",
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
