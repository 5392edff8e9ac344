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

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from weldcell.hal.iso9409 import ISO9409_1, check_dimensions, iso9409_dimensions
from weldcell.sdk.cloud import UNIT_SCALE
from weldcell.sdk.errors import DataError
from weldcell.sdk.repeatable import open3d_serial

__all__ = [
    "ISO9409_1",
    "FlangeModel",
    "clean_flange_model",
    "iso9409_dimensions",
    "iso9409_model",
    "load_flange_model",
]


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


@dataclass
class FlangeModel:
    """A cleaned flange model: ``points`` (N, 3, metres, flange frame: face at z = 0, z out of the
    face, origin on the axis), what was done (``report``) and what a person should check (``warnings``)."""

    points: np.ndarray
    report: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


#: a flange's outer diameter is between these (m): ISO 9409-1 d3 runs from 40 mm (d1 31.5) to 125 mm
#: (d1 100); the bounds leave room for adapter plates
MIN_DIAMETER, MAX_DIAMETER = 0.02, 0.4
#: the model keeps the face and this much of the rim behind it (m), like :func:`iso9409_model`
FACE_DEPTH = 0.002
#: models are thinned to this voxel (m) for the eq. 13 ICP (run time bounded, ~3k points for d1 = 50)
MODEL_VOXEL = 0.001


def detect_units(P: np.ndarray, where: str) -> str:
    """'mm' or 'm' from a model's size (its largest extent must be a flange's diameter in one of them);
    DataError when it fits neither."""
    ext = float(np.max(np.ptp(P, axis=0)))
    if MIN_DIAMETER * 1e3 <= ext <= MAX_DIAMETER * 1e3:
        return "mm"
    if MIN_DIAMETER <= ext <= MAX_DIAMETER:
        return "m"
    raise DataError(
        f"{where}: the model is {ext:.4g} units across, which is no flange in mm or m "
        f"({MIN_DIAMETER * 1e3:.0f}-{MAX_DIAMETER * 1e3:.0f} mm)",
        "give the flange plate's model (STL, PCD or PLY) in mm or m, or pass its units",
    )


def _outer_circle(xy: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Centre, radius and angular coverage (0-1) of the outer rim of a face seen along its axis:
    a robust circle fit (soft-L1) to the convex hull's vertices, so a straight crop edge does not pull it."""
    from scipy.optimize import least_squares
    from scipy.spatial import ConvexHull

    h = xy[ConvexHull(xy).vertices]
    A = np.column_stack([2 * h, np.ones(len(h))])
    sol = np.linalg.lstsq(A, (h**2).sum(1), rcond=None)[0]
    c0 = sol[:2]
    r0 = float(np.sqrt(max(sol[2] + c0 @ c0, 1e-12)))
    fit = least_squares(
        lambda p: np.linalg.norm(h - p[:2], axis=1) - p[2], np.r_[c0, r0], loss="soft_l1", f_scale=r0 * 0.01
    )
    c, r = fit.x[:2], float(abs(fit.x[2]))
    rho = np.linalg.norm(xy - c, axis=1)
    ang = np.arctan2(*(xy[rho > 0.9 * r] - c).T[::-1])
    cover = len(np.unique(np.floor((ang + np.pi) / (2 * np.pi) * 36).astype(int))) / 36
    return c, r, cover


def clean_flange_model(
    points: np.ndarray, units: str = "auto", expected_diameter: float | None = None, where: str = "model"
) -> FlangeModel:
    """A CAD or scanned flange cloud made usable by the eq. 13 verifier: non-finite points dropped, the
    units detected from its size, the axis found (least-variance direction; its sign kept along the
    file's +z), the face (the highest well-populated slab along the axis) kept with ``FACE_DEPTH`` of
    rim, the origin moved to the centre of the outer rim (a robust circle fit, so a cropped or offset
    model still centres on the axis), x kept along the file's x, and thinned to ``MODEL_VOXEL``.
    DataError for a model that cannot work (no finite points, no flange size, not a plate, less than
    half of the rim, a diameter far from ``expected_diameter``)."""
    P = np.asarray(points, float).reshape(-1, 3)
    fin = np.all(np.isfinite(P), axis=1)
    rep: dict = {"points_in": len(P), "nonfinite_dropped": int((~fin).sum())}
    P = P[fin]
    if len(P) < 100:
        raise DataError(
            f"{where}: only {len(P)} finite points ({rep['nonfinite_dropped']} NaN/inf dropped)",
            "export the flange model again (a dense cloud or an STL mesh)",
        )
    units = detect_units(P, where) if units == "auto" else units
    if units not in UNIT_SCALE:
        raise DataError(f"{where}: unknown units '{units}'", f"use one of auto, {', '.join(UNIT_SCALE)}")
    rep["units"] = units
    P = P * UNIT_SCALE[units]
    mu = P.mean(0)
    _, sv, Vt = np.linalg.svd(P - mu, full_matrices=False)
    if sv[2] > 0.5 * sv[1]:
        raise DataError(
            f"{where}: the model is not a plate (its thinnest extent is {sv[2] / sv[1]:.2f} of its width)",
            "give the flange plate only (crop the robot link off the model)",
        )
    z = Vt[2] if Vt[2][2] >= 0 else -Vt[2]
    h = (P - mu) @ z
    bins = np.arange(h.min(), h.max() + 2.5e-4, 2.5e-4)
    cnt, edges = np.histogram(h, bins=bins if len(bins) > 1 else 1)
    k = int(np.flatnonzero(cnt >= 0.05 * cnt.max()).max())
    top = float(np.median(h[(h >= edges[k]) & (h <= edges[k + 1])]))
    face = P[h >= top - FACE_DEPTH]
    x0 = np.array([1.0, 0, 0]) - z[0] * z
    x0 = x0 / np.linalg.norm(x0) if np.linalg.norm(x0) > 0.1 else np.cross([0, 1.0, 0], z)
    y0 = np.cross(z, x0)
    xy = (face - mu) @ np.stack([x0, y0]).T
    c, r, cover = _outer_circle(xy)
    rep.update(diameter_mm=round(2 * r * 1e3, 2), rim_coverage=round(cover, 2))
    warnings = _model_checks(r, cover, expected_diameter, where)
    origin = mu + c[0] * x0 + c[1] * y0 + top * z
    R = np.stack([x0, y0, z])  # rows: flange axes in the file frame
    Q = (face - origin) @ R.T
    Q[:, 2] = np.minimum(Q[:, 2], 0.0)
    rep["offset_mm"] = np.round(origin * 1e3, 2).tolist()
    rep["axis_in_file"] = np.round(z, 4).tolist()
    if np.linalg.norm(origin) > 1e-3 or abs(z[2]) < 0.999:
        rep["moved"] = (
            f"{where}: face centre found at {rep['offset_mm']} mm, axis {rep['axis_in_file']} in the "
            "file; moved onto the flange frame"
        )
    Q = _voxel(Q, MODEL_VOXEL)
    rep["points_out"] = len(Q)
    return FlangeModel(Q, rep, warnings)


def _model_checks(r: float, cover: float, expected: float | None, where: str) -> list[str]:
    if not MIN_DIAMETER <= 2 * r <= MAX_DIAMETER:
        raise DataError(
            f"{where}: the face's outer rim is {2 * r * 1e3:.1f} mm across; no flange is",
            "check the model's units and that it is the flange plate",
        )
    if cover < 0.5:
        raise DataError(
            f"{where}: the model covers only {cover * 100:.0f}% of the flange rim; ICP cannot place it",
            "give a model of the whole flange face",
        )
    if expected is not None and abs(2 * r - expected) > 0.15 * expected:
        raise DataError(
            f"{where}: the model is {2 * r * 1e3:.1f} mm across but the flange (flange_d1) is "
            f"{expected * 1e3:.1f} mm",
            "give this robot's flange model, or the right --flange-d1",
        )
    if cover < 0.9:
        return [f"{where}: cropped model ({cover * 100:.0f}% of the rim); centred on the rim's arc"]
    return []


def _voxel(P: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the mean) per occupied voxel."""
    key = np.floor(P / voxel).astype(np.int64)
    _, inv, n = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    out = np.zeros((len(n), 3))
    np.add.at(out, inv.ravel(), P)
    return out / n[:, None]


def read_model_points(path: str | Path, n_points: int = 30000) -> np.ndarray:
    """The raw points of a model file: a mesh (STL/OBJ/OFF, uniformly sampled) or a cloud (PCD/PLY,
    NaN points kept for the cleaner to count)."""
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise DataError(f"flange model not found: {path}", "check the path")
    from weldcell.sdk.cloudfile import quiet_native_output

    if path.suffix.lower() in (".stl", ".obj", ".off"):
        with quiet_native_output() as said:  # Open3D's own warning must not print before our error
            mesh = o3d.io.read_triangle_mesh(str(path))
        if len(mesh.triangles) == 0:
            why = f" (the reader said: {said[0]})" if said else ""
            raise DataError(f"{path}: mesh has no triangles{why}", "export the flange model again")
        o3d.utility.random.seed(0)
        with open3d_serial():
            return np.asarray(mesh.sample_points_uniformly(n_points).points)
    with quiet_native_output():
        pc = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
    return np.asarray(pc.points)


def load_flange_model(
    path: str | Path,
    units: str = "auto",
    T_flange_model: np.ndarray | None = None,
    center: bool = True,
    n_points: int = 30000,
    expected_diameter: float | None = None,
) -> np.ndarray:
    """Model points (N, 3, metres, flange frame) from an STL/OBJ mesh (uniformly sampled) or a
    PCD/PLY cloud. With ``T_flange_model`` the file's frame is mapped by it (units "auto" = from the
    size); otherwise, with ``center``, the model is cleaned by :func:`clean_flange_model` (NaN points,
    units, face, axis and centre found from the rim). :func:`load_clean_model` also returns what was done."""
    if T_flange_model is None and center:
        return load_clean_model(path, units, n_points, expected_diameter).points
    P = read_model_points(path, n_points)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < 10 or np.ptp(P, axis=0).max() == 0:
        raise DataError(f"{path}: flange model has no usable points", "check the file (units, encoding)")
    units = detect_units(P, str(path)) if units == "auto" else units
    if units not in UNIT_SCALE:
        raise DataError(f"unknown units '{units}'", f"use one of auto, {', '.join(UNIT_SCALE)}")
    P = P * UNIT_SCALE[units]
    if T_flange_model is not None:
        T = np.asarray(T_flange_model, float)
        return P @ T[:3, :3].T + T[:3, 3]
    return P


def load_clean_model(
    path: str | Path, units: str = "auto", n_points: int = 30000, expected_diameter: float | None = None
) -> FlangeModel:
    """:func:`clean_flange_model` of a model file (its name in every message)."""
    P = read_model_points(path, n_points)
    return clean_flange_model(P, units, expected_diameter, where=Path(path).name)
