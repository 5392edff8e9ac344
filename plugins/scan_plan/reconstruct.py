"""Multi-view reconstruction of the scan-and-plan method (paper 000, section II-C, eq. 1 + eqs. 2-8).

Every captured view is put into the robot base frame with the robot's flange pose and the hand-eye
transform, ``bFp = bMe . eMc . cFp`` (eq. 1), then refined by linear point-to-plane ICP against the
model merged so far (not only the previous view), and added to the model.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid, rotation_angle
from weldcell.sdk.scan import PosedScan  # noqa: F401  (re-exported: the scan type of this stage)

from .denoise import as_points, voxel_downsample
from .nearest import PointTree
from .registration import IcpResult, linear_icp

Progress = Callable[[int, int, str], None]
ANCHORS = ("mean", "first")


@dataclass
class ReconstructResult:
    """Outcome of :func:`reconstruct`.

    ``cloud`` is the merged model in the base frame. Per view ``i``: ``T_base_camera[i]`` the refined
    camera pose, ``corrections[i]`` the ICP correction ``T_base_base'`` applied on top of eq. 1 (identity
    for the first view and for rejected corrections), ``fitness_before[i]`` / ``fitness[i]`` eq. 20
    against the model before / after refinement, ``accepted[i]`` whether the ICP correction was kept,
    ``icp[i]`` the full :class:`IcpResult` (None for the first view or when ICP was off).
    ``anchor_shift`` is the transform applied to the registered model by ``anchor="mean"`` (identity
    for ``anchor="first"``); it is included in ``corrections`` and ``T_base_camera``.
    """

    cloud: PointCloud
    T_base_camera: list[np.ndarray]
    corrections: list[np.ndarray]
    fitness_before: list[float]
    fitness: list[float]
    accepted: list[bool]
    icp: list[IcpResult | None] = field(default_factory=list)
    anchor_shift: np.ndarray = field(default_factory=lambda: np.eye(4))


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
    """Union of all views mapped into the base frame with eq. 1 (no refinement)."""
    if len(views) == 0:
        raise DataError("no views to merge", "capture at least one view")
    parts = [view_to_base(v, T_flange_camera)[0] for v in views]
    normals = None
    if all(v.cloud.normals is not None for v in views):
        T_fc = np.asarray(T_flange_camera, dtype=float)
        normals = np.concatenate(
            [v.cloud.normals @ (np.asarray(v.T_base_flange)[:3, :3] @ T_fc[:3, :3]).T for v in views]
        )
    return PointCloud(np.concatenate(parts), normals=normals, frame="base", meta={"n_views": len(views)})


def reconstruct(
    scans: Sequence[PosedScan],
    T_flange_camera: np.ndarray,
    *,
    voxel: float | None,
    register_to_model: bool = True,
    max_correspondence_distance: float | None = None,
    max_iterations: int = 50,
    tolerance: float = 1e-6,
    robust: str | None = "huber",
    update: str = "exact",
    max_correction: tuple[float, float] = (0.05, np.deg2rad(10.0)),
    normal_k: int = 20,
    fitness_distance: float | None = None,
    anchor: str = "mean",
    prior: tuple[float, float] | None = None,
    progress: Progress | None = None,
) -> ReconstructResult:
    """Merge posed views into one model in the base frame (eq. 1) refined by ICP (eqs. 2-8).

    The first view seeds the model. Each further view starts from its kinematic pose (flange pose x
    hand-eye) and is registered by :func:`linear_icp` to the model merged so far (``register_to_model``;
    with False, views are only merged by eq. 1). Both the view and the model are voxel-down-sampled at
    ``voxel`` metres for registration; the returned cloud is the union of all points with the refined
    poses, down-sampled at ``voxel`` (None keeps every point).
    ``max_correspondence_distance`` defaults to 3 x ``voxel`` (or 1 cm without a voxel). The reported
    fitness (eq. 20, view points aligned to the model / model points) counts pairs closer than
    ``fitness_distance`` (default: a third of the correspondence distance, i.e. the voxel size).
    A correction larger than ``max_correction`` (m, rad), or one that lowers the fitness by more than
    0.02, is rejected (kinematic pose kept) with a warning: the kinematics are trusted over a wrong
    local minimum.
    ``anchor`` = "mean" places the registered model where the views' kinematic poses put it on
    average (the mean of the accepted corrections is removed: mean translation, chordal mean rotation);
    "first" keeps the first view's kinematic pose (the paper).
    ``prior = (sigma_t, sigma_r)`` (m, rad), the expected error of a view's kinematic pose, makes each
    registration a MAP estimate (see :func:`linear_icp`): poorly constrained directions stay put.
    ``progress(i, n, message)`` is called once per view.
    """
    n = len(scans)
    if anchor not in ANCHORS:
        raise DataError(f"unknown anchor '{anchor}'", "use anchor='mean' or 'first'")
    if n == 0:
        raise DataError("no scans to reconstruct", "capture at least one view")
    if voxel is not None and (not np.isfinite(voxel) or voxel <= 0):
        raise DataError(
            f"voxel must be > 0 m or None, got {voxel}", "use e.g. 2 mm (0.002) for an RGB-D scan"
        )
    d_max = max_correspondence_distance or (3.0 * voxel if voxel else 0.01)
    d_fit = fitness_distance or d_max / 3.0

    def down(P: np.ndarray) -> np.ndarray:
        return voxel_downsample(P, voxel_size=voxel) if voxel else P

    full: list[np.ndarray] = []
    T_bc: list[np.ndarray] = []
    corrections: list[np.ndarray] = []
    fit_before: list[float] = []
    fit_after: list[float] = []
    accepted: list[bool] = []
    icps: list[IcpResult | None] = []
    model = np.empty((0, 3))
    for i, scan in enumerate(scans):
        P, T0 = view_to_base(scan, T_flange_camera)
        corr = np.eye(4)
        res = None
        ok = True
        fb = fa = 1.0
        if i > 0 and register_to_model:
            src = down(P)
            # one KD-tree of the model per view, shared by the normals (computed only where the view
            # overlaps the model), the correspondence search and eq. 20 before and after
            tree = PointTree(model)
            res = linear_icp(
                src,
                model,
                None,
                max_correspondence_distance=d_max,
                max_iterations=max_iterations,
                tolerance=tolerance,
                robust=robust,
                update=update,
                normal_k=normal_k,
                target_tree=tree,
                prior=prior,
            )
            fb = _fitness(res.initial_distances, src, np.eye(4), tree, d_fit, d_max)
            fa = _fitness(res.distances, src, res.T, tree, d_fit, d_max)
            dt = float(np.linalg.norm(res.T[:3, 3]))
            dr = rotation_angle(res.T[:3, :3])
            ok = dt <= max_correction[0] and dr <= max_correction[1] and fa >= fb - 0.02
            if ok:
                corr = res.T
            else:
                warnings.warn(
                    f"view {i}: ICP correction {dt * 1e3:.1f} mm / {np.rad2deg(dr):.2f} deg "
                    f"(fitness {fb:.3f} -> {fa:.3f}) rejected; kept the kinematic pose",
                    stacklevel=2,
                )
                fa = fb
        Pc = P @ corr[:3, :3].T + corr[:3, 3]
        full.append(Pc)
        T_bc.append(corr @ T0)
        corrections.append(corr)
        fit_before.append(fb)
        fit_after.append(fa)
        accepted.append(ok)
        icps.append(res)
        model = down(np.concatenate([model, Pc])) if register_to_model else model
        if progress is not None:
            progress(i + 1, n, f"view {i + 1}/{n}: fitness {fb:.3f} -> {fa:.3f}")
    shift = np.eye(4)
    if anchor == "mean" and register_to_model:
        shift = mean_anchor_shift([c for c, ok in zip(corrections, accepted, strict=True) if ok])
        full = [P @ shift[:3, :3].T + shift[:3, 3] for P in full]
        T_bc = [shift @ T for T in T_bc]
        corrections = [shift @ C for C in corrections]
    merged = down(np.concatenate(full))
    cloud = PointCloud(merged, frame="base", meta={"n_views": n, "voxel": voxel, "anchor": anchor})
    return ReconstructResult(cloud, T_bc, corrections, fit_before, fit_after, accepted, icps, shift)


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
