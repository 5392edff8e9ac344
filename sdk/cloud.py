"""Point clouds: an (N, 3) numpy array in metres with optional normals and colours, a frame name,
and reading/writing PLY and PCD. Open3D is used at the borders (``to_open3d``/``from_open3d``)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from weldcell.sdk.errors import DataError

UNIT_SCALE = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "um": 1e-6}


@dataclass
class PointCloud:
    """Points (N, 3) in metres in ``frame``; ``normals`` (N, 3) and ``colors`` (N, 3, 0..1) are optional."""

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    frame: str = "base"
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.points = np.asarray(self.points, dtype=float).reshape(-1, 3)
        n = len(self.points)
        for name in ("normals", "colors"):
            arr = getattr(self, name)
            if arr is not None:
                arr = np.asarray(arr, dtype=float).reshape(-1, 3)
                if len(arr) != n:
                    raise DataError(f"point cloud has {n} points but {len(arr)} {name}")
                setattr(self, name, arr)

    def __len__(self) -> int:
        return len(self.points)

    def select(self, index: np.ndarray) -> PointCloud:
        """A new cloud with the points at ``index`` (boolean mask or integer indices)."""
        return replace(
            self,
            points=self.points[index],
            normals=None if self.normals is None else self.normals[index],
            colors=None if self.colors is None else self.colors[index],
            meta=dict(self.meta),
        )

    def transformed(self, T: np.ndarray, frame: str | None = None) -> PointCloud:
        """This cloud mapped by ``T`` (``T_new_old``) into ``frame``."""
        T = np.asarray(T, dtype=float)
        return replace(
            self,
            points=self.points @ T[:3, :3].T + T[:3, 3],
            normals=None if self.normals is None else self.normals @ T[:3, :3].T,
            frame=frame or self.frame,
            meta=dict(self.meta),
        )

    def to_open3d(self):
        """An ``open3d.geometry.PointCloud`` (legacy API) with the same points, normals and colours."""
        import open3d as o3d

        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.points))
        if self.normals is not None:
            pc.normals = o3d.utility.Vector3dVector(self.normals)
        if self.colors is not None:
            pc.colors = o3d.utility.Vector3dVector(self.colors)
        return pc

    @classmethod
    def from_open3d(cls, pc, frame: str = "base") -> PointCloud:
        """Wrap an Open3D legacy point cloud."""
        pts = np.asarray(pc.points)
        return cls(
            pts.copy(),
            np.asarray(pc.normals).copy() if pc.has_normals() else None,
            np.asarray(pc.colors).copy() if pc.has_colors() else None,
            frame=frame,
        )


def check_cloud(cloud: PointCloud, what: str = "point cloud", min_points: int = 1) -> PointCloud:
    """Refuse empty clouds and clouds with NaN/inf coordinates, with a message saying what to do."""
    if len(cloud) < min_points:
        raise DataError(
            f"{what} has {len(cloud)} points; at least {min_points} are needed",
            "check that the camera saw the workpiece (range, exposure) and that cropping kept it",
        )
    bad = ~np.all(np.isfinite(cloud.points), axis=1)
    if bad.any():
        raise DataError(
            f"{what} has {int(bad.sum())} of {len(cloud)} points with NaN or infinite coordinates",
            "drop invalid depth pixels before passing the cloud (weldcell.sdk.cloud.drop_invalid)",
        )
    return cloud


def drop_invalid(cloud: PointCloud) -> PointCloud:
    """The cloud without NaN/inf points (and, for depth images, without zero-depth points at the origin)."""
    ok = np.all(np.isfinite(cloud.points), axis=1) & np.any(cloud.points != 0.0, axis=1)
    return cloud.select(ok)


def guess_units(points: np.ndarray) -> str | None:
    """'m' or 'mm' judged from the cloud's extent, or None when it cannot be told.

    A welding workpiece seen by a cell camera spans about 5 cm to 5 m. An extent over 20 (units)
    is almost surely millimetres; under 5 almost surely metres.
    """
    if len(points) < 2:
        return None
    ext = float(np.max(np.ptp(points, axis=0)))
    if ext > 20.0:
        return "mm"
    if ext < 5.0:
        return "m"
    return None


def check_units(cloud: PointCloud, declared: str, what: str = "point cloud") -> None:
    """Refuse a cloud whose size does not fit the declared units, with the option that fixes it."""
    guess = guess_units(cloud.points)
    if guess is not None and guess != declared:
        ext = float(np.max(np.ptp(cloud.points, axis=0)))
        raise DataError(
            f"{what} spans {ext:.4g} units; that looks like {guess}, not {declared}",
            f"pass --units {guess} (or convert the file to metres)",
        )


# A coordinate this large (in any unit weldcell reads) is garbage, not a workpiece: the data is damaged
# or the header's types do not match it.
_MAX_COORDINATE = 1e6


def load_cloud_file(path: str | Path, frame: str = "base") -> PointCloud:
    """Read a PLY or PCD file as stored (no unit conversion, NaN points kept).

    The file is checked first (:func:`weldcell.sdk.cloudfile.check_cloud_file`: header, declared
    point count against the body, x/y/z present), then read by Open3D with its console output
    silenced; the points read must be the points declared. DataError with the fix otherwise.
    """
    import open3d as o3d
    from weldcell.sdk.cloudfile import check_cloud_file, quiet_native_output

    info = check_cloud_file(path)
    with quiet_native_output() as said:
        pc = o3d.io.read_point_cloud(str(info.path), remove_nan_points=False, remove_infinite_points=False)
    cloud = PointCloud.from_open3d(pc, frame=frame)
    if len(cloud) != info.points:
        why = f" (the reader said: {said[0]})" if said else ""
        raise DataError(
            f"{info.path}: declares {info.points} points but {len(cloud)} could be read{why}",
            "the file is damaged; export or copy it again",
        )
    finite = cloud.points[np.all(np.isfinite(cloud.points), axis=1)]
    if len(finite) and float(np.max(np.abs(finite))) > _MAX_COORDINATE:
        raise DataError(
            f"{info.path}: coordinates reach {float(np.max(np.abs(finite))):.3g}: no scan in m or mm",
            "the data is damaged or its header declares the wrong types; export it again",
        )
    cloud.meta["source"] = str(info.path)
    return cloud


def read_cloud(
    path: str | Path, units: str = "m", frame: str = "base", check_scale: bool = True
) -> PointCloud:
    """Read a PLY or PCD file whose coordinates are in ``units``; return it in metres.

    Raises :class:`DataError` for a missing, unreadable, damaged (see :func:`load_cloud_file`) or
    empty file, NaNs, or (with ``check_scale``) a cloud whose extent does not fit ``units``.
    """
    path = Path(path)
    if units not in UNIT_SCALE:
        raise DataError(f"unknown units '{units}'", f"use one of {', '.join(UNIT_SCALE)}")
    cloud = load_cloud_file(path, frame=frame)
    check_cloud(cloud, what=str(path))
    if check_scale:
        check_units(cloud, units, what=str(path))
    if units != "m":
        cloud.points *= UNIT_SCALE[units]
    return cloud


def write_cloud(path: str | Path, cloud: PointCloud, binary: bool = True) -> Path:
    """Write a PLY or PCD file (metres) atomically."""
    import open3d as o3d
    from weldcell.sdk.artifacts import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        tmp_with_ext = tmp.with_suffix(path.suffix)
        ok = o3d.io.write_point_cloud(str(tmp_with_ext), cloud.to_open3d(), write_ascii=not binary)
        if not ok:
            raise DataError(f"could not write point cloud {path}", "check the folder exists and is writable")
        tmp_with_ext.replace(tmp)
    return path
