"""RANSAC circle fit on the flange plane (paper §2.1.4 second step, parameters of §3.2.2).

The flange face is projected onto its plane; its boundary points (outer rim and hole edges) are
found by the angular-gap test; 3-point circles (the minimal sample) are drawn, circles whose radius
is outside ``R ± e_r`` are rejected before verification (the paper's model check), and the circle
with the most boundary points within ``e_d`` wins. The winner is refined by a geometric
least-squares circle fit on its inliers. All ``k_max`` hypotheses are evaluated in one vectorized
pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from weldcell.sdk.errors import DataError

#: the paper's RANSAC parameters (§3.2.2), in metres
PAPER_RADIUS = 0.031
PAPER_E_D = 0.0003
PAPER_E_R = 0.001
PAPER_K_MAX = 10_000


@dataclass
class CircleFit:
    """A 3-D circle: ``center`` (3,), plane ``normal`` (3,, toward the camera), ``radius``, the
    indices of its inlier points in the input, and fit statistics."""

    center: np.ndarray
    normal: np.ndarray
    radius: float
    inliers: np.ndarray
    rms: float
    n_boundary: int
    n_hypotheses: int
    stats: dict = field(default_factory=dict)


def plane_basis(points: np.ndarray, toward: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Centroid and orthonormal basis (3x3, rows u, v, n) of the least-squares plane; ``n`` points
    toward ``toward`` (default: the origin, i.e. the camera)."""
    mu = points.mean(0)
    _, _, Vt = np.linalg.svd(points - mu, full_matrices=False)
    n = Vt[2]
    ref = (np.zeros(3) if toward is None else np.asarray(toward, float)) - mu
    if np.dot(n, ref) < 0:
        n = -n
    u = Vt[0]
    v = np.cross(n, u)
    return mu, np.stack([u, v, n])


def boundary_mask(xy: np.ndarray, k: int = 16, gap: float = np.pi / 2) -> np.ndarray:
    """Points on the boundary of a 2-D point set: the largest angular gap between a point's ``k``
    nearest neighbours exceeds ``gap``."""
    k = min(k, len(xy) - 1)
    tree = cKDTree(xy)
    _, nb = tree.query(xy, k + 1)
    d = xy[nb[:, 1:]] - xy[:, None, :]
    ang = np.sort(np.arctan2(d[..., 1], d[..., 0]), axis=1)
    gaps = np.diff(np.concatenate([ang, ang[:, :1] + 2 * np.pi], axis=1), axis=1)
    return gaps.max(axis=1) > gap


def _circumcircles(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ax, ay, bx, by, cx, cy = a[:, 0], a[:, 1], b[:, 0], b[:, 1], c[:, 0], c[:, 1]
    d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    with np.errstate(divide="ignore", invalid="ignore"):
        a2, b2, c2 = ax**2 + ay**2, bx**2 + by**2, cx**2 + cy**2
        ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
        uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    centers = np.stack([ux, uy], axis=1)
    return centers, np.linalg.norm(a - centers, axis=1)


def _refine_circle(xy: np.ndarray, c0: np.ndarray, r0: float, fix_radius: float | None):
    if fix_radius is not None:
        sol = least_squares(lambda p: np.linalg.norm(xy - p, axis=1) - fix_radius, c0)
        return sol.x, float(fix_radius)
    sol = least_squares(lambda p: np.linalg.norm(xy - p[:2], axis=1) - p[2], np.r_[c0, r0])
    return sol.x[:2], float(sol.x[2])


# parameters: the paper's RANSAC circle settings (R, e_d, e_r, k_max, ...), each a documented keyword
# (callers pass them as one settings mapping: handeye.flange's ``circle`` settings)
def ransac_circle(
    points: np.ndarray,
    radius: float = PAPER_RADIUS,
    e_d: float = PAPER_E_D,
    e_r: float = PAPER_E_R,
    k_max: int = PAPER_K_MAX,
    use_boundary: bool = True,
    refine: bool = True,
    fix_radius: bool = False,
    min_inliers: int = 20,
    rng: np.random.Generator | int | None = 0,
) -> CircleFit:
    """Fit the flange circle to face points (N, 3) in metres (see module doc).

    ``radius``, ``e_d`` (inlier distance), ``e_r`` (radius tolerance) and ``k_max`` default to the
    paper's R = 31 mm, e_d = 0.3 mm, e_r = 1 mm, k_max = 10 000. Raises DataError when no circle of
    the expected radius is supported by at least ``min_inliers`` points.
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(P) < 10 or not np.all(np.isfinite(P)):
        raise DataError(
            f"flange face has {len(P)} points (or NaNs); cannot fit a circle",
            "check the segmentation (crop box, cluster size) and that the flange faces the camera",
        )
    mu, basis = _face_plane(P)
    xy = (P - mu) @ basis[:2].T
    cand_idx = np.flatnonzero(boundary_mask(xy)) if use_boundary else np.arange(len(P))
    if len(cand_idx) < 3:
        cand_idx = np.arange(len(P))
    C = xy[cand_idx]
    centers, radii = _hypotheses(C, radius, e_r, k_max, np.random.default_rng(rng))
    best_count, best_i = _most_supported(C, centers, radii, e_d)
    if best_count < min_inliers:
        raise DataError(
            f"best circle of radius ~{radius * 1e3:.1f} mm has only {best_count} supporting points",
            "the flange rim is not visible enough; check segmentation, R, e_d, or the viewing angle",
        )
    c2, r = centers[best_i], float(radii[best_i])
    inl = np.abs(np.linalg.norm(C - c2, axis=1) - r) <= e_d
    if refine:
        c2, r, inl = _refined(C, c2, r, inl, e_d, radius if fix_radius else None, min_inliers)
    d = np.abs(np.linalg.norm(C[inl] - c2, axis=1) - r)
    center = mu + c2[0] * basis[0] + c2[1] * basis[1]  # on the face plane
    return CircleFit(
        center=center,
        normal=basis[2],
        radius=r,
        inliers=cand_idx[inl],
        rms=float(np.sqrt(np.mean(d**2))) if len(d) else float("nan"),
        n_boundary=int(len(C)),
        n_hypotheses=int(len(centers)),
        stats={"support": int(inl.sum()), "plane_rms": float(np.std((P - mu) @ basis[2]))},
    )


def _face_plane(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`plane_basis` of the face, robustly: points off the face (rim wall, burrs) dropped, refit."""
    mu, basis = plane_basis(P)
    for _ in range(3):
        d = (P - mu) @ basis[2]
        near = np.abs(d) <= max(3.0 * 1.4826 * float(np.median(np.abs(d))), 1e-5)
        if near.sum() < 10 or near.all():
            break
        mu, basis = plane_basis(P[near])
    return mu, basis


def _hypotheses(
    C: np.ndarray, radius: float, e_r: float, k_max: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Circles through ``k_max`` random point triples of ``C`` that pass the paper's model check
    (radius within ``radius ± e_r``), before any verification."""
    m = len(C)
    s = np.stack([rng.integers(0, m, k_max) for _ in range(3)], axis=1)
    centers, radii = _circumcircles(C[s[:, 0]], C[s[:, 1]], C[s[:, 2]])
    ok = np.isfinite(radii) & (np.abs(radii - radius) <= e_r)
    if not ok.any():
        raise DataError(
            f"no 3-point circle with radius {radius * 1e3:.2f} ± {e_r * 1e3:.2f} mm in {k_max} samples",
            "check the flange radius setting (R) and units of the cloud; raise k_max for sparse rims",
        )
    return centers[ok], radii[ok]


def _most_supported(C: np.ndarray, centers: np.ndarray, radii: np.ndarray, e_d: float) -> tuple[int, int]:
    """(inlier count, index) of the circle with most points within ``e_d`` (then lowest inlier rms),
    evaluated in chunks of about 4 M point-circle distances."""
    best_count, best_i, best_rms = -1, -1, np.inf
    chunk = max(1, 4_000_000 // max(len(C), 1))
    for j in range(0, len(centers), chunk):
        dist = np.abs(
            np.linalg.norm(C[None] - centers[j : j + chunk, None], axis=2) - radii[j : j + chunk, None]
        )
        inl = dist <= e_d
        cnt = inl.sum(1)
        rms = np.sqrt(np.where(inl, dist**2, 0).sum(1) / np.maximum(cnt, 1))
        i = np.lexsort((rms, -cnt))[0]
        if cnt[i] > best_count or (cnt[i] == best_count and rms[i] < best_rms):
            best_count, best_i, best_rms = int(cnt[i]), j + int(i), float(rms[i])
    return best_count, best_i


def _refined(
    C: np.ndarray,
    c2: np.ndarray,
    r: float,
    inl: np.ndarray,
    e_d: float,
    fix_radius: float | None,
    min_inliers: int,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Geometric least-squares circle on the inliers, re-selected up to three times."""
    for _ in range(3):
        c2, r = _refine_circle(C[inl], c2, r, fix_radius)
        new = np.abs(np.linalg.norm(C - c2, axis=1) - r) <= e_d
        if np.array_equal(new, inl) or new.sum() < min_inliers:
            break
        inl = new
    return c2, r, inl
