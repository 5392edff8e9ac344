"""The pose an as-built part *should* be localized at: the reference of the Table 1 pose error.

In the simulated cell the worker's placement (a rigid motion P about the template's centroid) is applied
before each member k is moved off CAD by its own small rigid motion V_k (:func:`.synth.member_variations`):
the as-built member k is ``P @ V_k`` applied to its CAD outline. Such a part has no single true pose, and
scoring the localization against P alone mixes its precision with the spread of the members' deviations.
The references below are computed from ground-truth geometry only (template, P, V_k, the plan's lines) --
never from the localizer's output, the sensor noise, the robot-sensor coupling or the edge extraction:

* :func:`asbuilt_pose_crossings` (the primary reference, ``pose_error_vs_asbuilt``): *the pose a perfect
  measurement of this as-built part along this inspection would return*. The exact points where the plan's
  lines cross a visible edge of the as-built part (a real height step, as a noiseless sensor with a
  point-sized spot would see it), each assigned to the CAD edge it belongs to, and the rigid pose that
  minimises the sum of their squared distances to those CAD edges' lines (the least-squares form of the
  paper's eq. 3 with the true correspondences). It weights members and edges as the inspection does.
* :func:`asbuilt_pose_outline` (``pose_error_vs_asbuilt_outline``): plan-independent -- the rigid motion
  that best maps the CAD outlines onto the as-built ones, every point of every member's outline weighted by
  arc length (Procrustes / Kabsch with the material correspondence, closed form).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .pose import rot2, wrap
from .template import Template


@dataclass
class AsBuiltReference:
    """A reference pose (x, y, theta) about the template's centroid, with what it was computed from:
    ``points`` the number of edge crossings (or outline samples) and ``rms`` their residual RMS (m) -- how
    far the as-built part is from any rigid copy of the CAD part, along this inspection."""

    pose: np.ndarray
    points: int
    rms: float


def _placement_matrix(pose, center) -> np.ndarray:
    P = np.eye(3)
    R = rot2(float(pose[2]))
    P[:2, :2] = R
    P[:2, 2] = np.asarray(center, float) + np.asarray(pose[:2], float) - R @ np.asarray(center, float)
    return P


def _pose_of(R: np.ndarray, t: np.ndarray, center: np.ndarray) -> np.ndarray:
    """(x, y, theta) about ``center`` of the rigid map p -> R p + t."""
    return np.array([*(t + R @ center - center), np.arctan2(R[1, 0], R[0, 0])])


def member_transforms(pose, center, variations: list[np.ndarray]) -> list[np.ndarray]:
    """Each as-built member's 3x3 map from its CAD outline: the placement after the member's deviation."""
    P = _placement_matrix(pose, center)
    return [P @ np.asarray(V, float) for V in variations]


def outline_samples(outline: np.ndarray, step: float) -> np.ndarray:
    """Points every ``step`` (at most) along a closed outline, each segment sampled at the midpoints of
    equal sub-intervals (so every length of edge carries the same weight)."""
    P = np.asarray(outline, float)
    Q = np.roll(P, -1, axis=0)
    out = []
    for a, b in zip(P, Q, strict=True):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        t = (np.arange(n) + 0.5) / n
        out.append(a + t[:, None] * (b - a))
    return np.concatenate(out)


def kabsch_2d(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R and translation t minimising sum |R src_i + t - dst_i|^2 (2-D, no reflection)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs


def asbuilt_pose_outline(
    template: Template, pose, variations: list[np.ndarray], step: float = 0.5e-3
) -> AsBuiltReference:
    """The rigid motion of the CAD part that best matches the as-built part's outlines (module docstring)."""
    c = template.centroid
    T = member_transforms(pose, c, variations)
    src = [outline_samples(m.outline, step) for m in template.members]
    dst = [s @ Tk[:2, :2].T + Tk[:2, 2] for s, Tk in zip(src, T, strict=True)]
    S, D = np.concatenate(src), np.concatenate(dst)
    R, t = kabsch_2d(S, D)
    rms = float(np.sqrt(((S @ R.T + t - D) ** 2).sum(axis=1).mean()))
    return AsBuiltReference(_pose_of(R, t, c), len(S), rms)


def visible_crossings(
    template: Template, pose, variations: list[np.ndarray], lines: list[np.ndarray], probe: float = 0.05e-3
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the plan's lines cross a visible edge of the as-built part: (points (K, 2), member (K,), CAD
    segment index within the member (K,)). A crossing is visible when the surface height just before and
    just after it along the line (``probe``) differs -- an edge hidden under another member is not."""
    from .plans import _crossings
    from .synth import height_at

    T = member_transforms(pose, template.centroid, variations)
    built = Template([type(m)(m.id, m.top, m.outline) for m in template.members], [], template.table_z)
    segs, owner, local = [], [], []
    for k, (m, Tk) in enumerate(zip(built.members, T, strict=True)):
        m.outline = m.outline @ Tk[:2, :2].T + Tk[:2, 2]
        s = m.segments()
        segs.append(s)
        owner.append(np.full(len(s), k))
        local.append(np.arange(len(s)))
    S, own, loc = np.concatenate(segs), np.concatenate(owner), np.concatenate(local)
    hits, js = [], []
    for ln in lines:
        ln = np.asarray(ln, float)
        if len(ln) >= 2:
            hit, j = _crossings(ln, S)
            hits.append(hit)
            js.append(j)
    if not hits or not sum(len(j) for j in js):
        return np.empty((0, 2)), np.empty(0, int), np.empty(0, int)
    hit, j = np.concatenate(hits), np.concatenate(js)
    d = S[j, 1] - S[j, 0]
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.linalg.norm(d, axis=1)[:, None]
    up, down = height_at(built, hit + probe * n), height_at(built, hit - probe * n)
    keep = np.abs(up - down) > 1e-6
    return hit[keep], own[j[keep]], loc[j[keep]]


def fit_to_lines(points: np.ndarray, a: np.ndarray, n: np.ndarray, center, start) -> np.ndarray:
    """The pose (x, y, theta) about ``center`` minimising sum (n_i . (M^-1 p_i - a_i))^2: each point's
    distance to the line through a_i with unit normal n_i (template frame) after the template is moved by
    M(pose). Least squares (scipy ``least_squares``, exact Jacobian), from ``start``."""
    c = np.asarray(center, float)

    def res(p):
        q = (points - c - p[:2]) @ rot2(p[2]) + c  # inverse_xy
        return np.einsum("ij,ij->i", q - a, n)

    def jac(p):
        R = rot2(p[2])
        m = n @ R.T  # the normals turned into the base frame
        v = points - c - p[:2]
        dR = np.array([[-np.sin(p[2]), np.cos(p[2])], [-np.cos(p[2]), -np.sin(p[2])]])  # d R^T / d theta
        return np.column_stack([-m, np.einsum("ij,ij->i", v @ dR.T, n)])

    sol = least_squares(res, np.asarray(start, float), jac=jac, method="lm", xtol=1e-15, ftol=1e-15)
    return sol.x


def asbuilt_pose_crossings(
    template: Template, pose, variations: list[np.ndarray], lines: list[np.ndarray]
) -> AsBuiltReference:
    """The pose a perfect measurement of the as-built part along ``lines`` would return (module docstring).
    Raises ValueError when the crossings cannot fix the pose (fewer than three, or a singular fit)."""
    pts, mem, seg = visible_crossings(template, pose, variations, lines)
    if len(pts) < 3:
        raise ValueError(f"{len(pts)} visible edge crossings: not enough to fix a rigid pose")
    cad = [m.segments() for m in template.members]
    a = np.stack([cad[k][j, 0] for k, j in zip(mem, seg, strict=True)])
    d = np.stack([cad[k][j, 1] - cad[k][j, 0] for k, j in zip(mem, seg, strict=True)])
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.linalg.norm(d, axis=1)[:, None]
    c = template.centroid
    p = fit_to_lines(pts, a, n, c, pose)
    p[2] = float(wrap(p[2]))
    q = (pts - c - p[:2]) @ rot2(p[2]) + c
    r = np.einsum("ij,ij->i", q - a, n)
    return AsBuiltReference(p, len(pts), float(np.sqrt((r**2).mean())))
