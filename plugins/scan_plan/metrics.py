"""Evaluation metrics of the scan-and-plan method (paper 000, section III, eqs. 20-22).

* :func:`fitness` -- eq. 20, share of aligned points after registration;
* :func:`seam_f1` -- eq. 21, harmonic mean over the xy, xz and yz rasterisations of detected vs
  ground-truth seam points;
* :func:`pose_rmse` -- eq. 22, RMSE of the torch positions and orientations against a ground-truth seam.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from weldcell.sdk.errors import DataError

from .cloud_numerics import as_points

PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2)}


def fitness(
    source: np.ndarray,
    target: np.ndarray,
    T: np.ndarray | None = None,
    *,
    max_distance: float,
    denominator: str = "target",
) -> float:
    """Eq. 20: ``S(M) = |P_m| / |P_t|`` with ``P_m = {m_i : |t_i - M m_i| < d}``.

    ``source`` are the model points m_i, mapped by ``T`` (``T_target_source``, identity when None);
    t_i is each one's nearest target point and ``d = max_distance``. The paper divides by the number of
    target points; ``denominator="source"`` divides by the number of source points (Open3D's fitness).
    """
    S = as_points(source, "fitness source")
    Tg = as_points(target, "fitness target")
    if not np.isfinite(max_distance) or max_distance <= 0:
        raise DataError(
            f"max_distance must be > 0 m, got {max_distance}", "pass the inlier distance in metres"
        )
    if denominator not in ("target", "source"):
        raise DataError(f"unknown denominator '{denominator}'", "use 'target' (eq. 20) or 'source'")
    if T is not None:
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise DataError("T must be a finite 4x4 transform", "pass T_target_source as a 4x4 matrix")
        S = S @ T[:3, :3].T + T[:3, 3]
    d, _ = cKDTree(Tg).query(S, k=1, distance_upper_bound=max_distance, workers=-1)
    n_in = int(np.count_nonzero(d < max_distance))
    return n_in / (len(Tg) if denominator == "target" else len(S))


def harmonic_mean(values: np.ndarray) -> float:
    """``len(v) / sum(1 / v)`` as in eq. 21; 0 when any value is 0."""
    v = np.asarray(values, dtype=float)
    if np.any(v <= 0):
        return 0.0
    return float(len(v) / np.sum(1.0 / v))


def _cells(P2: np.ndarray, cell: float) -> np.ndarray:
    return np.unique(np.floor(P2 / cell).astype(np.int64), axis=0)


def _matched(a: np.ndarray, b: np.ndarray, tol: int) -> np.ndarray:
    """For each cell of ``a``: is there a cell of ``b`` within ``tol`` cells (Chebyshev)?"""
    if tol == 0:
        bset = {tuple(c) for c in b}
        return np.array([tuple(c) in bset for c in a], dtype=bool)
    d, _ = cKDTree(b).query(a, k=1, p=np.inf, distance_upper_bound=tol + 0.5)
    return np.isfinite(d)


def seam_f1(
    pred_points: np.ndarray, gt_points: np.ndarray, cell: float = 0.002, tolerance_cells: int = 0
) -> dict:
    """Rasterised seam-detection score, eq. 21 (paper 000).

    Detected and ground-truth seam points are rasterised onto the xy, xz and yz planes with square
    cells of ``cell`` metres (one grid for both sets). On each plane, precision = share of detected
    cells that hit a ground-truth cell, recall (the paper's "coverage") = share of ground-truth cells
    hit, and the plane's accuracy is their F1. A cell counts as a hit when a cell of the other set
    lies within ``tolerance_cells`` cells. The three planes are combined by eq. 21,
    ``F1 = 3 / (1/a_xy + 1/a_xz + 1/a_yz)``, for each of precision, recall and F1.
    Returns ``{"precision", "recall", "f1", "planes": {plane: {"precision", "recall", "f1"}}}``.
    """
    pred = as_points(pred_points, "detected seam points")
    gt = as_points(gt_points, "ground-truth seam points")
    if not np.isfinite(cell) or cell <= 0:
        raise DataError(f"cell must be > 0 m, got {cell}", "pass the raster cell size in metres, e.g. 0.002")
    if tolerance_cells < 0:
        raise DataError(f"tolerance_cells must be >= 0, got {tolerance_cells}", "pass 0 or a positive count")
    planes = {}
    for name, (a, b) in PLANES.items():
        cp, cg = _cells(pred[:, [a, b]], cell), _cells(gt[:, [a, b]], cell)
        p = float(np.mean(_matched(cp, cg, tolerance_cells)))
        r = float(np.mean(_matched(cg, cp, tolerance_cells)))
        f = 2 * p * r / (p + r) if p + r > 0 else 0.0
        planes[name] = {"precision": p, "recall": r, "f1": f}
    return {
        "precision": harmonic_mean([v["precision"] for v in planes.values()]),
        "recall": harmonic_mean([v["recall"] for v in planes.values()]),
        "f1": harmonic_mean([v["f1"] for v in planes.values()]),
        "planes": planes,
    }


def _unit_rows(V: np.ndarray, what: str) -> np.ndarray:
    n = np.linalg.norm(V, axis=1, keepdims=True)
    if np.any(n < 1e-12):
        raise DataError(f"{what} has zero-length vectors", f"give a non-zero {what} at every seam point")
    return V / n


def _project_on_polyline(P: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point of the polyline ``G`` to each of ``P`` -> (points, segment index, fraction)."""
    if len(G) == 1:
        z = np.zeros(len(P), dtype=np.int64)
        return np.repeat(G, len(P), axis=0), z, np.zeros(len(P))
    _, near = cKDTree(G).query(P, k=1)
    best_d = np.full(len(P), np.inf)
    best = (np.zeros((len(P), 3)), np.zeros(len(P), dtype=np.int64), np.zeros(len(P)))
    for seg in (np.clip(near - 1, 0, len(G) - 2), np.clip(near, 0, len(G) - 2)):
        a, b = G[seg], G[seg + 1]
        ab = b - a
        L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
        s = np.clip(np.einsum("ij,ij->i", P - a, ab) / L2, 0.0, 1.0)
        q = a + s[:, None] * ab
        d = np.linalg.norm(P - q, axis=1)
        better = d < best_d
        best_d = np.where(better, d, best_d)
        best[0][better], best[1][better], best[2][better] = q[better], seg[better], s[better]
    return best


def pose_rmse(
    pred_poses: np.ndarray,
    gt_points: np.ndarray,
    gt_approach: np.ndarray,
    gt_travel: np.ndarray | None = None,
) -> dict:
    """Eq. 22 (paper 000): RMSE of translation and rotation of torch poses against a ground-truth seam.

    ``pred_poses`` (K, 4, 4) are torch frames in the base frame (z = approach, x = travel).
    ``gt_points`` (M, 3) is the ground-truth seam ordered along travel with the approach direction
    ``gt_approach`` (M, 3) and optionally the travel direction ``gt_travel`` (M, 3) at each point
    (default: the polyline tangent). Each pose is matched to the closest point of the ground-truth
    polyline (so the error does not depend on how densely either path is sampled) with the
    directions interpolated there. The rotation error is the angle of ``R_gt^T R_pred`` with the
    ground-truth frame built from (travel, approach); ``approach_rad`` is the angle between the z axes.
    Returns ``{"translation_m", "rotation_rad", "approach_rad", "translation_max_m", "rotation_max_rad",
    "n"}``.
    """
    T = np.asarray(pred_poses, dtype=float)
    if T.ndim == 2:
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) == 0:
        raise DataError(
            f"pred_poses must be a (K, 4, 4) array with K >= 1, got shape {T.shape}", "stack 4x4 poses"
        )
    if not np.all(np.isfinite(T)):
        raise DataError("pred_poses contain NaN or infinite values", "drop invalid poses before scoring")
    G = as_points(gt_points, "ground-truth seam points")
    A = as_points(gt_approach, "ground-truth approach directions")
    if len(A) != len(G):
        raise DataError(
            f"{len(G)} ground-truth points but {len(A)} approach directions",
            "give one direction per seam point",
        )
    A = _unit_rows(A, "ground-truth approach")
    if gt_travel is None:
        if len(G) < 2:
            raise DataError("one ground-truth point has no travel direction", "pass gt_travel or more points")
        tang = np.gradient(G, axis=0)
        X = _unit_rows(tang, "ground-truth seam tangent")
    else:
        X = as_points(gt_travel, "ground-truth travel directions")
        if len(X) != len(G):
            raise DataError(
                f"{len(G)} ground-truth points but {len(X)} travel directions",
                "give one direction per seam point",
            )
        X = _unit_rows(X, "ground-truth travel")
    P = T[:, :3, 3]
    Q, seg, s = _project_on_polyline(P, G)
    nxt = np.minimum(seg + 1, len(G) - 1)
    a = _unit_rows((1 - s)[:, None] * A[seg] + s[:, None] * A[nxt], "interpolated approach")
    x = _unit_rows((1 - s)[:, None] * X[seg] + s[:, None] * X[nxt], "interpolated travel")
    e_t = np.linalg.norm(P - Q, axis=1)
    z_pred = T[:, :3, 2] / np.linalg.norm(T[:, :3, 2], axis=1, keepdims=True)
    e_a = np.arccos(np.clip(np.einsum("ij,ij->i", z_pred, a), -1.0, 1.0))
    x_perp = _unit_rows(x - np.einsum("ij,ij->i", x, a)[:, None] * a, "travel (parallel to approach)")
    R_gt = np.stack([x_perp, np.cross(a, x_perp), a], axis=2)  # frame_from_axes(x, a), vectorised
    dR = np.einsum("kji,kjl->kil", R_gt, T[:, :3, :3])
    e_r = np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    return {
        "translation_m": float(np.sqrt(np.mean(e_t**2))),
        "rotation_rad": float(np.sqrt(np.mean(e_r**2))),
        "approach_rad": float(np.sqrt(np.mean(e_a**2))),
        "translation_max_m": float(e_t.max()),
        "rotation_max_rad": float(e_r.max()),
        "n": int(len(P)),
    }
