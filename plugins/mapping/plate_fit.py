"""A plate's box measured by analysis by synthesis: render the box into every key frame that saw it and
compare with the measured depth image, pixel by pixel (depth and silhouette).

Why: at 1-7° above a plate's top face (the route's views) the top face is 3-5 pixel rows tall at VGA;
the side faces' pixels crowd the near edge and the far part of the top face thins out (a row spans
15 cm of the plate there, grazing dropouts). A measurement on the points alone must assume how they are
spread over the plate, and the uniform spread (plate.py's interval fit) slides the plate towards the
camera by 2-14 cm. Rendering the box into each view needs no such assumption: which pixels the plate
covers, and at what depth, follows from the box, the key frame's pose and the intrinsics.

The box: centre x, y, yaw, length, width, top height and thickness (world frame, z up, the plate lying
flat). Per key frame, every pixel of the crop where the region was seen is one of

* **plate**: its measured depth lies within 3 σ of the box (grown by ``grow``) along its ray: a depth
  residual (measured - rendered z) / σ, σ the camera model's ``depth_noise``·z² / max(cos θ, 0.1) with θ
  from the rendered face; and a silhouette residual, how far (pixels) the pixel centre lies outside the
  box's projected outline, less half a pixel, over the pixel footprint's standard deviation 1/√12;
* **background**: its depth lies beyond the box by more than 3 σ (the ground, the stand below): a
  silhouette residual, how far it lies inside the outline, plus half a pixel, over 1/√12;
* **in front** or **no depth**: no residual.

Half a pixel: a pixel is plate when its centre is inside the outline, so between the last plate and the
first background pixel the edge is most likely midway. The labels follow the box (a few rounds: label,
fit with ``scipy.optimize.least_squares`` and a soft-L1 loss, label again), starting from the points'
measurement (plate.py) grown by its horizontal smear. Ray-box intersections are numpy slab tests: all
pixels of all views in one vectorised pass: 7 ms for 2·10^4 rays on this (loaded) machine, against
550 ms with trimesh's ray casting (without Embree: its numpy triangle intersector, and the box's mesh
rebuilt for every trial box), measured 2026-11-25.

The key frames' poses: views from different passes of the route disagree by centimetres even after
the global batch; with the key frames' pose covariance in the store, each pass gets one rigid correction
fitted with the box under the covariance's prior (:mod:`.plate_poses`, relaxed in ``STAGES``), and a
pass that needs a correction the covariance makes improbable makes the plate "not measured".

What the fit will not return: the box's centre stays within the horizontal extent of the points it was
started from and its sides within that extent's diagonal (it cannot follow a surface beyond the data),
and a box whose outline runs off the handed-over pixels in all but one key frame is reported as failed
(``ok`` False with the reason): its extent there is the crop's, not the plate's (a region fused with the
ground or a stand, a start on the wrong surface).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.optimize import least_squares
from weldcell.plugins.mapping.plate_poses import PassPrior, corrected_pose, corrections, group_passes

STAGES = (0.1, 0.3, 1.0)
"""The passes' prior sigmas relaxed in stages (fractions of the covariance's): the labels follow the box
and the poses, so the fit settles on the nearest consistent labelling; started at once with the full
freedom and passes centimetres apart it can settle on one that fits neither (a 0.6 x 0.4 m plate measured
0.67 m wide, tests/mapping/test_plate_poses.py)."""
K_SIGMA = 3.0
"""Labels: a measured depth within K_SIGMA σ of the box is the plate's, beyond it the background's."""
PIXEL_SD = 1.0 / np.sqrt(12.0)
"""Standard deviation of an edge's position inside the pixel it falls in (uniform over 1 px)."""
MIN_COS = 0.1
"""Incidence cosine below which the depth noise stops growing (the camera model's ``min_cos``)."""


@dataclass
class PlateView:
    """One key frame's depth around a region: the crop ``depth`` (z, m; 0 = none) whose pixel (0, 0) is
    the image's (u0, v0), the pinhole intrinsics, the key frame's pose and its depth noise (σ_z / z²)."""

    depth: np.ndarray
    u0: int
    v0: int
    fx: float
    fy: float
    cx: float
    cy: float
    T_world_cam: np.ndarray
    depth_noise: float
    keyframe: int = -1
    """The key frame's index in the store (-1: unknown); consecutive ones form a pass (plate_poses.py)."""
    pose_cov: np.ndarray | None = None
    """6x6 covariance of the key frame's pose error as a world-frame correction [ω, δx at the camera
    centre] (:func:`~.plate_poses.camera_pose_cov`); None when the store has none."""


def crop_view(
    depth, K, T_world_cam, box_min, box_max, depth_noise: float, keyframe: int = -1, pose_cov=None
) -> PlateView | None:
    """The part of a depth image where the world box [box_min, box_max] projects, one pixel beyond; None
    when the box is not in front of the camera or outside the image."""
    lo, hi = np.asarray(box_min, float), np.asarray(box_max, float)
    C = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    T = np.asarray(T_world_cam, float)
    Pc = (C - T[:3, 3]) @ T[:3, :3]
    if np.any(Pc[:, 2] <= 0.05):
        return None
    u = K.fx * Pc[:, 0] / Pc[:, 2] + K.cx
    v = K.fy * Pc[:, 1] / Pc[:, 2] + K.cy
    H, W = np.asarray(depth).shape
    u0, u1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 2, W)
    v0, v1 = max(int(np.floor(v.min())) - 1, 0), min(int(np.ceil(v.max())) + 2, H)
    if u1 <= u0 or v1 <= v0:
        return None
    crop = np.nan_to_num(np.asarray(depth, np.float32)[v0:v1, u0:u1].copy(), nan=0.0, posinf=0.0)
    return PlateView(crop, u0, v0, K.fx, K.fy, K.cx, K.cy, T.copy(), float(depth_noise), keyframe, pose_cov)


@dataclass
class BoxFit:
    """A plate's fitted box: ``params`` (x, y, yaw, length, width, top z, thickness), their covariance
    (Gauss-Newton from the last fit's Jacobian: optimistic, the outline residuals are hinges that say
    nothing while satisfied), its top corners (4, 3), the views and plate pixels used, and ``ok`` with
    the ``reason`` when the box is not determined (then the corners are not a measurement)."""

    params: np.ndarray
    cov: np.ndarray
    corners: np.ndarray
    views: int
    pixels: int
    ok: bool
    reason: str = ""
    labels: dict = field(default_factory=dict)
    passes: list[dict] = field(default_factory=list)
    """Per pass of the route that saw the plate (with the key frames' covariance, plate_poses.py): its key
    frames, the fitted rigid correction [ω (rad), t (m)] and its squared Mahalanobis distance under the
    prior (χ² with 6 degrees of freedom when the pass agrees with the others as the covariance says)."""
    views_fitted: list[PlateView] = field(default_factory=list)
    """The views at their corrected poses (the fit's own)."""


def box_corners(p: np.ndarray) -> np.ndarray:
    """(4, 3) top corners of the box ``p`` (counter-clockwise from above, starting at (-L/2, -W/2))."""
    x, y, a, L, W, zt = p[:6]
    c, s = np.cos(a), np.sin(a)
    loc = np.array([[-L, -W], [L, -W], [L, W], [-L, W]]) / 2
    xy = loc @ np.array([[c, s], [-s, c]]) + [x, y]
    return np.column_stack([xy, np.full(4, zt)])


class _Pixels:
    """Every pixel of every view, flattened: view index, pixel (u, v), measured z, ray origin and the
    world direction whose camera z is 1 (so a ray parameter is a z-depth)."""

    def __init__(self, views: list[PlateView]) -> None:
        vi, uu, vv, zz, D = [], [], [], [], []
        for k, w in enumerate(views):
            h, wd = w.depth.shape
            v, u = np.mgrid[0:h, 0:wd]
            u, v = (u + w.u0).ravel().astype(float), (v + w.v0).ravel().astype(float)
            dc = np.column_stack([(u - w.cx) / w.fx, (v - w.cy) / w.fy, np.ones(len(u))])
            vi.append(np.full(len(u), k))
            uu.append(u)
            vv.append(v)
            zz.append(w.depth.ravel().astype(float))
            D.append(dc @ w.T_world_cam[:3, :3].T)
        self.views = views
        self.view = np.concatenate(vi)
        self.u, self.v, self.z = np.concatenate(uu), np.concatenate(vv), np.concatenate(zz)
        self.D = np.concatenate(D)
        self.O = np.array([w.T_world_cam[:3, 3] for w in views])[self.view]
        self.noise = np.array([w.depth_noise for w in views])[self.view]
        self.f = np.array([w.fx for w in views])[self.view]


def _slab(p: np.ndarray, O: np.ndarray, D: np.ndarray, grow: np.ndarray | float = 0.0):
    """Ray-box slab test: entry and exit ray parameters (z-depths), whether the ray hits, and the cosine
    of the incidence angle on the entry face."""
    x, y, a, L, W, zt, th = p
    c, s = np.cos(a), np.sin(a)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    h = np.array([L / 2, W / 2, th / 2]) + grow
    o = (O - [x, y, zt - th / 2]) @ R
    d = D @ R
    d = np.where(np.abs(d) < 1e-12, 1e-12, d)
    t1, t2 = (-h - o) / d, (h - o) / d
    tn, tf = np.minimum(t1, t2), np.maximum(t1, t2)
    ax = np.argmax(tn, axis=1)
    te = np.take_along_axis(tn, ax[:, None], 1)[:, 0]
    tx = tf.min(axis=1)
    cos = np.abs(np.take_along_axis(d, ax[:, None], 1)[:, 0]) / np.linalg.norm(d, axis=1)
    return te, tx, te <= tx, cos


def _outline_distance(
    p: np.ndarray, views: list[PlateView], vi: np.ndarray, u: np.ndarray, v: np.ndarray, poses=None
):
    """Signed distance (pixels) of each pixel centre (u, v) of view ``vi`` to the box's projected outline
    (< 0 inside; outside, the largest distance to an edge's line); ``poses``: the views' T_world_cam when
    not their own."""
    x, y, a, L, W, zt, th = p
    c, s = np.cos(a), np.sin(a)
    loc = np.array([[i * L / 2, j * W / 2] for i in (-1, 1) for j in (-1, 1)])
    xy = loc @ np.array([[c, s], [-s, c]]) + [x, y]
    C = np.vstack([np.column_stack([xy, np.full(4, zt)]), np.column_stack([xy, np.full(4, zt - th)])])
    N = np.zeros((len(views), 6, 2))  # each view's outline: up to 6 edges (outward normal n, offset n.v)
    off = np.full((len(views), 6), -np.inf)
    for k, w in enumerate(views):
        T = w.T_world_cam if poses is None else poses[k]
        Pc = (C - T[:3, 3]) @ T[:3, :3]
        uv = np.column_stack([w.fx * Pc[:, 0] / Pc[:, 2] + w.cx, w.fy * Pc[:, 1] / Pc[:, 2] + w.cy])
        hull = uv[cv2.convexHull(uv.astype(np.float32), returnPoints=False)[:, 0]]  # float64 for the Jacobian
        e = np.roll(hull, -1, axis=0) - hull
        n = np.column_stack([e[:, 1], -e[:, 0]]) / (np.linalg.norm(e, axis=1, keepdims=True) + 1e-12)
        n *= np.where(np.sum(n * (hull.mean(0) - hull), axis=1) > 0, -1.0, 1.0)[:, None]
        m = min(len(hull), 6)
        N[k, :m], off[k, :m] = n[:m], np.sum(n * hull, axis=1)[:m]
    return np.max(N[vi, :, 0] * u[:, None] + N[vi, :, 1] * v[:, None] - off[vi], axis=1)


def _labels(p: np.ndarray, px: _Pixels, O: np.ndarray, D: np.ndarray, grow_h: float):
    """Plate and background pixels of the box ``p`` grown by ``grow_h`` horizontally and one pixel
    footprint vertically, and each pixel's depth noise σ (z) from the rendered face; the pixels' rays
    start at ``O`` along ``D`` (the views' corrected poses)."""
    has = px.z > 0
    te0, tx0, hit0, cos0 = _slab(p, O, D)
    fp = np.where(has, px.z, np.maximum(te0, 0.1)) / px.f
    grow = np.column_stack([np.full(len(fp), grow_h), np.full(len(fp), grow_h), fp])
    te1, tx1, hit1, cos1 = _slab(p, O, D, grow)
    zr = np.where(hit0, te0, np.where(hit1, te1, np.minimum(te1, tx1)))
    cs = np.where(hit0, cos0, cos1)
    sig = px.noise * zr**2 / np.maximum(cs, MIN_COS)
    plate = has & hit1 & (px.z >= te1 - K_SIGMA * sig) & (px.z <= tx1 + K_SIGMA * sig)
    beyond = np.where(hit1, tx1, np.minimum(te1, tx1))
    # background only near the outline (three pixel footprints beyond the grown box): farther away its
    # residual is zero at any box the fit can reach
    near = _slab(p, O, D, grow + 3 * fp[:, None])[2]
    bg = has & near & ~plate & (px.z > beyond + K_SIGMA * sig)
    return plate, bg, sig


def params_from_corners(corners: np.ndarray, thickness: float) -> np.ndarray:
    """Box parameters from 4 top corners (counter-clockwise) and a thickness."""
    c = corners.mean(0)
    ex, ey = corners[1] - corners[0], corners[3] - corners[0]
    yaw = np.arctan2(ex[1], ex[0])
    return np.array(
        [c[0], c[1], yaw, np.linalg.norm(ex[:2]), np.linalg.norm(ey[:2]), corners[:, 2].mean(), thickness]
    )


def _soft(r: np.ndarray) -> np.ndarray:
    """Residuals whose squares are the soft-L1 cost 2(√(1 + r²) − 1): the pixels' robust loss applied
    here, so that the pose priors stay Gaussian (least_squares' loss would apply to all residuals)."""
    return np.sign(r) * np.sqrt(2.0 * (np.sqrt(1.0 + r * r) - 1.0))


class _Model:
    """The views' poses under their passes' rigid corrections ξ (plate_poses.py; no passes: the views stay
    at their poses): the pixels' rays, the views' poses and the prior residuals for a parameter vector
    [box (7), ξ per pass (6 each)]."""

    def __init__(self, px: _Pixels, passes: list[PassPrior] | None) -> None:
        self.px, self.passes = px, passes or []
        self.n = 6 * len(self.passes)
        of_view = np.zeros(len(px.views), int)
        for k, ps in enumerate(self.passes):
            of_view[ps.views] = k
        self.of_view, self.of_pixel = of_view, of_view[px.view]
        self.W = [ps.whiten() for ps in self.passes]
        self.prior_scale = 1.0

    def rays(self, xi: np.ndarray, idx: np.ndarray | None = None):
        O, D = (self.px.O, self.px.D) if idx is None else (self.px.O[idx], self.px.D[idx])
        if not self.passes:
            return O, D
        C = corrections(xi, self.passes)
        R, off = np.array([c[0] for c in C]), np.array([c[1] for c in C])
        k = self.of_pixel if idx is None else self.of_pixel[idx]
        return np.einsum("nij,nj->ni", R[k], O) + off[k], np.einsum("nij,nj->ni", R[k], D)

    def poses(self, xi: np.ndarray) -> list[np.ndarray]:
        if not self.passes:
            return [w.T_world_cam for w in self.px.views]
        C = corrections(xi, self.passes)
        return [corrected_pose(w.T_world_cam, *C[self.of_view[k]]) for k, w in enumerate(self.px.views)]

    def prior(self, xi: np.ndarray) -> np.ndarray:
        r = [W @ xi[6 * k : 6 * k + 6] / self.prior_scale for k, W in enumerate(self.W)]
        return np.concatenate(r + [np.zeros(0)])

    def sparsity(self, ip: np.ndarray, ib: np.ndarray):
        """Which residuals each parameter moves: the box all pixels', a pass's ξ its own pixels' and its
        prior's (so finite differences perturb every pass's ξ at once: 7 + 6 evaluations, not 7 + 6P)."""
        if not self.passes:
            return None
        from scipy.sparse import coo_matrix

        k = self.of_pixel[np.r_[ip, ip, ib]]
        m = len(k)
        rows = [np.repeat(np.arange(m), 7), np.repeat(np.arange(m), 6)]
        cols = [np.tile(np.arange(7), m), 7 + 6 * np.repeat(k, 6) + np.tile(np.arange(6), m)]
        for j in range(len(self.passes)):
            r, c = np.meshgrid(m + 6 * j + np.arange(6), 7 + 6 * j + np.arange(6), indexing="ij")
            rows.append(r.ravel())
            cols.append(c.ravel())
        r, c = np.concatenate(rows), np.concatenate(cols)
        return coo_matrix((np.ones(len(r)), (r, c)), shape=(m + self.n, 7 + self.n)).tocsr()


def _residuals(q: np.ndarray, model: _Model, ip: np.ndarray, ib: np.ndarray, sig: np.ndarray) -> np.ndarray:
    """Silhouette residuals of the plate pixels ``ip``, depth residuals of the same pixels, silhouette
    residuals of the background pixels ``ib`` (σ units, soft-L1), then the passes' prior residuals."""
    px, p, xi = model.px, q[:7], q[7:]
    isel = np.r_[ip, ib]
    sd = _outline_distance(p, px.views, px.view[isel], px.u[isel], px.v[isel], model.poses(xi))
    O, D = model.rays(xi, ip)
    te, tx, _, _ = _slab(p, O, D)
    n_p = len(ip)
    r = np.concatenate(
        [
            np.maximum(0.0, sd[:n_p] + 0.5) / PIXEL_SD,
            (px.z[ip] - np.minimum(te, tx)) / sig[ip],
            np.maximum(0.0, 0.5 - sd[n_p:]) / PIXEL_SD,
        ]
    )
    return np.concatenate([_soft(r), model.prior(xi)])


def _seen_across(p: np.ndarray, views: list[PlateView]) -> tuple[bool, bool]:
    """Whether each plate axis (length, width) is seen across the line of sight in at least one view.
    Moving an edge by δ along an axis at angle φ to the horizontal line of sight moves it in the image by
    δ·|sin φ|·f/z across and by δ·|cos φ|·sin(elevation)·f/z down the rows (the top face is foreshortened
    by the elevation above it): the axis counts as seen across where the first is the larger. A plate
    whose axis every view looks along has that extent only from the grazing far-edge rows."""
    a = p[2]
    axes = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
    rel = np.array([w.T_world_cam[:3, 3] - np.r_[p[:2], p[5]] for w in views])
    dist = np.linalg.norm(rel[:, :2], axis=1) + 1e-12
    sin_el = np.abs(rel[:, 2]) / np.hypot(dist, rel[:, 2])
    los = rel[:, :2] / dist[:, None]
    cos_phi = np.abs(los @ axes.T)
    across = np.sqrt(np.maximum(1 - cos_phi**2, 0)) > cos_phi * sin_el[:, None]
    return bool(across[:, 0].any()), bool(across[:, 1].any())


def _along_reason(p: np.ndarray, across: tuple[bool, bool]) -> str:
    yaw = np.degrees(p[2] + (0.0 if not across[0] else np.pi / 2)) % 180
    return f"the plate's extent along {yaw:.0f}° (world) is seen only along the line of sight (grazing rows)"


def _views_containing(p: np.ndarray, views: list[PlateView]) -> int:
    """Views whose crop holds the box's whole projected outline, a pixel clear of its border: in the
    others part of the outline falls where no pixel was handed over, and the edge there is the crop's."""
    C = np.vstack([box_corners(p), box_corners(p) - [0.0, 0.0, p[6]]])
    n = 0
    for w in views:
        Pc = (C - w.T_world_cam[:3, 3]) @ w.T_world_cam[:3, :3]
        if np.any(Pc[:, 2] <= 0):
            continue
        u = w.fx * Pc[:, 0] / Pc[:, 2] + w.cx - w.u0
        v = w.fy * Pc[:, 1] / Pc[:, 2] + w.cy - w.v0
        h, wd = w.depth.shape
        n += bool(u.min() >= 1 and v.min() >= 1 and u.max() <= wd - 2 and v.max() <= h - 2)
    return n


def top_face_rows(p: np.ndarray, views: list[PlateView]) -> np.ndarray:
    """Per view, how many pixel rows the box's top face spans (its corners' row range): the near and the
    far edge are told apart (an interior row of the top face between them) only above two rows."""
    out = []
    for w in views:
        Pc = (box_corners(p) - w.T_world_cam[:3, 3]) @ w.T_world_cam[:3, :3]
        v = w.fy * Pc[:, 1] / np.maximum(Pc[:, 2], 1e-6) + w.cy
        out.append(v.max() - v.min() if np.all(Pc[:, 2] > 0) else 0.0)
    return np.array(out)


def _trust(p: np.ndarray, views: list[PlateView]) -> str:
    """Why the fitted box cannot be trusted ('' when it can): its outline leaves the crop in all but one
    view, so the fit followed a surface beyond the region (the ground, a stand, a neighbour) and its
    extent there is the crop's; or the top face spans more than two pixel rows (:func:`top_face_rows`)
    in fewer than two views: its extent along the line of sight then rests on one view's grazing rows
    (as with one key frame), and the fit can trade the plate for a smaller, thicker box (a plate 3.4-3.9
    m away seen 3° above its top: 0.24 x 0.32 x 0.20 m for 0.6 x 0.4 x 0.02 m). (A chi² test of the
    plate pixels' depth residuals against the camera model was tried: on a plate measured within 5 mm
    their mean square is 1.49 against 1.04 at the upper 10^-3 quantile: the key frames' pose errors are
    not in the model, so the test cannot tell.)"""
    rows = top_face_rows(p, views)
    if np.sum(rows > 2.0) < 2:
        return (
            f"the fitted top face spans more than two pixel rows in {np.sum(rows > 2.0)} of {len(views)} key "
            "frames (at least two needed, as for the views themselves): its near and far edges are not told "
            "apart (views too far or too low)"
        )
    return _crop_reason(p, views)


def _crop_reason(p: np.ndarray, views: list[PlateView]) -> str:
    """Why the box ``p`` is beyond the region's pixels ('' when at least two views hold its outline)."""
    inside = _views_containing(p, views)
    if inside < 2:
        return (
            f"the box reaches the edge of the region's pixels in {len(views) - inside} of "
            f"{len(views)} key frames: its extent is the crop's, not the plate's"
        )
    return ""


def _rounds(q: np.ndarray, model: _Model, grow_h: float, fp: float, box, rounds: int):
    """Label, fit, label again until the labels stop changing (at most ``rounds``): the labels from the
    box grown by ``grow_h`` horizontally first, then by two pixel footprints ``fp``. ``box``: the
    parameters' scales and bounds. None when too few pixels are the plate's."""
    scale, lo, hi = box
    prev, sol, plate, bg = None, None, None, None
    for _ in range(rounds):
        plate, bg, sig = _labels(q[:7], model.px, *model.rays(q[7:]), grow_h)
        grow_h = 2 * fp
        key = (plate.tobytes(), bg.tobytes())
        if key == prev:
            break
        prev = key
        if plate.sum() < 3 * 7:
            return None
        ip, ib = np.flatnonzero(plate), np.flatnonzero(bg)
        sol = least_squares(
            lambda x, ip=ip, ib=ib, sig=sig: _residuals(x, model, ip, ib, sig),
            q,
            x_scale=scale,
            bounds=(lo, hi),
            jac_sparsity=model.sparsity(ip, ib),
        )
        q = sol.x
    return q, sol, plate, bg


def fit_box(
    views: list[PlateView],
    p0: np.ndarray,
    grow_h: float,
    rounds: int = 8,
    region: tuple[np.ndarray, np.ndarray] | None = None,
    pose_correction: bool = True,
) -> BoxFit:
    """Fit the box to the views from ``p0``: labels from the box grown by ``grow_h`` horizontally first,
    then by two pixel footprints, until they stop changing (at most ``rounds``). With
    ``pose_correction`` and views that carry their key frame's pose covariance, each pass of the route
    gets a rigid correction fitted with the box under the covariance's prior (:mod:`.plate_poses`).
    ``ok`` is False, with the reason, when fewer than two key frames have depth there, when too few
    pixels are the plate's, or when an axis of the plate is seen only along the line of sight (see the
    module docstring), or when the result cannot be trusted (:func:`_trust`). ``region``: the horizontal
    extent (xy min, max) of the points the start was measured on; the box's centre stays within it and
    its sides within its diagonal (the fit cannot follow a surface beyond the data it was started from)."""
    views = [w for w in views if w is not None and np.any(w.depth > 0)]
    p = np.asarray(p0, float).copy()
    nan = np.full((7, 7), np.nan)
    if len(views) < 2:
        why = "no key frame with depth" if not views else "one key frame: its far edges are grazing rows"
        return BoxFit(p, nan, box_corners(p), len(views), 0, False, why)
    if not all(_seen_across(p, views)):  # already at the start (the rule is coarse: 45°): not worth fitting
        return BoxFit(p, nan, box_corners(p), len(views), 0, False, _along_reason(p, _seen_across(p, views)))
    if _crop_reason(p, views):  # a start beyond the region's pixels (the wrong surface): not fitted
        return BoxFit(p, nan, box_corners(p), len(views), 0, False, "the start: " + _crop_reason(p, views))
    px = _Pixels(views)
    passes = group_passes(views) if pose_correction else None
    model = _Model(px, passes if passes and len(passes) > 1 else None)
    c0 = np.r_[p[:2], p[5]]
    fp = float(np.median([np.linalg.norm(w.T_world_cam[:3, 3] - c0) / w.fx for w in views]))
    scale = np.r_[
        [fp, fp, fp / max(p[3], fp), fp, fp, fp, fp], *[np.sqrt(np.diag(ps.cov)) for ps in model.passes]
    ]
    lo = np.r_[[-np.inf, -np.inf, -np.inf, 2 * fp, 2 * fp, -np.inf, 1e-3], np.full(model.n, -np.inf)]
    hi = np.full(7 + model.n, np.inf)
    if region is not None:
        rlo, rhi = (np.asarray(b, float)[:2] for b in region)
        lo[:2], hi[:2] = rlo, rhi
        hi[3:5] = max(np.linalg.norm(rhi - rlo), 4 * fp)
        p[:2] = np.clip(p[:2], rlo + 1e-9, rhi - 1e-9)
    p[3:5] = np.minimum(np.maximum(p[3:5], 2 * fp), hi[3:5] - 1e-9)
    p[6] = max(p[6], 1.5e-3)
    q = np.r_[p, np.zeros(model.n)]
    fitted_rounds = _rounds(q[:7], _Model(px, None), grow_h, fp, (scale[:7], lo[:7], hi[:7]), rounds)
    for k in STAGES if model.n else ():  # the passes: the prior relaxed in stages (see STAGES)
        if fitted_rounds is None:
            break
        model.prior_scale = k
        q = fitted_rounds[0] if len(fitted_rounds[0]) > 7 else np.r_[fitted_rounds[0], np.zeros(model.n)]
        fitted_rounds = _rounds(q, model, 2 * fp, fp, (scale, lo, hi), rounds)
    if fitted_rounds is None:
        return BoxFit(q[:7], nan, box_corners(q[:7]), len(views), 0, False, "too few plate pixels")
    q, sol, plate, bg = fitted_rounds
    p, xi = q[:7], q[7:]
    J = sol.jac.toarray() if hasattr(sol.jac, "toarray") else sol.jac
    try:
        cov = np.linalg.inv(J.T @ J)[:7, :7]
    except np.linalg.LinAlgError:
        cov = nan
    fitted = [replace(w, T_world_cam=T) for w, T in zip(views, model.poses(xi), strict=True)]
    labels = {"plate": int(plate.sum()), "background": int(bg.sum())}
    across = _seen_across(p, fitted)
    why = "" if all(across) else _along_reason(p, across)
    why = why or _trust(p, fitted)
    info = [
        {
            "keyframes": ps.keyframes,
            "xi": xi[6 * k : 6 * k + 6].tolist(),
            "d2": float(np.sum((model.W[k] @ xi[6 * k : 6 * k + 6]) ** 2)),
        }
        for k, ps in enumerate(model.passes)
    ]
    why = why or _pass_reason(info)
    return BoxFit(p, cov, box_corners(p), len(views), labels["plate"], not why, why, labels, info, fitted)


PASS_P = 1e-3
"""A pass's correction beyond the χ²(6) quantile 1 - PASS_P of its prior: the views disagree more than
the key frames' pose covariance allows."""


def _pass_reason(info: list[dict]) -> str:
    """Why the passes' corrections cannot be trusted ('' when they can): a pass needing a correction the
    estimator's covariance makes improbable (squared Mahalanobis distance above the χ²(6) 1 - PASS_P
    quantile) is not a pose error the covariance knows of (a region fused with a neighbour, a fit on the
    wrong surface): the plate is reported, not measured."""
    from scipy.stats import chi2

    lim = chi2.ppf(1 - PASS_P, 6)
    bad = [ps for ps in info if ps["d2"] > lim]
    if not bad:
        return ""
    kf = bad[0]["keyframes"]
    return (
        f"the views of key frames {kf[0]}-{kf[-1]} need a pose correction beyond the key frames' covariance "
        f"(squared Mahalanobis distance {bad[0]['d2']:.1f} > {lim:.1f}, χ²(6) at {PASS_P:g}): the passes "
        "disagree more than the estimator's poses explain"
    )
