"""Scan structure (plugins/scan_plan/scan_structure.py) against the truth: generated cases and real scans.

Run:  .venv/bin/python benchmarks/scan_structure_eval.py [--cases 66] [--seed 0] [--real] [--denoised]

1. Generated cases (testing/seam_cases.py, ``make_case(i, seed)`` for i < ``--cases``: joints, placements
   over the whole sphere incl. vertical and overhead, base frames turned at random, three scanners). The
   truth is taken from the simulation itself: the profiler's step between profiles (the sweep's eye
   positions; the sheet normal is the sweep direction, so this is the distance between the sheets; of a
   two-sweep scan, the sweep's step nearest the estimate), and
   the surface noise as ``1.4826 x median |distance to the scene's meshes|`` of the scanned points (the
   noise along the surface normal; robust to the few points at edges). Per case: line-structured or not,
   share of points on slices, sheet gap and line spacing on the surface, noise; today's
   ``sampling_spacings`` coarse spacing and ``noise_level`` (at the seam stage's reach) beside them.
2. ``--real``: the four public scans of benchmarks/seam_real_scans.py (thillRobot/seam_detection, GPL-3.0,
   read locally from the fetched snapshot, nothing shipped), against the hand measurements of
   docs/methods/seams-and-paths.md ("Real weldment scans": tee profiles 4.5-4.8 mm apart, noise 0.6-1 mm).
3. ``--denoised``: also on the cloud the seam stage receives (the CLI's bilateral denoiser + voxel grid).
4. Time of :func:`scan_structure` on a 316,374-point cloud (with and without the caller's KD-tree), and of
   today's two estimators on it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def _truth_hooks():
    """Patch seam_cases so each make_case records the scene meshes, the scene-frame points and the
    profiler's poses (the module's own functions, called unchanged)."""
    import weldcell.testing.seam_cases as sc

    rec: dict = {}
    orig_cam, orig_line, orig_area = sc.RaycastCamera, sc._line_scan, sc._area_scan

    class Cam(orig_cam):  # type: ignore[misc,valid-type]
        def __init__(self, preset, meshes, *a, **k):
            rec["meshes"] = meshes
            super().__init__(preset, meshes, *a, **k)

    def line(cam, scn, center, dirs, travel, half, rng):
        pts, poses = orig_line(cam, scn, center, dirs, travel, half, rng)
        rec.update(points=pts, poses=poses)
        return pts, poses

    def area(cam, scn, center, dirs, rng):
        pts, poses = orig_area(cam, scn, center, dirs, rng)
        rec.update(points=pts, poses=poses)
        return pts, poses

    sc.RaycastCamera, sc._line_scan, sc._area_scan = Cam, line, area
    return sc, rec


def true_noise(points: np.ndarray, meshes) -> float:
    """1.4826 x median unsigned distance of ``points`` to ``meshes`` (m)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    for m in meshes:
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
    d = scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()
    return float(1.4826 * np.median(d))


def true_gaps(poses: list[np.ndarray]) -> list[float]:
    """The profiler's step of each sweep (m): the distances between consecutive eye positions that repeat
    (one per sweep; the jump between two sweeps occurs once)."""
    eyes = np.array([T[:3, 3] for T in poses])
    steps = np.round(np.linalg.norm(np.diff(eyes, axis=0), axis=1), 7)
    values, counts = np.unique(steps, return_counts=True)
    return [float(v) for v in values[counts > 2]]


def closest(value: float, options: list[float]) -> float:
    """The option nearest ``value`` (a two-sweep scan has two steps; the estimate matches one)."""
    return min(options, key=lambda o: abs(o - value))


def today(P: np.ndarray) -> tuple[float, float, float]:
    """Today's estimates as the seam stage makes them: fine and coarse spacing, noise at its reach."""
    from weldcell.plugins.scan_plan.cloud_numerics import noise_level, sampling_spacings

    tree = cKDTree(P)
    fine, coarse = sampling_spacings(P, tree)
    return fine, coarse, noise_level(P, max(3.0 * fine, 1.25 * coarse), sample=4000)


def denoised(P: np.ndarray) -> np.ndarray:
    """The cloud the CLI's seam stage receives (bilateral denoiser + voxel grid, default settings)."""
    from weldcell.plugins.scan_plan.stages import BilateralDenoiser, BilateralSettings
    from weldcell.sdk.cloud import PointCloud

    return np.asarray(BilateralDenoiser(BilateralSettings())(PointCloud(points=P, frame="base")).points)


def row(name: str, P: np.ndarray, gap: list[float] | None, noise: float | None) -> dict:
    """Estimates, truth (``gap``: the sweeps' steps; the nearest one is compared) and today's numbers."""
    from weldcell.plugins.scan_plan.scan_structure import scan_structure

    t0 = time.perf_counter()
    st = scan_structure(P)
    dt = time.perf_counter() - t0
    fine, coarse, nl = today(P)
    gap = closest(st.sheet_gap, gap) if gap else None
    return dict(name=name, n=len(P), st=st, gap=gap, noise=noise, fine=fine, coarse=coarse, nl=nl, dt=dt)


def fmt(r: dict) -> str:
    st = r["st"]
    mm = lambda v: "-" if v is None or not np.isfinite(v) else f"{v * 1e3:.2f}"  # noqa: E731
    ratio = lambda a, b: "-" if b is None else f"{a / b:.2f}"  # noqa: E731
    gap_ratio = ratio(st.sheet_gap, r["gap"]) if st.line_structured else "-"
    return (
        f"| {r['name']} | {r['n']} | {'line' if st.line_structured else 'area'} {st.line_share:.2f} "
        f"| {mm(st.along_spacing)} | {mm(st.sheet_gap)} / {mm(r['gap'])} | {gap_ratio} "
        f"| {mm(st.line_spacing)} | {mm(r['coarse'])} | {mm(st.noise)} / {mm(r['noise'])} "
        f"| {ratio(st.noise, r['noise'])} | {mm(r['nl'])} | {st.noise / r['nl']:.2f} "
        f"| {mm(st.span_radius)}, {st.span_neighbours} | {r['dt']:.2f} |"
    )


HEAD = (
    "| cloud | points | structure, share on slices | along (mm) | sheet gap est / true (mm) | gap ratio "
    "| line spacing on surface (mm) | today's coarse (mm) | noise est / true (mm) | noise ratio "
    "| today's noise_level (mm) | est / today | span radius (mm), points | s |\n" + "|---" * 14 + "|"
)


def generated(n: int, seed: int, with_denoised: bool) -> list[dict]:
    sc, rec = _truth_hooks()
    rows = []
    for i in range(n):
        case = sc.make_case(i, seed)
        gaps = true_gaps(rec["poses"]) if case.scanner == "line-laser" else None
        noise = true_noise(rec["points"], rec["meshes"])
        rows.append(row(case.name, case.points, gaps, noise))
        print(fmt(rows[-1]), flush=True)
        if with_denoised:
            rows.append(row(case.name + " (denoised)", denoised(case.points), gaps, noise))
            print(fmt(rows[-1]), flush=True)
    return rows


def real(with_denoised: bool) -> list[dict]:
    from seam_real_scans import DEFAULT_MIRROR, SCANS, extract, load_points

    out = Path("/tmp/seam_real_scans")
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for scan in SCANS:
        P = load_points(extract(scan, DEFAULT_MIRROR, out), scan.units)
        rows.append(row(scan.name, P, None, None))
        print(fmt(rows[-1]), flush=True)
        if with_denoised:
            rows.append(row(scan.name + " (denoised)", denoised(P), None, None))
            print(fmt(rows[-1]), flush=True)
    return rows


def summary(rows: list[dict]) -> None:
    """Per scanner: decisions, gap and noise ratios (min / median / max)."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r["noise"] is None:
            continue
        scanner = next(s for s in ("rgbd", "structured-light", "line-laser") if s in r["name"])
        groups.setdefault(scanner + (" denoised" if "denoised" in r["name"] else ""), []).append(r)
    print(
        "\n| scanner | cases | read as line scan | share on slices | sheet gap est/true | noise est/true "
        "| noise est/today |\n|---|---|---|---|---|---|---|"
    )
    q = lambda v: f"{np.min(v):.2f} / {np.median(v):.2f} / {np.max(v):.2f}"  # noqa: E731
    for k, g in groups.items():
        line = [r["st"].line_structured for r in g]
        gaps = [r["st"].sheet_gap / r["gap"] for r in g if r["gap"] and r["st"].line_structured]
        print(
            f"| {k} | {len(g)} | {sum(line)} | {q([r['st'].line_share for r in g])} "
            f"| {q(gaps) if gaps else '-'} | {q([r['st'].noise / r['noise'] for r in g])} "
            f"| {q([r['st'].noise / r['nl'] for r in g])} |"
        )


def timing(index: int = 15, repeat: int = 3) -> None:
    """Seconds (best of ``repeat``) of :func:`scan_structure` on case ``index`` (316,374 points with seed
    0): with the caller's KD-tree, building its own, and today's ``sampling_spacings`` + ``noise_level``."""
    from weldcell.plugins.scan_plan.cloud_numerics import noise_level, sampling_spacings
    from weldcell.plugins.scan_plan.scan_structure import scan_structure
    from weldcell.testing.seam_cases import make_case

    P = make_case(index).points
    best = np.full(4, np.inf)
    for _ in range(repeat):
        t = [time.perf_counter()]
        tree = cKDTree(P, balanced_tree=False, compact_nodes=False)
        t.append(time.perf_counter())
        scan_structure(P, tree=tree)
        t.append(time.perf_counter())
        scan_structure(P)
        t.append(time.perf_counter())
        fine, coarse = sampling_spacings(P, tree)
        noise_level(P, max(3.0 * fine, 1.25 * coarse), sample=4000)
        t.append(time.perf_counter())
        best = np.minimum(best, np.diff(t))
    print(
        f"\ntiming on {len(P)} points (best of {repeat}): KD-tree {best[0]:.3f} s, scan_structure with that "
        f"tree {best[1]:.3f} s, building its own {best[2]:.3f} s; today's sampling_spacings + noise_level "
        f"{best[3]:.3f} s"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", type=int, default=66, help="generated cases 0..N-1 (joints x scanners cycle)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--real", action="store_true", help="also the public real scans (fetched snapshot)")
    ap.add_argument("--denoised", action="store_true", help="also the denoised + voxelised clouds")
    a = ap.parse_args()
    print(HEAD)
    rows = generated(a.cases, a.seed, a.denoised)
    if a.real:
        rows += real(a.denoised)
    summary(rows)
    timing()


if __name__ == "__main__":
    main()
