"""3-D reconstruction (paper 004 eq. 3) and the map folder: global voxel map, TSDF of the weld
regions, and the key-frame store ``weldcell/keyframes@1`` that map segmentation and relocalization
read (docs/file-formats.md).

Map folder::

    map/
      map.ply                 global coloured cloud (one point per occupied voxel: mean position + colour)
      regions/<id>.ply        dense TSDF surface (Open3D UniformTSDFVolume over the region's box)
      keyframes.json          weldcell/keyframes@1: intrinsics, T_imu_cam, one record per key frame
      keyframes/000042.npz    rgb (H,W,3 uint8), depth (H,W float32 m), ORB pixels/descriptors/points
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from weldcell.hal.readings import Intrinsics
from weldcell.sdk import artifacts
from weldcell.sdk.errors import DataError

KEYFRAMES_SCHEMA = "weldcell/keyframes@1"


def back_project(
    depth: np.ndarray,
    K: Intrinsics,
    T_world_cam: np.ndarray,
    rgb: np.ndarray | None = None,
    step: int = 1,
    max_depth: float = np.inf,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Eq. (3): pixels with depth -> world points (N, 3) (and their colours 0-1) through ``T_world_cam``."""
    d = depth[::step, ::step]
    v, u = np.nonzero(np.isfinite(d) & (d > 0) & (d <= max_depth))
    z = d[v, u].astype(np.float64)
    u, v = u * step, v * step
    P = np.column_stack([(u - K.cx) * z / K.fx, (v - K.cy) * z / K.fy, z])
    P = P @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    col = None if rgb is None else rgb[v, u, :3].astype(np.float64) / 255.0
    return P, col


class VoxelMap:
    """A global map with one cell per occupied voxel (running mean of position and colour): memory is
    bounded by the mapped volume / voxel size, not by the number of frames."""

    def __init__(self, voxel: float) -> None:
        if voxel <= 0:
            raise DataError(f"voxel size must be > 0, got {voxel}", "give e.g. 0.05 m")
        self.voxel = float(voxel)
        self._index: dict[int, int] = {}
        self._sum = np.zeros((0, 3))
        self._col = np.zeros((0, 3))
        self._n = np.zeros(0)

    def __len__(self) -> int:
        return len(self._n)

    def _keys(self, P: np.ndarray) -> np.ndarray:
        q = np.floor(P / self.voxel).astype(np.int64) + (1 << 20)
        return (q[:, 0] << 42) | (q[:, 1] << 21) | q[:, 2]

    def count_new(self, P: np.ndarray) -> int:
        """How many voxels integrating ``P`` would add (the map's point count after it, minus now)."""
        if len(P) == 0:
            return 0
        keys = np.unique(self._keys(P))
        return int(sum(int(k) not in self._index for k in keys))

    def integrate(self, P: np.ndarray, colors: np.ndarray | None = None) -> None:
        if len(P) == 0:
            return
        colors = np.full((len(P), 3), 0.5) if colors is None else colors
        keys, inv = np.unique(self._keys(P), return_inverse=True)
        s = np.zeros((len(keys), 3))
        c = np.zeros((len(keys), 3))
        n = np.bincount(inv, minlength=len(keys)).astype(float)
        for j in range(3):
            s[:, j] = np.bincount(inv, P[:, j], len(keys))
            c[:, j] = np.bincount(inv, colors[:, j], len(keys))
        idx = np.array([self._index.get(int(k), -1) for k in keys])
        new = idx < 0
        start = len(self._n)
        for i, k in enumerate(keys[new]):
            self._index[int(k)] = start + i
        self._sum = np.vstack([self._sum, np.zeros((new.sum(), 3))])
        self._col = np.vstack([self._col, np.zeros((new.sum(), 3))])
        self._n = np.concatenate([self._n, np.zeros(new.sum())])
        idx[new] = np.arange(start, start + new.sum())
        self._sum[idx] += s
        self._col[idx] += c
        self._n[idx] += n

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        n = np.maximum(self._n, 1)[:, None]
        return self._sum / n, np.clip(self._col / n, 0, 1)

    def save(self, path: Path) -> Path:
        import open3d as o3d

        P, C = self.points()
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
        pc.colors = o3d.utility.Vector3dVector(C)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + ".tmp" + path.suffix)
        o3d.io.write_point_cloud(str(tmp), pc, write_ascii=False)
        tmp.replace(path)
        return path


TSDF_MAX_RESOLUTION = 160
"""Voxels per side of a region's TSDF cube at most (memory: 20 bytes a voxel, 82 MB at 160³)."""


def tsdf_region(
    keyframes: list[dict], box_min: np.ndarray, box_max: np.ndarray, voxel: float, max_depth: float = 6.0
):
    """Dense surface of one weld region: the key frames that see the box fused into an Open3D
    ``UniformTSDFVolume`` (a cube over the box, truncation 4 voxels), cropped to the box; returns a legacy
    TriangleMesh, or None when no key frame sees the box.

    Open3D's hash-based volumes (``ScalableTSDFVolume``, ``t.geometry.VoxelBlockGrid``) extract nothing
    with the installed Open3D 0.20 build (a single flat view gave 0 vertices): the uniform volume over the
    region's box is used instead. Its memory is bounded by ``TSDF_MAX_RESOLUTION`` (a region larger than
    ``TSDF_MAX_RESOLUTION · voxel`` gets coarser voxels)."""
    import open3d as o3d

    box_min, box_max = np.asarray(box_min, float), np.asarray(box_max, float)
    side = float(np.max(box_max - box_min))
    res = int(min(TSDF_MAX_RESOLUTION, max(8, np.ceil(side / voxel))))
    vox = side / res
    center = (box_min + box_max) / 2
    vol = o3d.pipelines.integration.UniformTSDFVolume(
        length=side,
        resolution=res,
        sdf_trunc=4 * vox,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8,
        origin=center - side / 2,
    )
    used = 0
    for kf in keyframes:
        K: Intrinsics = kf["intrinsics"]
        T = kf["T_world_cam"]
        depth = np.ascontiguousarray(kf["depth"], dtype=np.float32)
        P, _ = back_project(depth, K, T, step=4, max_depth=max_depth)
        if not len(P) or not np.any(np.all((P >= box_min) & (P <= box_max), axis=1)):
            continue
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(kf["rgb"])),
            o3d.geometry.Image(depth),
            depth_scale=1.0,
            depth_trunc=max_depth,
            convert_rgb_to_intensity=False,
        )
        intr = o3d.camera.PinholeCameraIntrinsic(K.width, K.height, K.fx, K.fy, K.cx, K.cy)
        vol.integrate(rgbd, intr, np.linalg.inv(T))
        used += 1
    if used == 0:
        return None
    mesh = vol.extract_triangle_mesh()
    return mesh.crop(o3d.geometry.AxisAlignedBoundingBox(box_min, box_max))


@dataclass
class KeyFrameRecord:
    """One key frame of the store (what ``keyframes.json`` lists)."""

    index: int
    t: float
    stamp: float
    T_world_cam: np.ndarray
    T_world_imu: np.ndarray
    velocity: np.ndarray
    bias: np.ndarray
    file: str
    visual: bool = True
    covariance: np.ndarray | None = None
    """6x6 covariance of ``T_world_imu`` (gtsam Pose3 tangent space, [rotation, translation], body frame)
    from the global batch; None when the run did not compute it (older stores: the field is optional)."""

    def to_json(self) -> dict:
        extra = {} if self.covariance is None else {"covariance": np.asarray(self.covariance).tolist()}
        return {
            "index": self.index,
            "t": self.t,
            "stamp": self.stamp,
            "T_world_cam": self.T_world_cam.tolist(),
            "T_world_imu": self.T_world_imu.tolist(),
            "velocity": self.velocity.tolist(),
            "bias": self.bias.tolist(),
            "file": self.file,
            "visual": self.visual,
            **extra,
        }


class KeyFrameStore:
    """The ``weldcell/keyframes@1`` store of a map folder: written incrementally (a key frame's data
    file first, then the index, both atomically), so an interrupted run loses nothing already written."""

    def __init__(
        self,
        root: Path,
        intrinsics: Intrinsics | None = None,
        T_imu_cam: np.ndarray | None = None,
        meta: dict | None = None,
    ) -> None:
        self.root = Path(root)
        self.intrinsics = intrinsics
        self.T_imu_cam = np.eye(4) if T_imu_cam is None else np.asarray(T_imu_cam, float)
        self.records: list[KeyFrameRecord] = []
        self.meta = meta or {}

    @property
    def index_path(self) -> Path:
        return self.root / "keyframes.json"

    def add(self, kf, T_world_cam: np.ndarray) -> KeyFrameRecord:
        """Write one key frame (an :class:`~.estimator.KeyFrame`) and update the index."""
        name = f"keyframes/{kf.index:06d}.npz"
        path = self.root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + ".tmp.npz")
        f = kf.features
        np.savez_compressed(
            tmp,
            rgb=kf.rgb,
            depth=kf.depth.astype(np.float32),
            pixels=f.pixels.astype(np.float32),
            descriptors=f.descriptors,
            points=f.points.astype(np.float32),
        )
        tmp.replace(path)
        if self.intrinsics is None:
            self.intrinsics = kf.intrinsics
        rec = KeyFrameRecord(
            kf.index,
            float(kf.t),
            float(kf.stamp),
            T_world_cam,
            kf.T_world_imu.copy(),
            np.asarray(kf.velocity, float),
            np.asarray(kf.bias, float),
            name,
            bool(kf.visual),
        )
        self.records = [r for r in self.records if r.index != kf.index] + [rec]
        self.save_index()
        return rec

    def update_poses(
        self,
        poses: dict[int, tuple[np.ndarray, np.ndarray]],
        covariances: dict[int, np.ndarray | None] | None = None,
    ) -> None:
        """Replace key-frame poses (index -> (T_world_imu, T_world_cam)) after optimisation, and their
        pose covariances where given (index -> 6x6; None keeps the stored one: a resumed run's poses are
        the stored ones)."""
        for r in self.records:
            if r.index in poses:
                r.T_world_imu, r.T_world_cam = poses[r.index]
            if covariances is not None and covariances.get(r.index) is not None:
                r.covariance = covariances[r.index]

    def save_index(self) -> None:
        K = self.intrinsics
        data = {
            "schema": KEYFRAMES_SCHEMA,
            "frame": "world",
            "units": "m",
            "world": "first IMU frame, gravity-aligned (z up)",
            "intrinsics": None
            if K is None
            else {
                "width": K.width,
                "height": K.height,
                "fx": K.fx,
                "fy": K.fy,
                "cx": K.cx,
                "cy": K.cy,
                "dist": list(K.dist),
            },
            "T_imu_cam": self.T_imu_cam.tolist(),
            "descriptor": "ORB (OpenCV), 32-byte binary",
            "keyframes": [r.to_json() for r in sorted(self.records, key=lambda r: r.index)],
            **self.meta,
        }
        artifacts.write_json(self.index_path, data)

    @classmethod
    def load(cls, root: Path) -> KeyFrameStore:
        root = Path(root)
        p = root / "keyframes.json"
        if not p.is_file():
            raise DataError(
                f"{root} has no keyframes.json", "give a map folder written by `weldcell run` (job map)"
            )
        data = json.loads(p.read_text())
        if data.get("schema") != KEYFRAMES_SCHEMA:
            raise DataError(
                f"{p} is not {KEYFRAMES_SCHEMA} (schema {data.get('schema')!r})",
                "give a key-frame store written by this version",
            )
        k = data["intrinsics"]
        K = (
            None
            if k is None
            else Intrinsics(
                k["width"], k["height"], k["fx"], k["fy"], k["cx"], k["cy"], tuple(k.get("dist", ()))
            )
        )
        store = cls(root, K, np.array(data["T_imu_cam"]))
        for r in data["keyframes"]:
            store.records.append(
                KeyFrameRecord(
                    r["index"],
                    r["t"],
                    r["stamp"],
                    np.array(r["T_world_cam"]),
                    np.array(r["T_world_imu"]),
                    np.array(r["velocity"]),
                    np.array(r["bias"]),
                    r["file"],
                    r.get("visual", True),
                    np.array(r["covariance"]) if r.get("covariance") is not None else None,
                )
            )
        return store

    def read(self, rec: KeyFrameRecord) -> dict:
        """The images and features of one key frame."""
        with np.load(self.root / rec.file) as z:
            return {k: z[k] for k in z.files}
