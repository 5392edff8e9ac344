"""Ray-cast depth cameras with the noise, range and dropouts of real models.

A :class:`CameraPreset` (:mod:`weldcell.hal.sim.camera_presets`) holds a camera's published resolution
and field of view (turned into pinhole intrinsics), its working range and its depth-noise model::

    sigma(z) = sigma0 + sigma1 * z + sigma2 * z**2          (metres, z = depth along the optical axis)

Active stereo (RealSense D415/D435, ZED 2i) uses Intel's RMS-error formula, ``sigma2 = subpixel /
(f_px * baseline)``; structured light (PhoXi S/M) scales the published temporal noise at the sweet
spot with z² (triangulation); time of flight (Azure Kinect) is ``sigma0 + sigma1 * z``. On top of
that: noise grows at grazing incidence (``1 / max(cos θ, 0.1)``), pixels drop out at grazing angles
beyond ~75°, next to depth discontinuities, at random, where the second view (stereo partner or
projector, ``baseline`` along the camera's +x) is shadowed, and outside the working range.

:class:`RaycastCamera` renders :class:`DepthImage` s (z-depth in metres, 0 = no data) from a reusable
``open3d.t.geometry.RaycastingScene``. Sources of every preset are listed in docs/simulated-cell.md.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
from weldcell.hal.readings import DepthFrame, Intrinsics
from weldcell.hal.sim.camera_presets import (  # noqa: F401  (re-exported: the presets' old import path)
    PRESETS,
    STEREO_MAX_DISPARITY,
    STEREO_SUBPIXEL,
    ZED_RESOLUTIONS,
    CameraPreset,
    get_preset,
    zed_mode,
)
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid

# --------------------------------------------------------------------------------------------------
# Depth images
# --------------------------------------------------------------------------------------------------


@dataclass
class DepthImage:
    """A rendered depth image: z-depth (H, W) float32 metres, 0 = no data, in the optical frame
    (z forward, x right, y down) of a camera at ``T_world_camera``."""

    depth: np.ndarray
    intrinsics: Intrinsics
    T_world_camera: np.ndarray
    timestamp: float = 0.0
    meta: dict = field(default_factory=dict)

    @property
    def valid(self) -> np.ndarray:
        """(H, W) mask of pixels with data."""
        return np.isfinite(self.depth) & (self.depth > 0)

    def to_points(self) -> np.ndarray:
        """Back-project the valid pixels to (N, 3) points in the camera frame (row-major pixel order).

        Paper 004 eq. (3): X = (u - u0) d / fx, Y = (v - v0) d / fy, Z = d (depth scale 1: metres);
        the same back-projection as every depth camera's :meth:`DepthFrame.to_cloud`.
        """
        return self.to_cloud().points

    def to_cloud(self) -> PointCloud:
        """The valid pixels as a :class:`PointCloud` in frame 'camera'."""
        return self.to_frame().to_cloud()

    def to_world_cloud(self, frame: str = "world") -> PointCloud:
        """The valid pixels as a :class:`PointCloud` in the world frame (through ``T_world_camera``)."""
        return self.to_cloud().transformed(self.T_world_camera, frame=frame)

    def to_frame(self, frame: str = "camera") -> DepthFrame:
        """This image as a HAL :class:`~weldcell.hal.readings.DepthFrame` reading."""
        return DepthFrame(self.timestamp, self.depth, self.intrinsics, frame=frame, meta=dict(self.meta))


# --------------------------------------------------------------------------------------------------
# The ray-casting camera
# --------------------------------------------------------------------------------------------------


def _as_triangles(item: object) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (float32, world) and triangles (uint32) of a legacy/tensor mesh or a Workpiece."""
    mesh = item
    if hasattr(item, "mesh_in_world"):
        mesh = item.mesh_in_world()
    if isinstance(mesh, o3d.t.geometry.TriangleMesh):
        V = mesh.vertex.positions.numpy()
        F = mesh.triangle.indices.numpy()
    elif isinstance(mesh, o3d.geometry.TriangleMesh):
        V = np.asarray(mesh.vertices)
        F = np.asarray(mesh.triangles)
    else:
        raise DataError(
            f"cannot ray-cast a {type(item).__name__}",
            "give an open3d TriangleMesh (legacy or tensor) or a Workpiece",
        )
    if len(F) == 0:
        raise DataError("mesh has no triangles", "give a mesh with at least one triangle")
    if not np.all(np.isfinite(V)):
        raise DataError("mesh has NaN or infinite vertices", "clean the mesh before adding it to the scene")
    return np.ascontiguousarray(V, dtype=np.float32), np.ascontiguousarray(F, dtype=np.uint32)


class RaycastCamera:
    """A simulated depth camera that ray-casts a scene of triangle meshes (world frame).

    ``preset`` is a :class:`CameraPreset` or a key of ``PRESETS``; ``overrides`` replace preset fields
    (e.g. ``min_range=0.3``); ``decimation`` subsamples the image for speed. Meshes (or Workpieces,
    placed in the world) are added with :meth:`add` and can be replaced or removed by the handle it
    returns; the ray-casting scene is rebuilt only when the set of meshes changed.
    """

    def __init__(
        self,
        preset: CameraPreset | str = "realsense-d415",
        meshes: Iterable[object] = (),
        *,
        decimation: int = 1,
        noise: bool = True,
        shadows: bool = True,
        **overrides: object,
    ) -> None:
        self.preset = get_preset(preset).with_overrides(**overrides).decimated(decimation)
        self.noise = bool(noise)
        self.shadows = bool(shadows)
        p = self.preset
        u, v = np.meshgrid(np.arange(p.width, dtype=np.float32), np.arange(p.height, dtype=np.float32))
        # unnormalised directions with unit z: the ray parameter at a hit is the z-depth
        self._dirs_cam = np.column_stack(
            [((u - p.cx) / p.fx).ravel(), ((v - p.cy) / p.fy).ravel(), np.ones(u.size, dtype=np.float32)]
        ).astype(np.float32)
        self._dir_norm = np.linalg.norm(self._dirs_cam, axis=1)
        self._items: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._next = 0
        self._scene: o3d.t.geometry.RaycastingScene | None = None
        self._dirty = True
        for m in meshes:
            self.add(m)

    # -- scene -------------------------------------------------------------------------------------

    @property
    def intrinsics(self) -> Intrinsics:
        return self.preset.intrinsics

    def add(self, item: object) -> int:
        """Add a mesh (legacy or tensor open3d TriangleMesh, world frame) or a Workpiece; return a handle."""
        tri = _as_triangles(item)
        h = self._next
        self._next += 1
        self._items[h] = tri
        if self._scene is not None and not self._dirty:
            self._scene.add_triangles(o3d.core.Tensor(tri[0]), o3d.core.Tensor(tri[1]))
        else:
            self._dirty = True
        return h

    def replace(self, handle: int, item: object) -> None:
        """Replace the mesh added under ``handle`` (e.g. a workpiece placed elsewhere)."""
        self._check_handle(handle)
        self._items[handle] = _as_triangles(item)
        self._dirty = True

    def remove(self, handle: int) -> None:
        """Remove the mesh added under ``handle``."""
        self._check_handle(handle)
        del self._items[handle]
        self._dirty = True

    def clear(self) -> None:
        """Remove every mesh."""
        self._items.clear()
        self._dirty = True

    def _check_handle(self, handle: int) -> None:
        if handle not in self._items:
            raise DataError(
                f"no mesh with handle {handle} in the camera's scene",
                f"use a handle returned by add(): {sorted(self._items)}",
            )

    @property
    def scene(self) -> o3d.t.geometry.RaycastingScene:
        """The ray-casting scene (rebuilt lazily after replace/remove)."""
        if self._scene is None or self._dirty:
            scene = o3d.t.geometry.RaycastingScene()
            for V, F in self._items.values():
                scene.add_triangles(o3d.core.Tensor(V), o3d.core.Tensor(F))
            self._scene = scene
            self._dirty = False
        return self._scene

    # -- rendering ---------------------------------------------------------------------------------

    def cast(self, T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Noise-free ray cast: z-depth (H, W) (inf = no hit), cos of the incidence angle (H, W) and
        the unit surface normals (H, W, 3, world frame, facing the camera)."""
        p = self.preset
        z, cos, n, _ = self._cast(_check_pose(T_world_camera))
        return z.reshape(p.height, p.width), cos.reshape(p.height, p.width), n.reshape(p.height, p.width, 3)

    def _cast(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Flat (H·W) z-depth, |cos θ|, camera-facing normals and world ray directions (float32)."""
        d = self._dirs_cam @ np.ascontiguousarray(T[:3, :3].T, dtype=np.float32)  # BLAS path
        if not self._items:
            z = np.full(len(d), np.inf, dtype=np.float32)
            return z, np.zeros(len(d), np.float32), np.zeros_like(d), d
        rays = np.empty((len(d), 6), dtype=np.float32)
        rays[:, :3] = T[:3, 3].astype(np.float32)
        rays[:, 3:] = d
        ans = self.scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
        z = ans["t_hit"].numpy()
        n = ans["primitive_normals"].numpy()
        dn = np.einsum("ij,ij->i", n, d) / self._dir_norm
        n *= np.where(dn > 0, -1.0, 1.0).astype(np.float32)[:, None]  # face the camera
        cos = np.abs(dn)
        cos[~np.isfinite(z)] = 0.0
        return z, cos, n, d

    def render(
        self,
        T_world_camera: np.ndarray,
        rng: np.random.Generator | int | None = None,
        *,
        noise: bool | None = None,
        timestamp: float = 0.0,
    ) -> DepthImage:
        """Render a depth image from a camera at ``T_world_camera`` (optical frame: z forward, y down).

        With noise (the default unless the camera was built with ``noise=False``): Gaussian depth noise
        along each ray with std ``preset.sigma(z, cos θ)``, and dropouts (random, grazing beyond
        ``grazing_dropout_deg``, depth discontinuities, stereo/projector shadows). Without noise: the
        exact depth of every surface within the working range. Pixels outside
        ``[min_range, max_range]`` are always 0. ``rng`` (a Generator or a seed) makes it reproducible.
        """
        use_noise = self.noise if noise is None else bool(noise)
        T = _check_pose(T_world_camera)
        p = self.preset
        z, cos, nrm, d = self._cast(T)
        hit = np.isfinite(z)
        valid = hit & (z >= p.min_range) & (z <= p.max_range)
        out = np.where(valid, z, np.float32(0.0))
        meta = {"camera": p.name, "noise": use_noise}
        if use_noise and valid.any():
            rng = np.random.default_rng(rng)
            gauss = rng.standard_normal(z.shape, dtype=np.float32)
            draw = rng.random(z.shape, dtype=np.float32)
            # dropout probability: random, grazing incidence, next to depth discontinuities
            keep_prob = np.full(z.shape, 1.0 - p.random_dropout, dtype=np.float32)
            g0 = p.grazing_dropout_deg
            graze = valid & (cos < math.cos(math.radians(g0)))
            if g0 < 90 and graze.any():
                theta = np.degrees(np.arccos(np.clip(cos[graze], 0.0, 1.0)))
                keep_prob[graze] *= 1.0 - np.clip((theta - g0) / (90.0 - g0), 0.0, 1.0)
            if p.edge_dropout > 0:
                edge = _discontinuities(
                    np.where(hit, z, np.inf).reshape(p.height, p.width), p.edge_jump, p.edge_width
                ).ravel()
                keep_prob[edge] *= 1.0 - p.edge_dropout
            keep = valid & (draw < keep_prob)
            if self.shadows and p.baseline > 0:
                keep &= ~self._shadowed(T, z, nrm, d, keep)
            noisy = out + p.sigma(out, cos).astype(np.float32) * gauss
            out = np.where(keep & (noisy > 0), noisy, np.float32(0.0))
            meta["dropped"] = int(valid.sum() - np.count_nonzero(out))
        out = out.reshape(p.height, p.width).astype(np.float32, copy=False)
        return DepthImage(out, p.intrinsics, T.copy(), float(timestamp), meta)

    def _shadowed(
        self, T: np.ndarray, z: np.ndarray, n: np.ndarray, d: np.ndarray, mask: np.ndarray
    ) -> np.ndarray:
        """Pixels whose surface point the second view (at ``baseline`` along camera +x) cannot see."""
        out = np.zeros(z.shape, dtype=bool)
        idx = np.flatnonzero(mask)
        if len(idx) == 0:
            return out
        o = T[:3, 3].astype(np.float32)
        P = o + d[idx] * z[idx, None]
        n = n[idx]
        to2 = (o + (T[:3, 0] * self.preset.baseline).astype(np.float32)) - P
        facing_away = np.einsum("ij,ij->i", n, to2) <= 0
        rays = np.empty((len(idx), 6), dtype=np.float32)
        rays[:, :3] = P + np.float32(2e-5) * n
        rays[:, 3:] = to2
        occluded = self.scene.test_occlusions(o3d.core.Tensor.from_numpy(rays), tnear=1e-6, tfar=1.0).numpy()
        out[idx] = facing_away | occluded.astype(bool)
        return out


def _discontinuities(z: np.ndarray, rel_jump: float, width: int) -> np.ndarray:
    """(H, W) mask of pixels next to a depth jump larger than ``rel_jump`` · z (or next to no-hit)."""
    e = np.zeros(z.shape, dtype=bool)
    for axis in (0, 1):
        a = z.take(np.arange(z.shape[axis] - 1), axis=axis)
        b = z.take(np.arange(1, z.shape[axis]), axis=axis)
        with np.errstate(invalid="ignore"):
            near = np.minimum(a, b)
            jump = (np.abs(a - b) > rel_jump * near) | (np.isinf(a) != np.isinf(b))
        jump &= np.isfinite(near)
        sl_a = [slice(None)] * 2
        sl_b = [slice(None)] * 2
        sl_a[axis] = slice(0, -1)
        sl_b[axis] = slice(1, None)
        e[tuple(sl_a)] |= jump
        e[tuple(sl_b)] |= jump
    if width > 1:
        from scipy.ndimage import binary_dilation

        e = binary_dilation(e, iterations=width - 1)
    return e & np.isfinite(z)


def _check_pose(T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if not is_rigid(T):
        raise DataError(
            "T_world_camera is not a rigid 4x4 transform",
            "give a 4x4 pose with an orthonormal rotation (camera optical frame in the world)",
        )
    return T
