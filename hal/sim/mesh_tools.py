"""Building blocks of the workpiece builders: triangle-mesh pieces, straight seams and argument checks.

Meshes are built as vertex (V, 3) and face (F, 3) arrays, merged with :func:`merge_parts` and turned
into an Open3D mesh once by :func:`triangle_mesh`; faces are oriented outward with :func:`orient_faces`.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import open3d as o3d
from weldcell.hal.sim.workpiece_model import SeamTruth
from weldcell.sdk.errors import DataError


def triangle_mesh(V: np.ndarray, F: np.ndarray) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.ascontiguousarray(V, dtype=float)),
        o3d.utility.Vector3iVector(np.ascontiguousarray(F, dtype=np.int32)),
    )
    m.compute_triangle_normals()
    m.compute_vertex_normals()
    return m


def merge_parts(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    Vs, Fs, off = [], [], 0
    for V, F in parts:
        Vs.append(V)
        Fs.append(F + off)
        off += len(V)
    return np.vstack(Vs), np.vstack(Fs)


def ear_clip(poly: np.ndarray) -> np.ndarray:
    """Triangulate a simple counter-clockwise polygon (M, 2); triangles are counter-clockwise."""
    idx = list(range(len(poly)))
    tris = []

    def cross(o, a, b) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3 and guard < 10000:
        guard += 1
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if cross(a, b, c) <= 1e-15:
                continue  # reflex or degenerate corner
            inside = False
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                p = poly[j]
                if cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0:
                    inside = True
                    break
            if not inside:
                tris.append((i0, i1, i2))
                idx.pop(k)
                break
        else:  # pragma: no cover - only for non-simple polygons
            raise DataError("cross-section polygon is not simple", "check the workpiece parameters")
    tris.append(tuple(idx))
    return np.array(tris, dtype=np.int64)


def extrude_yz(poly_yz: np.ndarray, x0: float, x1: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed prism: a counter-clockwise (y, z) polygon extruded along x from x0 to x1, faces outward."""
    P = np.asarray(poly_yz, dtype=float)
    m = len(P)
    V = np.vstack([np.column_stack([np.full(m, x0), P]), np.column_stack([np.full(m, x1), P])])
    i = np.arange(m)
    j = (i + 1) % m
    # side quad (x0,p_i) (x0,p_j) (x1,p_j) (x1,p_i): normal (0, dz, -dy) = outward for a CCW polygon
    sides = np.vstack([np.column_stack([i, j, m + j]), np.column_stack([i, m + j, m + i])])
    cap = ear_clip(P)  # CCW in (y, z) -> normal +x
    F = np.vstack([sides, cap[:, [0, 2, 1]], cap + m])
    return V, F


def orient_faces(V: np.ndarray, F: np.ndarray, outward: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Flip triangles whose normal points against ``outward(centroids)``."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    flip = np.sum(n * outward((a + b + c) / 3.0), axis=1) < 0
    F = F.copy()
    F[flip] = F[flip][:, [0, 2, 1]]
    return F


def fan_disc(center: np.ndarray, ring: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fan of triangles closing a ring of vertices (M, 3) around ``center``, facing ``normal``."""
    m = len(ring)
    V = np.vstack([center[None], ring])
    i = np.arange(m)
    F = np.column_stack([np.zeros(m, dtype=np.int64), 1 + i, 1 + (i + 1) % m])
    F = orient_faces(V, F, lambda c: np.broadcast_to(normal, c.shape))
    return V, F


def line_seam(seam_id: str, joint: str, p0, p1, approach, spacing: float) -> SeamTruth:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    k = int(math.ceil(np.linalg.norm(p1 - p0) / spacing)) + 1
    s = np.linspace(0.0, 1.0, k)[:, None]
    pts = p0 + s * (p1 - p0)
    travel = np.broadcast_to((p1 - p0) / np.linalg.norm(p1 - p0), pts.shape)
    return SeamTruth(seam_id, joint, pts, np.broadcast_to(np.asarray(approach, float), pts.shape), travel)


def circle_segments(circumference: float, max_sagitta: float = 1e-5, minimum: int = 64) -> int:
    """Number of polygon sides so the chord sagitta of a circle stays below ``max_sagitta``."""
    r = circumference / (2 * math.pi)
    return max(minimum, int(math.ceil(math.pi / math.acos(max(1.0 - max_sagitta / r, -1.0)))))


# --------------------------------------------------------------------------------------------------
# Argument checks
# --------------------------------------------------------------------------------------------------


def check_positive(kind: str, **values: float) -> None:
    for name, v in values.items():
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise DataError(
                f"{kind}: {name} must be a positive length in metres, got {v!r}", f"give {name} > 0"
            )


def check_nonnegative(kind: str, **values: float) -> None:
    for name, v in values.items():
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise DataError(f"{kind}: {name} must be >= 0 (metres), got {v!r}", f"give {name} >= 0")


def check_spacing(kind: str, seam_spacing: float) -> None:
    check_positive(kind, seam_spacing=seam_spacing)
    if seam_spacing > 0.001:
        raise DataError(
            f"{kind}: seam_spacing {seam_spacing * 1e3:.3g} mm is coarser than 1 mm",
            "give seam_spacing <= 0.001 (m)",
        )


def require(ok: bool, message: str, fix: str) -> None:
    if not ok:
        raise DataError(message, fix)
