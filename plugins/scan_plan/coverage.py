"""How much of each seam a weld path covers: against the simulated cell's true seams, or against the
seam lengths the operator expects. A seam found over 119 of its 493 mm is a partial seam, not a found one.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

#: a true seam point counts as found when a found seam passes within this distance (m): the 2 mm cell
#: of eq. 21's rasterised F1
COVERAGE_TOL = 0.002


def _densify(points: np.ndarray, closed: bool, step: float = 5e-4) -> np.ndarray:
    """A polyline's points every ``step`` (m) or closer (linear)."""
    P = np.vstack([points, points[:1]]) if closed and len(points) > 1 else np.asarray(points, dtype=float)
    if len(P) < 2:
        return P
    seg = np.diff(P, axis=0)
    n = np.maximum(1, np.ceil(np.linalg.norm(seg, axis=1) / step)).astype(int)
    t = np.concatenate([np.arange(k) / k for k in n])
    return np.vstack([np.repeat(P[:-1], n, axis=0) + t[:, None] * np.repeat(seg, n, axis=0), P[-1:]])


def seam_coverage(weld_path, gt, tol: float = COVERAGE_TOL) -> list[dict]:
    """Per true seam: its length, the length of it the found seams cover (points within ``tol``, m) and
    that fraction, so a seam found over 119 of its 493 mm is not counted as found."""
    found = [_densify(s.points, s.closed) for s in weld_path.seams]
    tree = cKDTree(np.vstack(found)) if found else None
    out = []
    for name, truth in gt:
        P = np.vstack([truth.points, truth.points[:1]]) if truth.closed else truth.points
        seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
        hit = np.zeros(len(P), dtype=bool) if tree is None else tree.query(P, k=1)[0] <= tol
        covered = float(seg[hit[:-1] & hit[1:]].sum())
        total = float(seg.sum())
        out.append(
            {
                "seam": f"{name}/{truth.id}",
                "length_mm": round(total * 1e3, 1),
                "found_mm": round(covered * 1e3, 1),
                "fraction": round(covered / total, 4) if total > 0 else 0.0,
            }
        )
    return out


def expected_coverage(weld_path, lengths: list[float]) -> list[dict]:
    """Found seams (longest first) against the expected seam lengths (longest first); an expected seam
    without a found one is covered 0."""
    found = sorted((s.length for s in weld_path.seams), reverse=True)
    out = []
    for i, L in enumerate(sorted(lengths, reverse=True)):
        f = min(found[i], L) if i < len(found) else 0.0
        out.append(
            {
                "seam": f"expected #{i + 1}",
                "length_mm": round(L * 1e3, 1),
                "found_mm": round(f * 1e3, 1),
                "fraction": round(f / L, 4),
            }
        )
    return out


def partial_seams(coverage: list[dict], minimum: float) -> list[str]:
    """One line per seam found over less than ``minimum`` of its length (not found at all included)."""
    return [
        f"seam {c['seam']}: found {c['found_mm']:.0f} of {c['length_mm']:.0f} mm "
        f"({100 * c['fraction']:.0f} %)"
        for c in coverage
        if c["fraction"] < minimum
    ]
