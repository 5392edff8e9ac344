"""Multi-view reconstruction of the scan-and-plan method (paper 000, section II-C, eq. 1 + eqs. 2-8).

Every captured view is put into the robot base frame with the robot's flange pose and the hand-eye
transform, ``bFp = bMe . eMc . cFp`` (eq. 1), then refined by linear point-to-plane ICP against the
model merged so far (not only the previous view), and added to the model.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import invert, is_rigid, rotation_angle
from weldcell.sdk.scan import PosedScan  # noqa: F401  (re-exported: the scan type of this stage)

from .cloud_numerics import as_points, pca_normals, voxel_downsample
from .hand_eye_fit import MIN_OVERLAP, HandEyeFit, fit_hand_eye
from .nearest import PointTree
from .registration import IcpOptions, IcpResult, linear_icp, point_to_plane_information

Progress = Callable[[int, int, str], None]
ANCHORS = ("mean", "first", "hand-eye")


@dataclass
class ReconstructResult:
    """Outcome of :func:`reconstruct`.

    ``cloud`` is the merged model in the base frame (``viewpoints``: each view's camera position). Per
    view ``i``: ``T_base_camera[i]`` the refined camera pose, ``corrections[i]`` the ICP correction
    ``T_base_base'`` applied on top of eq. 1 (identity
    for the first view and for rejected corrections), ``fitness_before[i]`` / ``fitness[i]`` eq. 20
    against the model before / after refinement, ``accepted[i]`` whether the ICP correction was kept,
    ``icp[i]`` the full :class:`IcpResult` (None for the first view or when ICP was off).
    ``anchor_shift`` is the transform applied to the registered model by ``anchor="mean"`` (identity
    for ``anchor="first"``); it is included in ``corrections`` and ``T_base_camera``. With
    ``anchor="hand-eye"`` ``hand_eye`` holds the fitted hand-eye correction (also when it was not
    identifiable and the mean anchor was used instead: ``hand_eye.applied`` False, ``hand_eye.note``);
    when applied, the views are re-placed one by one with the one correction (``corrections[i] =
    B_i D B_i^-1``, ``B_i`` the eq.-1 pose) and ``anchor_shift`` stays the identity.
    """

    cloud: PointCloud
    T_base_camera: list[np.ndarray]
    corrections: list[np.ndarray]
    fitness_before: list[float]
    fitness: list[float]
    accepted: list[bool]
    icp: list[IcpResult | None] = field(default_factory=list)
    anchor_shift: np.ndarray = field(default_factory=lambda: np.eye(4))
    hand_eye: HandEyeFit | None = None


@dataclass(frozen=True)
class ReconstructOptions:
    """How :func:`reconstruct` merges and registers the views (checked when made; the stage builds it
    from :class:`~weldcell.plugins.scan_plan.stages.ReconstructSettings`).

    ``voxel`` (m, None keeps every point): the registration and output grid. ``register_to_model``: ICP
    each view against the model merged so far (False: eq. 1 only). ICP (see
    :class:`~.registration.IcpOptions`): ``max_correspondence_distance`` (default 3 x ``voxel``, or
    1 cm without a voxel), ``max_iterations``, ``tolerance``, ``robust``, ``update``, ``normal_k``, and
    ``prior = (sigma_t, sigma_r)`` (m, rad), the expected error of a view's kinematic pose.
    ``fitness_distance`` (default a third of the correspondence distance): the pair distance of eq. 20.
    ``max_correction`` (m, rad): larger ICP corrections are rejected. ``anchor``: "mean", "first" or
    "hand-eye" (see :func:`reconstruct`), ``hand_eye_passes`` its leave-one-out refinement passes.
    """

    voxel: float | None
    register_to_model: bool = True
    max_correspondence_distance: float | None = None
    max_iterations: int = 50
    tolerance: float = 1e-6
    robust: str | None = "huber"
    update: str = "exact"
    max_correction: tuple[float, float] = (0.05, np.deg2rad(10.0))
    normal_k: int = 20
    fitness_distance: float | None = None
    anchor: str = "mean"
    prior: tuple[float, float] | None = None
    hand_eye_passes: int = 2

    def __post_init__(self) -> None:
        if self.anchor not in ANCHORS:
            raise DataError(f"unknown anchor '{self.anchor}'", "use anchor='mean', 'first' or 'hand-eye'")
        if self.hand_eye_passes < 0:
            raise DataError(
                f"hand_eye_passes must be >= 0, got {self.hand_eye_passes}", "use e.g. 2 (0: one fit only)"
            )
        v = self.voxel
        if v is not None and (not np.isfinite(v) or v <= 0):
            raise DataError(
                f"voxel must be > 0 m or None, got {v}", "use e.g. 2 mm (0.002) for an RGB-D scan"
            )

    @property
    def correspondence_distance(self) -> float:
        """The ICP correspondence distance (m): as given, else 3 x ``voxel`` (1 cm without a voxel)."""
        return self.max_correspondence_distance or (3.0 * self.voxel if self.voxel else 0.01)

    def icp(self) -> IcpOptions:
        """The per-view registration's options (without the pose prior; the growing-model pass adds it)."""
        return IcpOptions(
            max_correspondence_distance=self.correspondence_distance,
            max_iterations=self.max_iterations,
            tolerance=self.tolerance,
            robust=self.robust,
            update=self.update,
            normal_k=self.normal_k,
        )


def _check_pose(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not is_rigid(T, tol=1e-5):
        raise DataError(
            f"{what} is not a rigid 4x4 transform (metres)",
            "pass the flange pose from the robot state and the hand-eye result as 4x4 matrices",
        )
    return T


def _fitness(
    dist: np.ndarray | None, src: np.ndarray, T: np.ndarray, tree: PointTree, d_fit: float, d_max: float
) -> float:
    """Eq. 20 of ``src`` mapped by ``T`` against the model of ``tree``, from the ICP's own nearest-model
    distances when they reach far enough (``d_fit <= d_max``), else by a search."""
    if dist is None or d_fit > d_max:
        S = src @ T[:3, :3].T + T[:3, 3]
        dist, _ = tree.query(S, k=1, distance_upper_bound=d_fit, workers=-1)
    return int(np.count_nonzero(dist < d_fit)) / tree.n


def view_to_base(scan: PosedScan, T_flange_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 1: the view's camera points in the base frame, and ``T_base_camera = bMe . eMc``."""
    if not isinstance(scan, PosedScan):
        raise DataError(f"expected a PosedScan, got {type(scan).__name__}", "wrap each view in PosedScan")
    if scan.cloud.frame != "camera":
        raise DataError(
            f"a view's cloud must be in the 'camera' frame, got '{scan.cloud.frame}'",
            "pass the camera's raw cloud; the robot pose and hand-eye put it into the base frame",
        )
    T_bc = _check_pose(scan.T_base_flange, "T_base_flange") @ _check_pose(T_flange_camera, "T_flange_camera")
    P = as_points(scan.cloud.points, "view cloud")
    return P @ T_bc[:3, :3].T + T_bc[:3, 3], T_bc


def merge_views(views: Sequence[PosedScan], T_flange_camera: np.ndarray) -> PointCloud:
    """Union of all views mapped into the base frame with eq. 1 (no refinement); its viewpoints are the
    views' camera positions."""
    if len(views) == 0:
        raise DataError("no views to merge", "capture at least one view")
    placed = [view_to_base(v, T_flange_camera) for v in views]
    parts = [P for P, _ in placed]
    normals = None
    if all(v.cloud.normals is not None for v in views):
        T_fc = np.asarray(T_flange_camera, dtype=float)
        normals = np.concatenate(
            [v.cloud.normals @ (np.asarray(v.T_base_flange)[:3, :3] @ T_fc[:3, :3]).T for v in views]
        )
    return PointCloud(
        np.concatenate(parts),
        normals=normals,
        frame="base",
        meta={"n_views": len(views)},
        viewpoints=[T[:3, 3] for _, T in placed],
    )


def reconstruct(
    scans: Sequence[PosedScan],
    T_flange_camera: np.ndarray,
    options: ReconstructOptions,
    progress: Progress | None = None,
) -> ReconstructResult:
    """Merge posed views into one model in the base frame (eq. 1) refined by ICP (eqs. 2-8). The settings
    named below are fields of ``options`` (:class:`ReconstructOptions`).

    The first view seeds the model. Each further view starts from its kinematic pose (flange pose x
    hand-eye) and is registered by :func:`linear_icp` to the model merged so far (``register_to_model``;
    with False, views are only merged by eq. 1). Both the view and the model are voxel-down-sampled at
    ``voxel`` metres for registration; the returned cloud is the union of all points with the refined
    poses, down-sampled at ``voxel`` (None keeps every point); its ``viewpoints`` are the views' camera
    positions (the registered ``T_base_camera``).
    ``max_correspondence_distance`` defaults to 3 x ``voxel`` (or 1 cm without a voxel). The reported
    fitness (eq. 20, view points aligned to the model / model points) counts pairs closer than
    ``fitness_distance`` (default: a third of the correspondence distance, i.e. the voxel size).
    A correction larger than ``max_correction`` (m, rad), or one that lowers the fitness by more than
    0.02, is rejected (kinematic pose kept) with a warning: the kinematics are trusted over a wrong
    local minimum.
    ``anchor`` = "mean" places the registered model where the views' kinematic poses put it on
    average (the mean of the accepted corrections is removed: mean translation, chordal mean rotation);
    "first" keeps the first view's kinematic pose (the paper). "hand-eye" explains the registered
    poses by one hand-eye correction ``D`` common to all views (:func:`~.hand_eye_fit.fit_hand_eye`:
    ``C_i B_i = G B_i D``) and re-places every view at ``B_i D`` (``B_i`` its eq.-1 pose): the model
    lands in the base frame without averaging and rigidly consistent; views whose ICP was refused or
    matched less than 20 % of their points are left out of the fit (and re-placed by it). When the
    views' rotations are too alike to identify ``D`` (or fewer than 3 views remain) it warns and falls
    back to "mean"; ``ReconstructResult.hand_eye`` has the correction and the note. The first fit
    uses the registrations against the growing model, which carry the early views' errors; each of
    ``hand_eye_passes`` then re-places the views with the correction found so far, registers every view
    to the union of all the others (leave-one-out) and fits again (each pass costs about one more
    registration per view).
    ``prior = (sigma_t, sigma_r)`` (m, rad), the expected error of a view's kinematic pose, makes each
    registration a MAP estimate (see :func:`linear_icp`): poorly constrained directions stay put.
    ``progress(i, n, message)`` is called once per view.
    """
    n = len(scans)
    if n == 0:
        raise DataError("no scans to reconstruct", "capture at least one view")
    o = options
    v = _register_views(scans, T_flange_camera, o, progress)
    fit = None
    if o.anchor == "hand-eye" and o.register_to_model:
        fit = _place_by_hand_eye(v, o, progress)
    shift = np.eye(4)
    if (o.anchor == "mean" or (fit is not None and not fit.applied)) and o.register_to_model:
        shift = _place_by_mean(v)
    merged = _down(np.concatenate(v.full), o.voxel)
    cloud = PointCloud(
        merged,
        frame="base",
        meta={"n_views": n, "voxel": o.voxel, "anchor": o.anchor},
        viewpoints=[T[:3, 3] for T in v.T_bc],
    )
    return ReconstructResult(
        cloud, v.T_bc, v.corrections, v.fit_before, v.fit_after, v.accepted, v.icps, shift, fit
    )


@dataclass
class _Views:
    """The views as :func:`reconstruct` registers and places them: per view its points in the base
    frame (``full``), eq.-1 pose ``T_kin``, registered pose ``T_bc``, correction, fitness before/after,
    acceptance and ICP result; for the hand-eye anchor the registration information and the
    registration points in the camera frame (``srcs``)."""

    full: list[np.ndarray] = field(default_factory=list)
    T_kin: list[np.ndarray] = field(default_factory=list)
    T_bc: list[np.ndarray] = field(default_factory=list)
    corrections: list[np.ndarray] = field(default_factory=list)
    fit_before: list[float] = field(default_factory=list)
    fit_after: list[float] = field(default_factory=list)
    accepted: list[bool] = field(default_factory=list)
    icps: list[IcpResult | None] = field(default_factory=list)
    info: list[np.ndarray] = field(default_factory=list)
    srcs: list[np.ndarray] = field(default_factory=list)


def _down(P: np.ndarray, voxel: float | None) -> np.ndarray:
    return voxel_downsample(P, voxel_size=voxel) if voxel else P


def _register_views(
    scans: Sequence[PosedScan], T_flange_camera: np.ndarray, o: ReconstructOptions, progress: Progress | None
) -> _Views:
    """Step 1: each view into the base frame (eq. 1), registered to the model merged so far (the first
    seeds it), and added to the model."""
    n, v = len(scans), _Views()
    model = np.empty((0, 3))
    icp_prior = replace(o.icp(), prior=o.prior)
    hand_eye = o.anchor == "hand-eye" and o.register_to_model
    for i, scan in enumerate(scans):
        P, T0 = view_to_base(scan, T_flange_camera)
        corr, res, ok, fb, fa = np.eye(4), None, True, 1.0, 1.0
        if i > 0 and o.register_to_model:
            corr, res, ok, fb, fa = _register_view(i, _down(P, o.voxel), model, o, icp_prior)
            v.info.append(res.information)
        elif i == 0 and hand_eye:
            src = _down(P, o.voxel)
            v.info.append(point_to_plane_information(src, pca_normals(src, k=o.normal_k)))
        if hand_eye:  # on the camera's voxel grid, see _leave_one_out
            v.srcs.append(_down(as_points(scan.cloud.points, "view cloud"), o.voxel))
        Pc = P @ corr[:3, :3].T + corr[:3, 3]
        v.T_kin.append(T0)
        v.full.append(Pc)
        v.T_bc.append(corr @ T0)
        v.corrections.append(corr)
        v.fit_before.append(fb)
        v.fit_after.append(fa)
        v.accepted.append(ok)
        v.icps.append(res)
        model = _down(np.concatenate([model, Pc]), o.voxel) if o.register_to_model else model
        if progress is not None:
            progress(i + 1, n, f"view {i + 1}/{n}: fitness {fb:.3f} -> {fa:.3f}")
    return v


def _register_view(
    i: int, src: np.ndarray, model: np.ndarray, o: ReconstructOptions, icp: IcpOptions
) -> tuple[np.ndarray, IcpResult, bool, float, float]:
    """ICP of view ``i``'s registration points ``src`` (base frame) to the model: (correction, ICP result,
    accepted, fitness before, after). A correction over ``max_correction`` or one that lowers the
    fitness by more than 0.02 is refused with a warning (identity kept; fitness after = before)."""
    d_max = o.correspondence_distance
    d_fit = o.fitness_distance or d_max / 3.0
    # one KD-tree of the model per view, shared by the normals (computed only where the view overlaps
    # the model), the correspondence search and eq. 20 before and after
    tree = PointTree(model)
    res = linear_icp(src, model, icp, target_tree=tree)
    fb = _fitness(res.initial_distances, src, np.eye(4), tree, d_fit, d_max)
    fa = _fitness(res.distances, src, res.T, tree, d_fit, d_max)
    dt = float(np.linalg.norm(res.T[:3, 3]))
    dr = rotation_angle(res.T[:3, :3])
    ok = dt <= o.max_correction[0] and dr <= o.max_correction[1] and fa >= fb - 0.02
    if ok:
        return res.T, res, True, fb, fa
    warnings.warn(
        f"view {i}: ICP correction {dt * 1e3:.1f} mm / {np.rad2deg(dr):.2f} deg "
        f"(fitness {fb:.3f} -> {fa:.3f}) rejected; kept the kinematic pose",
        stacklevel=4,
    )
    return np.eye(4), res, False, fb, fb


def _place_by_hand_eye(v: _Views, o: ReconstructOptions, progress: Progress | None) -> HandEyeFit:
    """Step 2 (anchor "hand-eye"): fit one hand-eye correction D to the registered poses, refine it by
    leave-one-out passes, and re-place every view at ``B_i D`` (when D is identifiable; else warn)."""
    conf = [1.0] + [
        r.inlier_fraction if ok and r.inlier_fraction >= MIN_OVERLAP else 0.0
        for r, ok in zip(v.icps[1:], v.accepted[1:], strict=True)
    ]
    first_fit = fit_hand_eye(v.T_bc, v.T_kin, v.info, conf)
    fit = _hand_eye_anchor(v.srcs, v.T_kin, first_fit, o.hand_eye_passes, o.icp(), o.max_correction, progress)
    if fit.applied:
        moves = [B @ fit.D @ invert(A) for A, B in zip(v.T_bc, v.T_kin, strict=True)]
        v.full = [P @ M[:3, :3].T + M[:3, 3] for P, M in zip(v.full, moves, strict=True)]
        v.T_bc = [B @ fit.D for B in v.T_kin]
        v.corrections = [B @ fit.D @ invert(B) for B in v.T_kin]
    else:
        warnings.warn(f"hand-eye anchor: {fit.note}; placed the model by the mean anchor", stacklevel=3)
    return fit


def _place_by_mean(v: _Views) -> np.ndarray:
    """Step 2 (anchor "mean"): remove the mean of the accepted corrections from every view; returns
    the shift applied."""
    shift = mean_anchor_shift([c for c, ok in zip(v.corrections, v.accepted, strict=True) if ok])
    v.full = [P @ shift[:3, :3].T + shift[:3, 3] for P in v.full]
    v.T_bc = [shift @ T for T in v.T_bc]
    v.corrections = [shift @ C for C in v.corrections]
    return shift


def _leave_one_out(
    srcs: list[np.ndarray],
    T_kin: list[np.ndarray],
    D: np.ndarray,
    icp: IcpOptions,
    max_correction: tuple[float, float],
) -> tuple[list[np.ndarray], list[np.ndarray], list[float]]:
    """Place the views' registration points (camera frame) at ``B_i D`` and register each to the union
    of the others -> (registered poses A_i, informations, confidences; 0 = left out).

    The points are down-sampled on each camera's own voxel grid: on one common grid (the base frame's)
    the views' voxel centroids of the same surface coincide where the views do, and ICP locks onto
    that grid (a 1 mm bias of the fitted correction on the Table I cylinder, 0.2 mm without)."""
    parts = [P @ (B @ D)[:3, :3].T + (B @ D)[:3, 3] for P, B in zip(srcs, T_kin, strict=True)]
    A, H, conf = [], [], []
    for i, P in enumerate(parts):
        others = [Q for j, Q in enumerate(parts) if j != i]
        c, info, T = 0.0, np.zeros((6, 6)), np.eye(4)
        try:
            r = linear_icp(P, np.concatenate(others), icp) if others else None
        except DataError:  # no overlap with the other views: left out of this fit
            r = None
        if r is not None:
            small = (
                np.linalg.norm(r.T[:3, 3]) <= max_correction[0] and rotation_angle(r.T) <= max_correction[1]
            )
            if small and r.inlier_fraction >= MIN_OVERLAP:
                c, info, T = r.inlier_fraction, r.information, r.T
        A.append(T @ T_kin[i] @ D)
        H.append(info)
        conf.append(c)
    return A, H, conf


def _hand_eye_anchor(
    srcs: list[np.ndarray],
    T_kin: list[np.ndarray],
    fit: HandEyeFit,
    passes: int,
    icp: IcpOptions,
    max_correction: tuple[float, float],
    progress=None,
) -> HandEyeFit:
    """Refine the first hand-eye fit by ``passes`` leave-one-out re-registrations (a pass whose fit is
    not identifiable ends the refinement and the previous fit is kept)."""
    n = len(srcs)
    for k in range(passes):
        if not fit.applied:
            break
        if progress is not None:
            progress(n, n, f"hand-eye correction: re-registration pass {k + 1}/{passes}")
        A, H, conf = _leave_one_out(srcs, T_kin, fit.D, icp, max_correction)
        new = fit_hand_eye(A, T_kin, H, conf)
        if not new.applied:
            break
        new.passes, fit = k + 1, new
    return fit


def mean_anchor_shift(corrections: Sequence[np.ndarray]) -> np.ndarray:
    """The transform S with ``mean(S @ C_i) = I`` for corrections C_i (mean translation about the base
    origin, chordal L2 mean rotation): the inverse of the corrections' mean."""
    if len(corrections) < 2:
        return np.eye(4)
    C = np.asarray(corrections, dtype=float)
    M = np.eye(4)
    M[:3, :3] = Rotation.from_matrix(C[:, :3, :3]).mean().as_matrix()
    M[:3, 3] = C[:, :3, 3].mean(axis=0)
    return np.linalg.inv(M)
