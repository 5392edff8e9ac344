"""The seam stage on real, public weldment scans, run as a user would run it (issue 16).

Run:  .venv/bin/python benchmarks/seam_real_scans.py [--mirror DIR] [--out DIR] [--only NAME]

Data (not shipped: GPL-3.0, used locally only). The scans come from thillRobot/seam_detection
(https://github.com/thillRobot/seam_detection, GPL-3.0): an RPLiDAR A2 2-D lidar swept by an Aubo i5 / i10
arm over steel parts on a table (a laser line scan: about 1 mm between points along a line, several mm
between lines, no viewpoint recorded) and single RGB-D frames over a table. Bring the snapshot
with the search tool's ``fetch github:thillRobot/seam_detection``; this script reads each file straight
from that git directory (``git show COMMIT:PATH``, no work tree needed) into ``--out``.

For each scan:

1. ``weldcell seam CLOUD -o path.json`` with the defaults; then the same command following the error
   message's own hint (``fix: ... lower --t, or --set seam.min_seam_length='10 mm'``): ``--t`` lowered
   from the default 40 to 30 (the eq. 16 threshold's floor is 27) plus every ``--set`` the hint names.
   The hint run is made whether or not the defaults failed, so a false seam found by the defaults shows.
2. Points, median spacing (nearest neighbour) and the spacing across scan lines (nearest neighbour more
   than 60 deg off the first one's direction), extent.
3. Where a seam can be marked from the geometry (:class:`TwoPlanes`, :class:`PlaneCylinder`: faces fitted
   by hand-picked boxes, their intersection clipped to where both faces were scanned), precision / recall
   of the found seams' points at 1.5 mm (and at 5 mm, to tell a seam found a little off from a false one),
   the faces' fit RMS (the scan's noise there), and how many found seams lie on the table contact.
4. A picture per scan (``OUT/NAME.png``): three orthographic views of the cloud near the part, the marked
   seam in green, the found seams in red (defaults) and orange (hint).
5. Where the marked seam is lost inside the stage (:func:`diagnose`: the CLI's default stages run
   in-process on the same points): derived spacings and radius, share of eq. 16 edge points, share of
   the marked seam with an edge point near it and their classes, the support plane found.

Loaders for the formats public weld scans come in (PLY/PCD, XYZ/CSV text in mm or m, organised depth
images with pinhole intrinsics, laser-line profiles with per-profile poses) are :func:`load_points`,
:func:`depth_to_points` and :func:`profiles_to_points`; anything not PLY/PCD in metres is written to a
PLY in metres first, as a user would before calling ``weldcell seam``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
WELDCELL = ROOT / ".venv" / "bin" / "weldcell"
TOLERANCE = 0.0015  # the precision / recall tolerance (m)
LOOSE = 0.005  # a seam within this is the right seam found a little off, not a false one
STEP = 0.0005  # polylines are compared resampled at this step (m)
DEFAULT_MIRROR = Path("/work/.mirror/thillRobot+seam_detection/repo")
SIDE = 0.002  # a face counts as scanned at a seam from this far off the seam line (m) ...
BESIDE = 0.004  # ... and within this along the seam of the point it shows (half a 5-8 mm line spacing)
HINT_T = 30.0  # "lower --t": the default is 40, the eq. 16 threshold's floor 27


# ----------------------------------------------------------------------------------------------- loaders


def load_points(path: str | Path, units: str = "m") -> np.ndarray:
    """(N, 3) points in metres from PLY/PCD (read by weldcell) or XYZ/CSV/TXT text (x y z first columns,
    any of space, comma or semicolon between them; ``units`` 'mm' or 'm'); NaN / inf rows dropped."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".ply", ".pcd"):
        from weldcell.sdk.cloud import load_cloud_file

        P = np.asarray(load_cloud_file(path).points, float)
    elif suffix in (".xyz", ".csv", ".txt", ".pts", ".asc"):
        rows = []
        for line in path.read_text().splitlines():
            tok = [t for t in re.split(r"[\s,;]+", line.strip()) if t]
            try:
                rows.append([float(t) for t in tok[:3]])
            except ValueError:
                continue  # a header or comment line
        P = np.asarray([r for r in rows if len(r) == 3], float).reshape(-1, 3)
    else:
        raise ValueError(f"{path}: unknown point format '{suffix}' (use .ply, .pcd, .xyz, .csv or .txt)")
    P = P * (0.001 if units == "mm" else 1.0)
    return P[np.isfinite(P).all(axis=1)]


def depth_to_points(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                    depth_scale: float = 0.001) -> np.ndarray:
    """Organised depth image (H, W) (raw units x ``depth_scale`` = metres; 0 / NaN = no return) to
    (N, 3) camera-frame points, pinhole model (x right, y down, z forward)."""
    z = np.asarray(depth, float) * depth_scale
    v, u = np.indices(z.shape)
    ok = np.isfinite(z) & (z > 0)
    return np.column_stack([(u[ok] - cx) * z[ok] / fx, (v[ok] - cy) * z[ok] / fy, z[ok]])


def profiles_to_points(profiles: list[np.ndarray], poses: list[np.ndarray], units: str = "mm") -> np.ndarray:
    """Laser-line profiles, each (K, 2) (x along the line, z along the beam) in the sensor's frame, with
    the sensor's pose (4x4, metres) at each profile, to (N, 3) points in the poses' frame."""
    s = 0.001 if units == "mm" else 1.0
    out = []
    for prof, T in zip(profiles, poses, strict=True):
        prof = np.asarray(prof, float) * s
        prof = prof[np.isfinite(prof).all(axis=1)]
        local = np.column_stack([prof[:, 0], np.zeros(len(prof)), prof[:, 1], np.ones(len(prof))])
        out.append((np.asarray(T, float) @ local.T).T[:, :3])
    return np.vstack(out) if out else np.zeros((0, 3))


def as_cloud_file(points: np.ndarray, path: Path) -> Path:
    """Write ``points`` (metres) as a PLY for ``weldcell seam``."""
    from weldcell.sdk.cloud import PointCloud, write_cloud

    return write_cloud(path, PointCloud(points=np.asarray(points, float), frame="base"))


# ------------------------------------------------------------------------------------ sampling statistics


def spacing(P: np.ndarray) -> tuple[float, float]:
    """Median nearest-neighbour distance, and the median distance to the nearest neighbour more than
    60 deg off the first one's direction (the spacing across a line scan's lines; equal for even
    sampling). Metres."""
    d, j = cKDTree(P).query(P, k=min(17, len(P)))
    first = P[j[:, 1]] - P
    first /= np.maximum(np.linalg.norm(first, axis=1, keepdims=True), 1e-12)
    off = P[j[:, 2:]] - P[:, None]
    cos = np.abs(np.einsum("nkj,nj->nk", off, first)) / np.maximum(np.linalg.norm(off, axis=2), 1e-12)
    across = np.where(cos < 0.5, d[:, 2:], np.inf).min(axis=1)
    return float(np.median(d[:, 1])), float(np.median(across[np.isfinite(across)]))


# ----------------------------------------------------------------------------------- seams marked by hand


def _in_box(P: np.ndarray, box: tuple) -> np.ndarray:
    lo, hi = np.asarray(box[0], float) / 1000, np.asarray(box[1], float) / 1000
    return ((P >= lo) & (P <= hi)).all(axis=1)


def fit_plane(Q: np.ndarray, iters: int = 5) -> tuple[np.ndarray, np.ndarray, float]:
    """Plane (point, unit normal) through ``Q`` by SVD, refitted without points beyond 2.5 x the RMS;
    also the final RMS (m)."""
    keep = np.ones(len(Q), bool)
    for _ in range(iters):
        c = Q[keep].mean(axis=0)
        n = np.linalg.svd(Q[keep] - c, full_matrices=False)[2][2]
        r = (Q - c) @ n
        rms = float(np.sqrt(np.mean(r[keep] ** 2)))
        keep = np.abs(r) <= max(2.5 * rms, 1e-5)
    return c, n, rms


def _shown_runs(T: np.ndarray, ok: np.ndarray, min_len: float = 0.003) -> list[np.ndarray]:
    """Runs of consecutive ``ok`` samples of polyline ``T`` longer than ``min_len``."""
    runs, start = [], None
    for i, flag in enumerate(np.r_[ok, False]):
        if flag and start is None:
            start = i
        elif not flag and start is not None:
            if (i - start) * STEP >= min_len:
                runs.append(T[start:i])
            start = None
    return runs


def _both_sides(T: np.ndarray, A: np.ndarray, B: np.ndarray, reach: float) -> np.ndarray:
    """Samples of polyline ``T`` with scanned points of face A and of face B within ``reach`` of them and
    beside them: within :data:`BESIDE` along the seam (a face that ends is not counted past its end)."""
    t = np.gradient(T, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-12)
    ok = np.ones(len(T), bool)
    for F in (A, B):
        near = cKDTree(F).query_ball_point(T, reach) if len(F) else [[] for _ in T]
        ok &= np.array([bool(len(j)) and bool(np.any(np.abs((F[j] - p) @ d) <= BESIDE))
                        for j, p, d in zip(near, T, t, strict=True)])
    return ok


def _on_plane(P: np.ndarray, c: np.ndarray, n: np.ndarray, rms: float) -> np.ndarray:
    """The cloud's points on the fitted plane (within 3 x its RMS, at least 2 mm): the face as scanned,
    also outside the box it was fitted in (up to the seam)."""
    return P[np.abs((P - c) @ n) <= max(3 * rms, 0.002)]


@dataclass
class TwoPlanes:
    """A fillet (or any plane-plane) seam: the intersection line of the planes fitted to the points in
    box ``a`` and box ``b`` (mm, axis-aligned, picked by hand from the pictures), kept where both faces
    were scanned within ``reach`` of it."""

    a: tuple
    b: tuple
    reach: float = 0.008

    def mark(self, P: np.ndarray) -> tuple[list[np.ndarray], float]:
        A, B = P[_in_box(P, self.a)], P[_in_box(P, self.b)]
        (ca, na, ra), (cb, nb, rb) = fit_plane(A), fit_plane(B)
        d = np.cross(na, nb)
        d /= np.linalg.norm(d)
        # a point on both planes: least squares on [na; nb; d] x = [na.ca; nb.cb; d.ca]
        p0 = np.linalg.solve(np.vstack([na, nb, d]), np.array([na @ ca, nb @ cb, d @ ca]))
        sa, sb = (A - p0) @ d, (B - p0) @ d  # the line runs where both boxes' faces do
        lo, hi = max(sa.min(), sb.min()) - self.reach / 2, min(sa.max(), sb.max()) + self.reach / 2
        T = p0 + np.arange(lo, hi, STEP)[:, None] * d
        # each face as scanned on its own side of the line (an edge of the other part lying on the same
        # plane, e.g. a bar's far edge flush with the standing plate, is not that face)
        sides = []
        for Q, c, n, r in ((A, ca, na, ra), (B, cb, nb, rb)):
            F = _on_plane(P, c, n, r)
            w = Q.mean(axis=0) - p0
            w -= (w @ d) * d
            sides.append(F[(F - p0) @ (w / np.linalg.norm(w)) > SIDE])
        return _shown_runs(T, _both_sides(T, *sides, self.reach)), float(np.hypot(ra, rb) / np.sqrt(2))


@dataclass
class PlaneCylinder:
    """A tube-on-plate (saddle) seam: the curve where the cylinder fitted to box ``tube`` meets the plane
    fitted to box ``plate`` (mm), kept where both were scanned within ``reach`` of it."""

    plate: tuple
    tube: tuple
    reach: float = 0.008

    def mark(self, P: np.ndarray) -> tuple[list[np.ndarray], float]:
        A, C = P[_in_box(P, self.plate)], P[_in_box(P, self.tube)]
        c0, n, ra = fit_plane(A)
        u = np.linalg.svd(np.eye(3) - np.outer(n, n))[0][:, 0]
        v = np.cross(n, u)

        def resid(x: np.ndarray) -> np.ndarray:
            a = n + x[2] * u + x[3] * v
            a /= np.linalg.norm(a)
            c = c0 + x[0] * u + x[1] * v
            D = C - c
            return np.linalg.norm(D - np.outer(D @ a, a), axis=1) - x[4]

        q = C - c0
        x0 = np.r_[np.mean(q @ u), np.mean(q @ v), 0.0, 0.0, 0.5 * np.ptp(q @ u)]
        x = least_squares(resid, x0, loss="soft_l1", f_scale=0.002).x
        a = n + x[2] * u + x[3] * v
        a /= np.linalg.norm(a)
        c = c0 + x[0] * u + x[1] * v
        e1 = np.cross(a, u)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        th = np.arange(0, 2 * np.pi, STEP / x[4])
        ring = c + x[4] * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)
        T = ring + (((c0 - ring) @ n) / (a @ n))[:, None] * a  # along the axis onto the plane
        rc = float(np.sqrt(np.mean(resid(x) ** 2)))
        D = P - c
        radial = np.linalg.norm(D - np.outer(D @ a, a), axis=1)
        up = np.sign(np.mean((C - c0) @ n))
        tube = P[(np.abs(radial - x[4]) <= max(3 * rc, 0.002)) & (up * ((P - c0) @ n) > SIDE)]
        F = _on_plane(P, c0, n, ra)
        Dp = F - c
        plate = F[np.linalg.norm(Dp - np.outer(Dp @ a, a), axis=1) > x[4] + SIDE]
        ok = _both_sides(T, plate, tube, self.reach)
        if ok.all():
            return [np.vstack([T, T[:1]])], float(np.hypot(ra, rc) / np.sqrt(2))
        k = int(np.argmin(ok))  # start the walk at a gap so a run never wraps around
        return _shown_runs(np.roll(T, -k, axis=0), np.roll(ok, -k)), float(np.hypot(ra, rc) / np.sqrt(2))


# ------------------------------------------------------------------------------------------------ scans


@dataclass
class RealScan:
    """One public scan: where it is (git path at a commit of the fetched snapshot) and what it shows."""

    name: str
    path: str
    commit: str
    sensor: str
    shows: str
    view: tuple  # box (mm) drawn in the picture
    truth: TwoPlanes | PlaneCylinder | None = None
    table: tuple | None = None  # box (mm) on the supporting table: seams on its plane are contact lines
    units: str = "m"


THILL_HEAD = "44beaf0bb9339a696c3ed84f3474ed1b3bb4470f"
SCANS = [
    RealScan(
        "tee_lidar_aubo_i5", "pcd_images/table_tee/table_8in10in_tee_x0y24.pcd", THILL_HEAD,
        "RPLiDAR A2 swept by an Aubo i5", "steel T (plate standing on a 50 mm bar) on a table",
        view=((-130, -760, -60), (240, -440, 300)),
        truth=TwoPlanes(a=((-30, -600, 70), (45, -570, 240)), b=((-60, -626, 40), (185, -592, 62))),
        table=((-130, -760, -15), (240, -440, 8)),
    ),
    RealScan(
        "tube_on_plate_lidar_aubo_i10", "pcd_images/shape1_shape2/shape1_0deg_filtered.pcd", THILL_HEAD,
        "RPLiDAR A2 swept by an Aubo i10 (filtered)", "steel tube standing on a plate (saddle fillet)",
        view=((-280, -740, 0), (-90, -570, 100)),
        truth=PlaneCylinder(
            plate=((-270, -730, 25), (-100, -585, 40)), tube=((-215, -680, 45), (-125, -590, 85))
        ),
    ),
    RealScan(
        "t_joint_lidar_aubo_i10", "pcd_images/shape1_shape2/shape2_0deg_filtered.pcd", THILL_HEAD,
        "RPLiDAR A2 swept by an Aubo i10 (filtered)", "steel T-joint, sparse lines, no marked seam",
        view=((-480, -400, 270), (80, -240, 400)),
    ),
    RealScan(
        "tube_on_plate_depth_frame", "pcd_images/single_scans/1plate_1tube_partA_fig1_cropped.pcd",
        THILL_HEAD,
        "one RGB-D frame (the repo's 2024 RealSense set-up; the file names no sensor)",
        "square tube standing on a plate, seen from above one side",
        view=((-360, -210, 120), (60, 190, 280)),
        truth=TwoPlanes(a=((-150, -112, 185), (-80, -98, 250)), b=((-150, -190, 150), (-80, -118, 180))),
    ),
]


# --------------------------------------------------------------------------------------- run and score


@dataclass
class Run:
    """One ``weldcell seam`` run: its arguments, exit status, the error's fix line, the found seams."""

    args: list[str]
    rc: int
    fix: str = ""
    seams: list[dict] = field(default_factory=list)
    seconds: float = 0.0


def run_seam(cloud: Path, out: Path, extra: list[str]) -> Run:
    """``weldcell seam CLOUD -o OUT EXTRA...`` as a subprocess; the seams from the written JSON."""
    import time

    # the tree's own CLI; a worktree without its own .venv runs it with this interpreter (PYTHONPATH kept)
    cli = [str(WELDCELL)] if WELDCELL.exists() else [sys.executable, "-m", "weldcell.sdk.cli"]
    args = [*cli, "seam", str(cloud), "-o", str(out), *extra]
    out.unlink(missing_ok=True)
    t0 = time.perf_counter()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    p = subprocess.run(args, capture_output=True, text=True, env=env)
    run = Run(extra, p.returncode, seconds=time.perf_counter() - t0)
    m = re.search(r"fix:\s*(.*)", p.stdout + p.stderr)
    run.fix = m.group(1).strip() if m else ""
    if p.returncode == 0 and out.exists():
        run.seams = json.loads(out.read_text())["seams"]
    elif p.returncode not in (0, 2):
        print(p.stdout[-2000:], p.stderr[-2000:], file=sys.stderr)
    return run


def hint_args(fix: str) -> list[str]:
    """The arguments the error's fix line asks for: ``--t`` lowered if it says 'lower --t', and every
    ``--set ROLE.KEY=VALUE`` it names (quotes removed)."""
    extra = ["--t", str(HINT_T)] if "lower --t" in fix else []
    for m in re.finditer(r"--set\s+(\S+?='[^']*'|\S+)", fix):
        extra += ["--set", m.group(1).replace("'", "")]
    return extra


def resample(P: np.ndarray) -> np.ndarray:
    """Polyline ``P`` resampled every :data:`STEP`."""
    P = np.asarray(P, float)
    if len(P) < 2:
        return P
    s = np.r_[0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]
    q = np.linspace(0, s[-1], max(2, int(s[-1] / STEP) + 1))
    return np.column_stack([np.interp(q, s, P[:, k]) for k in range(3)])


def score(found: list[dict], truth: list[np.ndarray], tol: float) -> tuple[float, float]:
    """Precision (share of found seam length within ``tol`` of the marked seam) and recall (share of the
    marked, scanned seam within ``tol`` of a found one)."""
    F = [resample(np.asarray(s["points"])) for s in found if len(s["points"]) >= 2]
    if not F or not truth:
        return 0.0, 0.0
    F, T = np.vstack(F), np.vstack([resample(t) for t in truth])
    precision = float(np.mean(cKDTree(T).query(F, k=1)[0] <= tol))
    recall = float(np.mean(cKDTree(F).query(T, k=1)[0] <= tol))
    return precision, recall


def on_table(found: list[dict], P: np.ndarray, box: tuple | None) -> int:
    """How many found seams lie on the table's plane (median distance below 5 mm)."""
    if box is None or not found:
        return 0
    c, n, _ = fit_plane(P[_in_box(P, box)])
    return sum(float(np.median(np.abs((np.asarray(s["points"]) - c) @ n))) < LOOSE for s in found)


def seam_text(seams: list[dict]) -> str:
    """'n: L1, L2 mm (centre x,y,z mm; ...)' for the table."""
    if not seams:
        return "none"
    parts = []
    for s in seams:
        c = np.asarray(s["points"]).mean(axis=0) * 1000
        parts.append(f"{s['length'] * 1000:.0f} mm at ({c[0]:.0f}, {c[1]:.0f}, {c[2]:.0f})")
    return f"{len(seams)}: " + "; ".join(parts)


def diagnose(P: np.ndarray, truth: list[np.ndarray], viewpoint: tuple | None = None, **seam: object) -> dict:
    """Where the marked seam is lost inside the stage, with the CLI's default stages run in-process on
    the same points: the spacings and radius the stage derived, the share of all points that are eq. 16
    edge points, the share of the marked seam with an edge point within 3 mm and the classes of those
    edge points, and the support plane the stage found (its normal). ``seam``: seam-stage settings."""
    from weldcell.plugins.scan_plan.seams.model import LABEL_NAMES
    from weldcell.plugins.scan_plan.stages import (
        BilateralDenoiser,
        BilateralSettings,
        EdgeSeamExtractor,
        EdgeSeamSettings,
    )
    from weldcell.sdk.cloud import PointCloud
    from weldcell.sdk.stages import denoised_scan

    views = None if viewpoint is None else np.asarray([viewpoint], float)
    cloud = PointCloud(points=P, frame="base", viewpoints=views)
    clean = denoised_scan(cloud, BilateralDenoiser(BilateralSettings())(cloud))
    ex = EdgeSeamExtractor(EdgeSeamSettings(**seam))(clean)
    Q = np.asarray(clean.points)
    fine, coarse = ex.params["spacing"]
    out = {"points": len(Q), "fine": fine, "coarse": coarse, "radius": ex.radius,
           "edge_share": float(ex.edge_mask.mean()), "support": ex.params.get("support"),
           "seams": len(ex.seams)}
    structure = getattr(clean, "structure", None)  # the scan's structure (a tree before 2026-11-25: none)
    out["structure"] = structure.summary() if structure is not None else "-"
    if truth:
        T = np.vstack([resample(x) for x in truth])
        E = np.flatnonzero(ex.edge_mask)
        d, j = cKDTree(Q[E]).query(T, k=1) if len(E) else (np.full(len(T), np.inf), None)
        out["truth_edge_share"] = float(np.mean(d <= 0.003))
        near = E[np.unique(cKDTree(Q[E]).query_ball_point(T, 0.003, return_sorted=False).sum())] \
            if len(E) and (d <= 0.003).any() else np.zeros(0, int)
        labels, counts = np.unique(ex.labels[near], return_counts=True)
        out["truth_labels"] = {LABEL_NAMES[int(k)]: int(c) for k, c in zip(labels, counts, strict=True)}
    return out


# ------------------------------------------------------------------------------------------------ picture


def picture(scan: RealScan, P: np.ndarray, truth: list[np.ndarray], runs: list[Run], path: Path) -> None:
    """Three orthographic views of the cloud in ``scan.view``: marked seam green, found seams red
    (defaults) and orange (hint)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    Q = P[_in_box(P, scan.view)] * 1000
    fig, axes = plt.subplots(1, 3, figsize=(18, 6))
    for ax, (i, j) in zip(axes, [(0, 1), (0, 2), (1, 2)], strict=True):
        ax.scatter(Q[:, i], Q[:, j], s=0.4, c="0.6", rasterized=True)
        for t in truth:
            ax.plot(t[:, i] * 1000, t[:, j] * 1000, "-", c="limegreen", lw=4, alpha=0.7)
        for run, colour in zip(runs, ("red", "orange"), strict=False):
            for s in run.seams:
                S = np.asarray(s["points"]) * 1000
                ax.plot(S[:, i], S[:, j], "-", c=colour, lw=1.6)
        ax.set_aspect("equal")
        ax.set_xlabel("xyz"[i] + " (mm)")
        ax.set_ylabel("xyz"[j] + " (mm)")
    labels = ["marked seam (green)"] + [
        f"{c}: {' '.join(r.args) or 'defaults'} -> {len(r.seams)} seam(s), exit {r.rc}"
        for r, c in zip(runs, ("red", "orange"), strict=False)
    ]
    fig.suptitle(f"{scan.name}: {scan.shows}\n" + " | ".join(labels), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    plt.close(fig)


# ------------------------------------------------------------------------------------------------- main


def extract(scan: RealScan, mirror: Path, out: Path) -> Path:
    """The scan's file from the fetched git directory into ``out`` (unchanged bytes)."""
    dst = out / Path(scan.path).name
    if not dst.exists():
        blob = subprocess.run(["git", "-C", str(mirror), "show", f"{scan.commit}:{scan.path}"],
                              capture_output=True, check=True).stdout
        dst.write_bytes(blob)
    return dst


def evaluate_scan(scan: RealScan, mirror: Path, out: Path) -> dict:
    """Runs, statistics and scores of one scan (see the module docstring)."""
    cloud = extract(scan, mirror, out)
    P = load_points(cloud, scan.units)
    if cloud.suffix.lower() not in (".ply", ".pcd") or scan.units != "m":
        cloud = as_cloud_file(P, out / f"{scan.name}.ply")
    nn, across = spacing(P)
    runs = [run_seam(cloud, out / f"{scan.name}_defaults.json", [])]
    # the hint of the CLI's "no weld seam was found" error, also when the defaults found (false) seams
    fix = runs[0].fix or "lower --t, or --set seam.min_seam_length='10 mm'"
    runs.append(run_seam(cloud, out / f"{scan.name}_hint.json", hint_args(fix)))
    truth, noise = scan.truth.mark(P) if scan.truth is not None else ([], float("nan"))
    row = {"scan": scan, "points": len(P), "nn": nn, "across": across, "extent": np.ptp(P, axis=0),
           "truth_len": sum(len(t) for t in truth) * STEP, "noise": noise, "runs": []}
    for run in runs:
        p15, r15 = score(run.seams, truth, TOLERANCE)
        p5, r5 = score(run.seams, truth, LOOSE)
        row["runs"].append({"run": run, "p15": p15, "r15": r15, "p5": p5, "r5": r5,
                            "table": on_table(run.seams, P, scan.table)})
    picture(scan, P, truth, runs, out / f"{scan.name}.png")
    row["diagnosis"] = diagnose(P, truth)
    return row


def table(rows: list[dict]) -> list[str]:
    """The markdown table of the docs."""
    head = ("| scan | points | spacing along / across (mm) | marked seam (mm), face RMS (mm) | run | exit "
            "| seams found (length, centre mm) | P / R at 1.5 mm | P / R at 5 mm | on table |")
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        s = r["scan"]
        marked = "not marked"
        if s.truth is not None:
            marked = f"{r['truth_len'] * 1000:.0f}, {r['noise'] * 1000:.1f}"
        for i, x in enumerate(r["runs"]):
            run = x["run"]
            pr = (lambda p, q: f"{p:.2f} / {q:.2f}") if s.truth is not None else (lambda p, q: "-")
            first = (f"{s.name} | {r['points']} | {r['nn'] * 1000:.1f} / {r['across'] * 1000:.1f} | {marked}"
                     if i == 0 else " | | | ")
            lines.append(
                f"| {first} | {' '.join(run.args) or 'defaults'} | {run.rc} | {seam_text(run.seams)} "
                f"| {pr(x['p15'], x['r15'])} | {pr(x['p5'], x['r5'])} | {x['table'] if s.table else '-'} |"
            )
    return lines


def diagnosis_table(rows: list[dict]) -> list[str]:
    """Where the marked seam is lost inside the stage (defaults; :func:`diagnose`)."""
    lines = [
        "| scan | points after denoise | spacing fine / coarse, r (mm) | eq. 16 edge points (all) "
        "| marked seam with an edge point within 3 mm | their classes | support plane | scan structure |",
        "|" + "---|" * 8,
    ]
    for r in rows:
        d = r["diagnosis"]
        labels = ", ".join(f"{k} {v}" for k, v in d.get("truth_labels", {}).items()) or "-"
        share = f"{d['truth_edge_share']:.0%}" if "truth_edge_share" in d else "-"
        sup = "none" if d["support"] is None else "n = (" + ", ".join(f"{v:.2f}" for v in d["support"]) + ")"
        lines.append(f"| {r['scan'].name} | {d['points']} | {d['fine'] * 1e3:.1f} / {d['coarse'] * 1e3:.1f}, "
                     f"{d['radius'] * 1e3:.1f} | {d['edge_share']:.0%} | {share} | {labels} | {sup} "
                     f"| {d.get('structure', '-')} |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mirror", type=Path, default=DEFAULT_MIRROR, help="fetched thillRobot/seam_detection")
    ap.add_argument("--out", type=Path, default=Path("/tmp/seam_real_scans"), help="files, JSON, pictures")
    ap.add_argument("--only", default="", help="run only the scans whose name contains this")
    a = ap.parse_args()
    if not (a.mirror / "HEAD").exists() and not (a.mirror / ".git").exists():
        sys.exit(f"{a.mirror}: no git directory; fetch github:thillRobot/seam_detection (see the docstring)")
    a.out.mkdir(parents=True, exist_ok=True)
    rows = [evaluate_scan(s, a.mirror, a.out) for s in SCANS if a.only in s.name]
    print("\n".join(table(rows)))
    print()
    print("\n".join(diagnosis_table(rows)))
    print(f"\npictures and path JSON in {a.out}")


if __name__ == "__main__":
    main()
