"""What the scan-and-plan report measures on a weld path, and its pictures (each answers one question).

* :func:`seam_measures` - per seam: length, points, torch poses, the work and travel angles and the
  standoff *as planned in the poses* (measured back from the poses against the seam's own frame, not
  copied from the settings), and in simulation the error against the true seam.
* :func:`cross_section_figure` - does the torch point into the joint at the right standoff and angle?
* :func:`overview_figure` - where on the part are the seams, and which way does each run?
* :func:`seam_error_figure` - (simulation) where along each seam is the found line off, and by how much?
* :func:`fitness_figure` - did ICP improve each view's fit, and by how large a correction?
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from weldcell.sdk.weldpath import SeamPath

SEAM_COLOURS = ("#d62728", "#1f77b4", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf", "#bcbd22")


def _deg1(rad: float) -> str:
    """Degrees with one decimal, without a '-0.0'."""
    s = f"{np.degrees(rad):.1f}"
    return "0.0" if s == "-0.0" else s


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


@dataclass
class SeamFrames:
    """The seam's own frame at each torch pose: ``point`` on the seam line, unit ``approach`` (into the
    joint) and ``travel`` (orthogonal to approach), and ``side`` = approach x travel."""

    point: np.ndarray
    approach: np.ndarray
    travel: np.ndarray

    @property
    def side(self) -> np.ndarray:
        return np.cross(self.approach, self.travel)


def seam_frames(seam: SeamPath) -> SeamFrames:
    """The seam frame nearest each torch pose (approach from the seam's recorded ``approach``, travel
    from the seam line's averaged direction)."""
    from weldcell.plugins.scan_plan.torch_path import travel_directions

    P = np.asarray(seam.points, dtype=float)
    A = np.asarray(seam.extra.get("approach", []), dtype=float).reshape(-1, 3)
    T = np.asarray(seam.poses, dtype=float)
    if len(A) != len(P):  # a path from elsewhere: the torch axis stands in for the approach
        A = np.array([T[np.argmin(np.linalg.norm(T[:, :3, 3] - p, axis=1)), :3, 2] for p in P])
    travel = travel_directions(P, 5, bool(seam.closed)) if len(P) > 1 else np.tile([1.0, 0, 0], (len(P), 1))
    a = _unit(A)
    x = _unit(travel - np.einsum("ij,ij->i", travel, a)[:, None] * a)
    # each pose aims at a point of the seam: the nearest seam point to its axis (a few candidates)
    o, z = T[:, :3, 3], T[:, :3, 2]
    tree = cKDTree(P)
    k = min(8, len(P))
    reach = float(np.median(np.linalg.norm(P[tree.query(o, k=1)[1]] - o, axis=1))) if len(o) else 0.0
    _, cand = tree.query(o + reach * z, k=k)
    cand = np.asarray(cand).reshape(len(o), k)
    rel = P[cand] - o[:, None, :]
    along = np.einsum("ijk,ik->ij", rel, z)
    perp = np.linalg.norm(rel - along[..., None] * z[:, None, :], axis=2)
    idx = cand[np.arange(len(o)), np.argmin(perp, axis=1)]
    return SeamFrames(P[idx], a[idx], x[idx])


@dataclass
class SeamMeasures:
    """One seam as the report shows it (lengths in m, angles in rad)."""

    id: str
    joint: str
    length: float
    points: int
    poses: int
    closed: bool
    work_angle: np.ndarray
    travel_angle: np.ndarray
    standoff: np.ndarray
    truth: str | None = None
    error: dict = field(
        default_factory=dict
    )  # per_seam entry of evaluate(): translation_m, rotation_rad, ...
    error_along: tuple[np.ndarray, np.ndarray] | None = None  # (arc length, distance to the truth) [m]


def torch_angles(seam: SeamPath) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(work angle, travel angle, standoff) of every torch pose, measured from the poses: the work angle
    is the torch axis's tilt about the travel direction away from the joint's approach direction, the
    travel angle its lean towards travel (+ push, - drag), the standoff the distance along the torch
    axis from the TCP to the seam point it aims at."""
    f = seam_frames(seam)
    T = np.asarray(seam.poses, dtype=float)
    z, o = T[:, :3, 2], T[:, :3, 3]
    travel = np.arcsin(np.clip(np.einsum("ij,ij->i", z, f.travel), -1, 1))
    work = np.arctan2(-np.einsum("ij,ij->i", z, f.side), np.einsum("ij,ij->i", z, f.approach))
    standoff = np.einsum("ij,ij->i", f.point - o, z)
    return work, travel, standoff


def _distance_to_polyline(Q: np.ndarray, G: np.ndarray) -> np.ndarray:
    """Distance of each point of Q to the polyline G (segments)."""
    if len(G) < 2:
        return np.linalg.norm(Q - G[0], axis=1)
    A, B = G[:-1], G[1:]
    AB = B - A
    best = np.full(len(Q), np.inf)
    for s in range(0, len(A), 256):
        a, ab = A[s : s + 256], AB[s : s + 256]
        t = np.clip(
            np.einsum("qsk,sk->qs", Q[:, None, :] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-18), 0, 1
        )
        d = np.linalg.norm(Q[:, None, :] - (a[None] + t[..., None] * ab[None]), axis=2)
        best = np.minimum(best, d.min(axis=1))
    return best


def seam_measures(path, gt) -> list[SeamMeasures]:
    """:class:`SeamMeasures` of every seam of ``path``; ``gt`` the ground truth [(name, seam)] or None."""
    per = {p["seam"]: p for p in path.metrics.get("per_seam", [])} if gt else {}
    out = []
    for seam in path.seams:
        work, travel, standoff = torch_angles(seam)
        m = SeamMeasures(
            seam.id,
            seam.joint,
            seam.length,
            len(seam.points),
            len(seam.poses),
            bool(seam.closed),
            work,
            travel,
            standoff,
        )
        if seam.id in per:
            m.error = per[seam.id]
            m.truth = per[seam.id].get("truth")
            name = str(m.truth).split("/")[0]
            truth = next((s for n, s in gt if n == name), None)
            if truth is not None:
                P = np.asarray(seam.points, dtype=float)
                s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
                m.error_along = (s, _distance_to_polyline(P, np.asarray(truth.points, dtype=float)))
        out.append(m)
    return out


def point_spacing(points: np.ndarray, sample: int = 4000, seed: int = 0) -> float:
    """Median nearest-neighbour distance of a cloud (from a seeded sample of it) [m]."""
    P = np.asarray(points, dtype=float)
    if len(P) < 2:
        return 1e-3
    idx = np.random.default_rng(seed).choice(len(P), size=min(sample, len(P)), replace=False)
    d, _ = cKDTree(P).query(P[idx], k=2)
    return float(np.median(d[:, 1]))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _draw_torch(ax, o_uv: np.ndarray, z_uv: np.ndarray, standoff: float) -> None:
    """The torch in a cross-section (mm): the wire from the TCP to the work, the contact tip and a
    tapered nozzle behind it, along the torch axis ``z_uv`` (unit, in the section plane)."""
    from matplotlib.patches import Polygon

    z = z_uv / max(np.linalg.norm(z_uv), 1e-9)
    n = np.array([-z[1], z[0]])
    tip = o_uv
    ax.plot(*np.c_[tip, tip + z * standoff], color="#444", lw=1.2, zorder=5, label="wire (stick-out)")
    back = 18.0
    nozzle = [tip - 3 * z + 4 * n, tip - 3 * z - 4 * n, tip - back * z - 7 * n, tip - back * z + 7 * n]
    ax.add_patch(Polygon(nozzle, closed=True, fc="#cfd8e3", ec="#36454f", lw=1.2, zorder=4, label="nozzle"))
    ax.plot(*tip, "o", color="#36454f", ms=4, zorder=6)


def cross_section_figure(cloud: np.ndarray, seam: SeamPath, m: SeamMeasures, gt_points=None, spacing=None):
    """Three cuts across one seam (near its start, middle and end), zoomed on the joint, with the torch
    drawn: does the torch point into the joint at the right standoff and angle?

    Each cut is a slab of the cloud three point spacings thick, perpendicular to travel; the view is
    the seam's own frame: horizontal = across the joint, up = away from the work (minus approach).
    """
    plt = _plt()
    P = np.asarray(cloud, dtype=float)
    spacing = spacing or point_spacing(P)
    f = seam_frames(seam)
    T = np.asarray(seam.poses, dtype=float)
    stations = np.unique(np.round(np.array([0.1, 0.5, 0.9]) * (len(T) - 1)).astype(int))
    half = 1e3 * max(float(np.nanmedian(m.standoff)) + 0.010, 0.015)
    fig, axes = plt.subplots(1, len(stations), figsize=(4.6 * len(stations), 4.4), squeeze=False)
    tree = cKDTree(P)
    for ax, i in zip(axes[0], stations, strict=True):
        c, a, x, h = f.point[i], f.approach[i], f.travel[i], f.side[i]
        near = P[tree.query_ball_point(c, r=half * 1.5e-3)]
        rel = near - c
        slab = near[np.abs(rel @ x) < 1.5 * spacing] - c
        u, v = 1e3 * slab @ h, -1e3 * slab @ a
        ax.scatter(u, v, s=4, c="#555", alpha=0.6, lw=0, rasterized=True, label="scanned points")
        o = T[i, :3, 3] - c
        z = T[i, :3, 2]
        _draw_torch(
            ax, 1e3 * np.array([o @ h, -(o @ a)]), np.array([z @ h, -(z @ a)]), 1e3 * float(m.standoff[i])
        )
        ax.plot(0, 0, "x", color="#d62728", ms=9, mew=2, zorder=7, label="seam found")
        if gt_points is not None and len(gt_points):
            g = np.asarray(gt_points, dtype=float)
            gi = np.argmin(np.linalg.norm(g - c, axis=1))
            ax.plot(
                1e3 * (g[gi] - c) @ h,
                -1e3 * (g[gi] - c) @ a,
                "+",
                color="#2ca02c",
                ms=11,
                mew=2,
                zorder=7,
                label="true seam",
            )
        s_along = 1e3 * float(np.linalg.norm(np.diff(T[: i + 1, :3, 3], axis=0), axis=1).sum())
        ax.set_title(
            f"{seam.id} at {s_along:.0f} mm: work {_deg1(m.work_angle[i])}°, "
            f"travel {'+' if m.travel_angle[i] >= 0 else ''}{_deg1(m.travel_angle[i])}°\n"
            f"standoff {1e3 * m.standoff[i]:.1f} mm",
            fontsize=9,
        )
        ax.set_xlim(-half, half)
        top = 1e3 * float(m.standoff[i]) + 22.0
        ax.set_ylim(-0.35 * top, top)
        ax.set_aspect("equal")
        ax.set_xlabel("across the joint [mm]")
        ax.grid(alpha=0.25)
    axes[0][0].set_ylabel("up from the seam (away from the work) [mm]")
    axes[0][0].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"Seam {seam.id} ({seam.joint}): cuts across the joint, torch as planned", fontsize=11)
    fig.tight_layout()
    return fig


def overview_figure(cloud: np.ndarray, path, gt, max_points: int = 40000):
    """Top view of the part with every seam labelled at its start and an arrow for its direction of
    travel (the true seams, in simulation, drawn beside as thin dashed lines): where on the part are
    the seams, and which way does each run?"""
    plt = _plt()
    from weldcell.sdk.html_report import decimate

    P = np.asarray(cloud, dtype=float)
    Q = 1e3 * P[decimate(P, max_points)]
    fig, ax = plt.subplots(figsize=(8, 6.5))
    ax.scatter(Q[:, 0], Q[:, 1], s=0.3, c=Q[:, 2], cmap="Greys", alpha=0.6, lw=0, rasterized=True)
    for k, (_, s) in enumerate(gt or []):
        g = 1e3 * np.asarray(s.points)
        ax.plot(
            g[:, 0], g[:, 1], "--", color="#2ca02c", lw=1.0, label="true seam" if k == 0 else None, zorder=3
        )
    for k, seam in enumerate(path.seams):
        col = SEAM_COLOURS[k % len(SEAM_COLOURS)]
        q = 1e3 * np.asarray(seam.points)
        ax.plot(
            q[:, 0], q[:, 1], "-", color=col, lw=2.2, alpha=0.85, label=f"{seam.id} ({seam.joint})", zorder=4
        )
        j = min(len(q) - 1, max(1, len(q) // 8))
        ax.annotate("", xy=q[j, :2], xytext=q[0, :2], arrowprops={"arrowstyle": "-|>", "color": col, "lw": 2})
        ax.text(q[0, 0], q[0, 1], f" {seam.id} start", color=col, fontsize=9, fontweight="bold", zorder=5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [mm] (robot base)")
    ax.set_ylabel("y [mm] (robot base)")
    ax.set_title("Seams on the part, seen from above (arrow: direction of travel)")
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.2)
    fig.tight_layout()
    return fig


def seam_error_figure(measures: list[SeamMeasures], attention_m: float):
    """Distance from each found seam line to its true seam along the seam: where is it off, by how
    much? The dashed line is the level the report flags."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 3.4))
    for k, m in enumerate(measures):
        if m.error_along is None:
            continue
        s, d = m.error_along
        ax.plot(1e3 * s, 1e3 * d, color=SEAM_COLOURS[k % len(SEAM_COLOURS)], label=f"{m.id} vs {m.truth}")
    ax.axhline(
        1e3 * attention_m, ls="--", color="#9a6700", lw=1, label=f"flagged above {1e3 * attention_m:g} mm"
    )
    ax.set_xlabel("along the found seam [mm]")
    ax.set_ylabel("distance to the true seam [mm]")
    ax.set_ylim(bottom=0)
    ax.set_title("How far the found seam line is from the true one")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def correction_sizes(rec) -> tuple[np.ndarray, np.ndarray]:
    """Translation [m] and rotation [rad] of each view's ICP correction (identity for the first view)."""
    C = [np.asarray(c, dtype=float) for c in getattr(rec, "corrections", [])]
    if not C:
        return np.zeros(len(rec.fitness)), np.zeros(len(rec.fitness))
    t = np.array([np.linalg.norm(c[:3, 3]) for c in C])
    r = np.array([Rotation.from_matrix(c[:3, :3]).magnitude() for c in C])
    return t, r


def fitness_figure(rec):
    """Per view: fitness (eq. 20) before ICP (kinematics + hand-eye) and after, joined by a line, with
    the size of the ICP correction written beside: did ICP improve each view's fit, and how much did
    it have to move the view? Rejected corrections are red."""
    plt = _plt()
    fb, fa = np.asarray(rec.fitness_before, dtype=float), np.asarray(rec.fitness, dtype=float)
    acc = np.asarray(getattr(rec, "accepted", [True] * len(fa)), dtype=bool)
    t, r = correction_sizes(rec)
    n = len(fa)
    fig, ax = plt.subplots(figsize=(8, 0.5 * n + 1.6))
    y = np.arange(n)
    for i in range(n):
        col = "#2da44e" if acc[i] else "#cf222e"
        ax.plot([fb[i], fa[i]], [y[i], y[i]], "-", color=col, lw=2, zorder=2)
        ax.text(
            1.02,
            y[i],
            f"{fa[i] - fb[i]:+.3f}; {1e3 * t[i]:.1f} mm, {np.degrees(r[i]):.2f}°"
            + ("" if acc[i] else " rejected"),
            va="center",
            fontsize=8,
            transform=ax.get_yaxis_transform(),
            color=col,
        )
    ax.scatter(fb, y, s=40, facecolors="white", edgecolors="#57606a", zorder=3, label="before ICP")
    ax.scatter(fa, y, s=40, c=np.where(acc, "#2da44e", "#cf222e"), zorder=4, label="after ICP")
    ax.set_yticks(y, [f"view {i}" + (" (first)" if i == 0 else "") for i in range(n)])
    ax.invert_yaxis()
    ax.set_xlim(0, 1.02)
    ax.set_xlabel("fitness (eq. 20): share of the view's points on the model merged before it")
    ax.set_title(
        "ICP per view: fit before → after (right: the change and the correction applied)", fontsize=10
    )
    ax.grid(alpha=0.3, axis="x")
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    return fig
