"""Flange model clouds for the ICP verification metric (eq. 13, Fig. 6).

:func:`iso9409_model` samples the tool-side face of an ISO 9409-1 plate from its main dimensions
(pitch circle d1, centring hole d2, outer diameter d3, N tapped holes d4 on d1, positioning pin hole
d5 on d1) plus the outer rim wall. :func:`load_flange_model` reads a CAD mesh (STL, sampled) or a
model cloud (PCD/PLY). Models live in the flange frame: origin at the face centre (the TCP),
z along the flange axis pointing away from the robot, x toward the pin hole.

The dimensions are the nominal ISO 9409-1:2004 Table 1 values of :mod:`weldcell.hal.iso9409` (the
project's one copy, shared with the simulated robots; verify against the robot maker's drawing, every
value can be overridden).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from weldcell.hal.iso9409 import ISO9409_1, check_dimensions, iso9409_dimensions
from weldcell.sdk.cloud import UNIT_SCALE
from weldcell.sdk.errors import DataError

__all__ = ["ISO9409_1", "iso9409_dimensions", "iso9409_model", "load_flange_model"]


def iso9409_model(
    d1_mm: float = 50.0,
    spacing: float = 0.0005,
    rim_depth: float = 0.003,
    dims: dict | None = None,
) -> np.ndarray:
    """Points (N, 3, metres, flange frame) on the face of an ISO 9409-1 flange: the annulus between
    the centring hole d2 and the outer diameter d3 without the N tapped holes (on d1, offset half a
    pitch from the pin hole) and the pin hole (on d1 at +x), plus the outer rim wall down to
    ``-rim_depth``. ``spacing`` is the sampling grid (m)."""
    d = iso9409_dimensions(d1_mm) if dims is None else check_dimensions(dims)
    mm = 1e-3
    r_out, r_in, r_pc = d["d3"] / 2 * mm, d["d2"] / 2 * mm, d["d1"] / 2 * mm
    g = np.arange(-r_out, r_out + spacing / 2, spacing)
    X, Y = np.meshgrid(g, g)
    xy = np.stack([X.ravel(), Y.ravel()], 1)
    rho = np.linalg.norm(xy, axis=1)
    keep = (rho <= r_out) & (rho >= r_in)
    n = int(d["n"])
    ang = np.pi / n + 2 * np.pi * np.arange(n) / n
    holes = [(r_pc * np.cos(a), r_pc * np.sin(a), d["d4"] / 2 * mm) for a in ang]
    holes.append((r_pc, 0.0, d["d5"] / 2 * mm))
    for hx, hy, hr in holes:
        keep &= np.hypot(xy[:, 0] - hx, xy[:, 1] - hy) > hr
    face = np.column_stack([xy[keep], np.zeros(keep.sum())])
    m = max(8, int(2 * np.pi * r_out / spacing))
    nz = max(1, int(rim_depth / spacing))
    th, z = np.meshgrid(np.linspace(0, 2 * np.pi, m, endpoint=False), -np.arange(1, nz + 1) * spacing)
    rim = np.column_stack([r_out * np.cos(th.ravel()), r_out * np.sin(th.ravel()), z.ravel()])
    return np.vstack([face, rim])


def load_flange_model(
    path: str | Path,
    units: str = "mm",
    T_flange_model: np.ndarray | None = None,
    center: bool = True,
    n_points: int = 30000,
) -> np.ndarray:
    """Model points (N, 3, metres, flange frame) from an STL/OBJ mesh (uniformly sampled) or a
    PCD/PLY cloud. With ``T_flange_model`` the file's frame is mapped by it; otherwise, with
    ``center``, the model is moved so its x-y bounding-box centre is the origin and its top face
    (largest z) is z = 0 — the layout of the CAD-derived clouds in the ancorasir data set."""
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise DataError(f"flange model not found: {path}", "check the path")
    if units not in UNIT_SCALE:
        raise DataError(f"unknown units '{units}'", f"use one of {', '.join(UNIT_SCALE)}")
    if path.suffix.lower() in (".stl", ".obj", ".off"):
        mesh = o3d.io.read_triangle_mesh(str(path))
        if len(mesh.triangles) == 0:
            raise DataError(f"{path}: mesh has no triangles", "export the flange model again")
        P = np.asarray(mesh.sample_points_uniformly(n_points).points)
    else:
        P = np.asarray(o3d.io.read_point_cloud(str(path)).points)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < 10 or np.ptp(P, axis=0).max() == 0:
        raise DataError(f"{path}: flange model has no usable points", "check the file (units, encoding)")
    P = P * UNIT_SCALE[units]
    if T_flange_model is not None:
        T = np.asarray(T_flange_model, float)
        return P @ T[:3, :3].T + T[:3, 3]
    if center:
        lo, hi = P.min(0), P.max(0)
        P = P - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2]])
    return P
