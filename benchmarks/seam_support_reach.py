"""How far a candidate support plane reaches beyond the part, by direction (issue 16, seams doc "Issue 16").

Run:  .venv/bin/python benchmarks/seam_support_reach.py [--only 2 11 29 46] [--lone]

For each cloud (evaluation-set cases, denoised as the job does, and with ``--lone`` the CLI tests' lone
V-groove plates), every plane the seam stage's :func:`~weldcell.plugins.scan_plan.seams.support_plane`
considers is printed with its hull measures (``SURROUND`` share, ``ENCLOSE`` corner share) and its
directional reach: ``min_d (h_plane(d) - h_part(d))`` over 16 evenly spaced directions in the plane, of
the support functions ``h`` of the plane's inliers and of the part's points (all of them, and those
within 3 mm of the part's nearest point to the plane), and whether the plane is the case's true table.
Asserts nothing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan.cloud_numerics import sampling_spacings
from weldcell.plugins.scan_plan.seams import pipeline, support
from weldcell.plugins.scan_plan.seams.settings import SeamSettings
from weldcell.plugins.scan_plan.stages import BilateralDenoiser, BilateralSettings
from weldcell.sdk.cloud import PointCloud

DIRECTIONS = 16
_planes: list[dict] = []
_hull_measures = support._surrounds


def reach(plane_pts: np.ndarray, part: np.ndarray, n: np.ndarray) -> float:
    """``min_d (h_plane(d) - h_part(d))`` (m) over :data:`DIRECTIONS` directions in the plane ``n``."""
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    B = np.column_stack([u, np.cross(n, u)])
    a = np.linspace(0.0, 2.0 * np.pi, DIRECTIONS, endpoint=False)
    D = B @ np.vstack([np.cos(a), np.sin(a)])
    return float(((plane_pts @ D).max(axis=0) - (part @ D).max(axis=0)).min()) if len(part) else float("nan")


def _recording(plane_pts, part, n, margin):
    share, corners = _hull_measures(plane_pts, part, n, margin)
    d = part @ n - float(np.median(plane_pts @ n))
    foot = part[d <= d.min() + 0.003] if len(d) else part
    _planes.append(
        dict(
            n=n.copy(),
            share=share,
            corners=corners,
            all=reach(plane_pts, part, n),
            foot=reach(plane_pts, foot, n),
        )
    )
    return share, corners


def report(name: str, P: np.ndarray, table_n: np.ndarray | None) -> None:
    _planes.clear()
    tree = cKDTree(P)
    fine, coarse = sampling_spacings(P, tree)
    _, chosen = pipeline._normals(P, tree, None, SeamSettings(), None, fine, coarse)
    for p in _planes:
        table = "-" if table_n is None else str(abs(float(p["n"] @ table_n)) > 0.98)
        used = chosen is not None and abs(float(chosen.normal @ p["n"])) > 0.999
        print(
            f"{name}: spacing {1e3 * fine:.2f} / {1e3 * coarse:.2f} mm, surround {p['share']:.2f}, "
            f"enclose {p['corners']:.2f}, reach {1e3 * p['all']:.1f} mm, "
            f"foot reach {1e3 * p['foot']:.1f} mm, "
            f"true table {table}, chosen {used}",
            flush=True,
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", type=int, nargs="*", default=[], help="evaluation-set case indices (seed 0)")
    ap.add_argument("--lone", action="store_true", help="also the CLI tests' lone V-groove plates")
    args = ap.parse_args()
    support._surrounds = _recording
    denoise = BilateralDenoiser(BilateralSettings())
    if args.lone:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
        from scan_plan.test_scan_plan_cli import groove_cloud

        for n, seed in ((10_000, 1), (10_000, 2), (150_000, 0)):
            report(f"groove_cloud({n}, seed={seed})", denoise(groove_cloud(n, seed=seed)).points, None)
    from weldcell.testing.seam_cases import make_case

    for i in args.only:
        c = make_case(i, 0)
        clean = denoise(PointCloud(c.points, frame="base"))
        report(c.name, clean.points, np.asarray(c.params["table_normal"], dtype=float).reshape(3))


if __name__ == "__main__":
    main()
