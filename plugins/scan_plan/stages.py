"""The scan-and-plan methods as stage plugins: settings models and the callables jobs use."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field
from scipy.spatial import cKDTree
from weldcell.sdk.cloud import PointCloud, check_cloud
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Angle, Length
from weldcell.sdk.weldpath import WeldPath

PositiveLength = Annotated[Length, Field(gt=0)]
PositiveAngle = Annotated[Angle, Field(gt=0)]


class ReconstructSettings(Settings):
    """Multi-view merge (eq. 1) + linear point-to-plane ICP (eqs. 2-8) against the growing model."""

    voxel: Length | None = Field(0.0015, gt=0, description="voxel size of the merged model [m]")
    register_to_model: bool = Field(True, description="register each view to the growing model (vs. no ICP)")
    max_correspondence_distance: Length | None = Field(
        0.005, gt=0, description="ICP correspondence distance d [m]; also the fitness distance of eq. 20"
    )
    max_iterations: int = Field(50, ge=1, description="ICP iterations per view")
    tolerance: float = Field(1e-6, gt=0, description="ICP convergence tolerance")
    robust: str | None = Field("huber", description="robust kernel: 'huber', 'tukey' or none")
    max_correction: tuple[PositiveLength, PositiveAngle] = Field(
        (0.05, 0.1745), description="largest ICP correction accepted over kinematics + hand-eye [m, rad]"
    )
    anchor: Literal["mean", "first", "hand-eye"] = Field(
        "mean",
        description="registered model placement: 'mean' of the views' kinematic poses, the 'first' view's, "
        "or 'hand-eye': fit one hand-eye correction common to all views and re-place them with it "
        "(needs views from varied tool orientations; falls back to 'mean' with a note)",
    )
    hand_eye_passes: int = Field(
        2,
        ge=0,
        description="anchor 'hand-eye': leave-one-out re-registration passes refining the correction "
        "(each costs about one more ICP per view)",
    )
    pose_prior: tuple[PositiveLength, PositiveAngle] | None = Field(
        None,
        description="expected error of a view's kinematic pose [m, rad], e.g. ['2 mm', '0.3 deg']: ICP "
        "becomes a MAP estimate that keeps weakly constrained directions near the kinematics; "
        "none = least squares",
    )


class Reconstructor:
    def __init__(self, s: ReconstructSettings) -> None:
        self.s = s

    def options(self):
        """The settings as :func:`~weldcell.plugins.scan_plan.reconstruct.reconstruct`'s options."""
        from weldcell.plugins.scan_plan.reconstruct import ReconstructOptions

        robust = None if (self.s.robust or "").lower() in ("", "none") else self.s.robust
        return ReconstructOptions(
            voxel=self.s.voxel,
            register_to_model=self.s.register_to_model,
            max_correspondence_distance=self.s.max_correspondence_distance,
            max_iterations=self.s.max_iterations,
            tolerance=self.s.tolerance,
            robust=robust,
            max_correction=tuple(self.s.max_correction),
            anchor=self.s.anchor,
            hand_eye_passes=self.s.hand_eye_passes,
            prior=tuple(self.s.pose_prior) if self.s.pose_prior is not None else None,
        )

    def __call__(self, scans, T_flange_camera, progress=None):
        from weldcell.plugins.scan_plan.reconstruct import reconstruct

        return reconstruct(scans, T_flange_camera, self.options(), progress=progress)


class BilateralSettings(Settings):
    """Point-cloud bilateral filter (eqs. 9-10) and voxel down-sampling."""

    radius: Length | None = Field(
        None, gt=0, description="neighbourhood radius [m]; default 3 x mean spacing"
    )
    sigma_c: Length | None = Field(None, gt=0, description="distance weight sigma_c [m]; default radius / 2")
    sigma_s: Length | None = Field(
        None, gt=0, description="normal-distance weight sigma_s [m]; default: noise"
    )
    iterations: int = Field(1, ge=0, le=10, description="filter passes (0 = off)")
    voxel_factor: float = Field(
        1.5, ge=0, description="down-sample to this multiple of the mean spacing (0 = off)"
    )
    min_voxel: Length = Field(
        0.0015,
        ge=0,
        description="but to voxels of at least this size [m]: a dense single "
        "frame is thinned to the resolution the seam stage is tuned for",
    )
    crop_min: tuple[Length, Length, Length] | None = Field(
        None, description="keep points above this corner [m]"
    )
    crop_max: tuple[Length, Length, Length] | None = Field(
        None, description="keep points below this corner [m]"
    )


class BilateralDenoiser:
    """The bilateral filter (eqs. 9-10) after an optional crop and voxel down-sampling.

    Returns the input cloud's scan (frame, viewpoints, meta) with the filtered points and their normals
    (:meth:`PointCloud.with_points`); after one pass the output also carries its neighbour table
    (:attr:`PointCloud.neighbours`), which the seam stage reuses instead of searching again. The scan's
    :class:`~weldcell.sdk.cloud.ScanStructure` (the input's, else measured on the cropped input before
    the voxel grid, where a line scan's profiles are still planar sheets,
    :func:`~weldcell.plugins.scan_plan.scan_structure.scan_structure`) travels with the output for the
    seam stage.
    """

    #: neighbours per point of the shared table (the seam stage's ``k_max``)
    k_table = 32
    #: points sampled for the spacing estimate of a big raw cloud (the voxel size only)
    spacing_sample = 20_000
    #: the shared table holds the neighbours within this multiple of the filter radius
    table_margin = 1.1

    def __init__(self, s: BilateralSettings) -> None:
        self.s = s

    def __call__(self, cloud: PointCloud) -> PointCloud:
        from weldcell.plugins.scan_plan.cloud_numerics import knn_table, mean_spacing, voxel_downsample
        from weldcell.plugins.scan_plan.denoise import bilateral_filter
        from weldcell.plugins.scan_plan.scan_structure import scan_structure

        check_cloud(cloud, "cloud to denoise", min_points=10)
        P = cloud.points
        keep = np.ones(len(P), dtype=bool)
        if self.s.crop_min is not None:
            keep &= np.all(P >= np.asarray(self.s.crop_min), axis=1)
        if self.s.crop_max is not None:
            keep &= np.all(P <= np.asarray(self.s.crop_max), axis=1)
        P = P[keep]
        check_cloud(PointCloud(P), "cloud inside the crop box", min_points=10)
        raw_tree = cKDTree(P, balanced_tree=False, compact_nodes=False)
        structure = cloud.structure if cloud.structure is not None else scan_structure(P, tree=raw_tree)
        cloud = cloud.with_structure(structure)
        if self.s.voxel_factor > 0:
            sp = mean_spacing(P, sample=self.spacing_sample, tree=raw_tree)
            P = voxel_downsample(P, voxel_size=max(self.s.voxel_factor * sp, self.s.min_voxel))
        normals = None
        if self.s.iterations > 0:
            tree = cKDTree(P)
            radius = self.s.radius or 3.0 * mean_spacing(P, sample=self.spacing_sample, tree=tree)
            # one search for the filter's N_r(p) and the seam stage's eq. 11 (the m = 12 nearest on a
            # filtered cloud; the margin covers them and the points' moves in the filter)
            table = knn_table(P, self.k_table, radius=self.table_margin * radius, tree=tree)
            P = table.points
            P, normals = bilateral_filter(
                P,
                radius,
                sigma_c=self.s.sigma_c,
                sigma_s=self.s.sigma_s,
                iterations=self.s.iterations,
                neighbours=table,
            )
            if self.s.iterations == 1:
                out = cloud.with_points(P, normals=normals)
                return out.with_neighbours(table.moved_to(out.points))
        return cloud.with_points(P, normals=normals)


def oriented_normals(cloud: PointCloud) -> np.ndarray | None:
    """The cloud's normals flipped toward a camera of ``cloud.viewpoints`` that saw the point (else None:
    the seam extractor then orients them itself).

    Each normal faces the nearest camera, as long as that camera can see the point
    (:func:`visible_from`). With a ring of views around a pipe the nearest camera is often *behind*
    the surface; such points face the camera that sees them most squarely among those that can see
    them, and points no camera sees keep the nearest camera.
    """
    V = cloud.sensor_viewpoints()
    if cloud.normals is None or V is None or len(V) == 0:
        return None
    P, N = cloud.points, cloud.normals
    d2 = ((P[:, None, :] - V[None, :, :]) ** 2).sum(axis=2)
    nearest = np.argmin(d2, axis=1)
    sign = np.sign(np.einsum("ij,ij->i", V[nearest] - P, N))
    if len(V) > 1:
        near_sees = np.zeros(len(P), dtype=bool)
        best = np.full(len(P), -1.0)  # |cos| of the most square camera that sees the point
        best_sign = np.zeros(len(P))
        for i, v in enumerate(V):
            D = v - P
            cos = np.einsum("ij,ij->i", D, N) / np.maximum(np.linalg.norm(D, axis=1), 1e-12)
            vis = visible_from(P, v)
            near_sees |= vis & (nearest == i)
            upd = vis & (np.abs(cos) > best)
            best[upd], best_sign[upd] = np.abs(cos[upd]), np.sign(cos[upd])
        other = ~near_sees & (best >= 0)
        sign[other] = best_sign[other]
    return N * np.where(sign < 0, -1.0, 1.0)[:, None]


def _image_axes(D: np.ndarray, z_axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pixel grid's axes in the image plane normal to ``z_axis``: the principal axes of the points'
    directions as the camera sees them, so the grid (and which points share a pixel) is the same in
    every frame the cloud may be expressed in (a sign flip of an axis leaves the bin edges in place)."""
    a = np.cross(z_axis, [1.0, 0.0, 0.0] if abs(z_axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(z_axis, a)
    zc = np.maximum(D @ z_axis, 1e-12)
    uv = np.stack([(D @ a) / zc, (D @ b) / zc], axis=1)
    _, vecs = np.linalg.eigh(np.cov(uv.T) if len(uv) > 2 else np.eye(2))
    x_axis = vecs[0, 1] * a + vecs[1, 1] * b  # the major axis
    x_axis /= np.linalg.norm(x_axis)
    return x_axis, np.cross(z_axis, x_axis)


def visible_from(
    P: np.ndarray, eye: np.ndarray, pixel: float | None = None, tol: float | None = 0.003
) -> np.ndarray:
    """Which points (N,) a camera at ``eye`` can see: a point-splat depth buffer.

    The points are projected through ``eye`` onto an image plane facing their centroid, binned in
    pixels of ``pixel`` rad (default 5 x the mean point spacing over the median range, so the surface
    closes without holes even where it is seen obliquely), and a point is visible when it lies within
    ``tol`` (m) of the nearest point in its pixel: the far side of a part is hidden. Points behind the
    eye's image plane are not visible. Conservative near creases and silhouettes (points there may be
    reported hidden), which :func:`oriented_normals` tolerates.
    """
    D = P - np.asarray(eye, dtype=float)
    z_axis = D.mean(axis=0)
    z_axis /= max(float(np.linalg.norm(z_axis)), 1e-12)
    x_axis, y_axis = _image_axes(D, z_axis)
    depth = np.linalg.norm(D, axis=1)
    zc = D @ z_axis
    front = zc > 1e-6
    out = np.zeros(len(P), dtype=bool)
    if not front.any():
        return out
    if pixel is None:
        from weldcell.plugins.scan_plan.cloud_numerics import mean_spacing

        pixel = 5.0 * mean_spacing(P, sample=2000) / float(np.median(depth[front]))
    f = np.flatnonzero(front)
    u = np.floor((D[f] @ x_axis) / zc[f] / pixel).astype(np.int64)
    w = np.floor((D[f] @ y_axis) / zc[f] / pixel).astype(np.int64)
    key = (u - u.min()) * (int(w.max() - w.min()) + 1) + (w - w.min())
    _, inv = np.unique(key, return_inverse=True)
    zmin = np.full(int(inv.max()) + 1, np.inf)
    np.minimum.at(zmin, inv, depth[f])
    if tol is None:
        tol = 0.003
    out[f] = depth[f] <= zmin[inv] + tol
    return out


class EdgeSeamSettings(Settings):
    """Edge-intensity seam extraction (eqs. 11-17) with joint classification and chaining."""

    m: int = Field(12, ge=3, description="minimum neighbourhood size of eq. 11")
    t: float = Field(40.0, ge=27.0, description="threshold on Tr(H)^3/Det(H) (eq. 16)")
    radius: Length | None = Field(None, gt=0, description="radius r of eq. 11 [m]; default 3 x spacing")
    sigma: Length | None = Field(None, gt=0, description="Gaussian of eq. 17 [m]; default as the paper")
    min_intensity: float = Field(0.15, ge=0, description="minimum edge intensity (eq. 12) of an edge point")
    joints: tuple[str, ...] = Field(("concave", "groove"), description="which edge classes become seams")
    contact_seams: bool = Field(
        False,
        description="keep the part's contact lines with the table or fixture plate it rests on or is held "
        "against (found from the scan) as seams; by default they are not weld seams and are dropped",
    )
    min_seam_length: Length = Field(0.02, gt=0, description="shorter seams are dropped [m]")
    spacing: Length | None = Field(None, gt=0, description="seam resampling step [m]; default r")
    wall_radius: Length | None = Field(
        None,
        ge=0,
        description="patch radius of the quadric wall fits that place curved and closed seams [m]; "
        "default 4 x the 8 mm side-plane radius; 0 keeps the side planes",
    )


class EdgeSeamExtractor:
    def __init__(self, s: EdgeSeamSettings) -> None:
        self.s = s

    def __call__(self, cloud: PointCloud):
        from weldcell.plugins.scan_plan.scan_structure import scan_structure
        from weldcell.plugins.scan_plan.seams import extract_seams

        check_cloud(cloud, "cloud for seam extraction", min_points=self.s.m + 1)
        normals = oriented_normals(cloud)
        return extract_seams(
            cloud.points,
            normals,
            m=self.s.m,
            t=self.s.t,
            radius=self.s.radius,
            sigma=self.s.sigma,
            min_intensity=self.s.min_intensity,
            joints=tuple(self.s.joints),
            contact_seams=self.s.contact_seams,
            min_seam_length=self.s.min_seam_length,
            spacing=self.s.spacing,
            wall_radius=self.s.wall_radius,
            neighbours=cloud.neighbours,
            viewpoints=cloud.sensor_viewpoints(),
            structure=cloud.structure if cloud.structure is not None else scan_structure(cloud.points),
        )


class TorchPathSettings(Settings):
    """Torch frames (o, m, n) along the seam (eq. 18) and linear + slerp interpolation (eq. 19)."""

    standoff: Length = Field(0.015, ge=0, description="contact-tip-to-work distance d [m]")
    work_angle: Angle = Field(0.0, description="torch rotation about the travel axis [rad]")
    travel_angle: Angle = Field(0.1745, description="push (+) or drag (-) angle about the torch y axis [rad]")
    travel_average: int = Field(5, ge=1, description="moving vectors averaged for the travel direction (m)")
    rho: int = Field(3, ge=0, description="poses interpolated between consecutive frames")


class TorchPathPlanner:
    def __init__(self, s: TorchPathSettings) -> None:
        self.s = s

    def __call__(self, seams, frame: str = "base") -> WeldPath:
        from weldcell.plugins.scan_plan.torch_path import plan_torch_path, weld_path

        paths = [
            plan_torch_path(
                seam,
                standoff=self.s.standoff,
                work_angle=self.s.work_angle,
                travel_angle=self.s.travel_angle,
                travel_average=self.s.travel_average,
                rho=self.s.rho,
            )
            for seam in seams
        ]
        return weld_path(list(seams), paths, frame=frame)
