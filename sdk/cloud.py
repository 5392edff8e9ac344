"""Point clouds: an (N, 3) numpy array in metres with optional normals and colours, a frame name,
the scan's viewpoints, an optional neighbour table, and reading/writing PLY and PCD. Open3D is used at
the borders (``to_open3d``/``from_open3d``).

What one stage hands the next travels in typed fields, never in ``meta`` (free-form notes only):

* ``viewpoints`` (V, 3): where the sensor was for the views the cloud came from, in the cloud's own
  frame. :meth:`PointCloud.select`, :meth:`~PointCloud.with_points` and :meth:`~PointCloud.transformed`
  carry them (the last one moves them with the points); PLY/PCD files keep them in header comments.
* :attr:`PointCloud.neighbours`: a :class:`NeighbourTable` cache (one k-nearest-neighbour search a
  stage leaves for the next). It holds a copy of the points it was built for and is given only while
  the cloud's points are exactly those; any new cloud (select, transform, a stage's output) starts
  without it.
* ``structure``: a :class:`ScanStructure`, how the scan was sampled (area or line scan, spacings along
  and across its lines, surface noise), measured once on the cloud as captured
  (``weldcell.plugins.scan_plan.scan_structure``). It belongs to the scan, not to the exact points: a
  crop, a transform or a stage's filtered output (:meth:`PointCloud.with_points`) keeps it;
  :meth:`PointCloud.scaled` scales it. Not written to files (it is measured again from the points).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from weldcell.sdk.errors import DataError

UNIT_SCALE = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "um": 1e-6}
#: header comment of a cloud file that holds one viewpoint: ``weldcell viewpoint x y z`` (metres)
VIEWPOINT_COMMENT = "weldcell viewpoint"


@dataclass
class NeighbourTable:
    """Neighbours of every point of ``points`` from one KD-tree query: ``idx`` and ``dist`` (N, k + 1),
    the point itself in column 0, then its ``k`` nearest neighbours within ``radius`` (any order;
    missing entries -- fewer than ``k`` points within ``radius`` -- hold the point's own index and an
    infinite distance).

    ``points`` is a read-only copy of the points the table was built for: :meth:`matches` tells whether
    another array holds exactly those points, so a cropped, transformed or filtered cloud (or one
    whose points were changed in place) never uses a stale table. Build one with :meth:`search`.
    """

    points: np.ndarray
    idx: np.ndarray
    dist: np.ndarray
    radius: float = float("inf")

    def __post_init__(self) -> None:
        self.points = np.array(self.points, dtype=float).reshape(-1, 3)
        self.points.flags.writeable = False
        n = len(self.points)
        if self.idx.ndim != 2 or self.idx.shape[0] != n or self.dist.shape != self.idx.shape:
            raise DataError(
                f"neighbour table of {n} points has idx {self.idx.shape} and dist {self.dist.shape}",
                "build it with NeighbourTable.search(points, k, radius)",
            )

    @classmethod
    def search(cls, points: np.ndarray, k: int, radius: float = float("inf"), tree=None) -> NeighbourTable:
        """One query for the (at most) ``k`` nearest neighbours within ``radius`` of every point, plus the
        point itself (all cores; a finite ``radius`` makes it ~2-3x faster). ``tree``: a
        ``scipy.spatial.cKDTree`` of ``points`` to reuse."""
        from scipy.spatial import cKDTree

        P = np.asarray(points, dtype=float)
        if P.ndim != 2 or P.shape[1] != 3 or len(P) < 2 or not np.all(np.isfinite(P)):
            raise DataError(
                f"a neighbour table needs at least 2 finite (N, 3) points, got shape {P.shape}",
                "pass the cloud's points in metres, without NaN (weldcell.sdk.cloud.drop_invalid)",
            )
        k = int(min(k, len(P) - 1))
        tree = tree if tree is not None else cKDTree(P)
        dist, idx = tree.query(P, k=k + 1, workers=-1, distance_upper_bound=radius)
        miss = ~np.isfinite(dist)
        if miss.any():
            idx[miss] = np.broadcast_to(np.arange(len(P))[:, None], idx.shape)[miss]
        idx[:, 0] = np.arange(len(P))  # self first (a duplicate point could tie with it)
        dist[:, 0] = 0.0
        return cls(P, idx, dist, float(radius))

    @property
    def k(self) -> int:
        """Neighbours per point (self not counted)."""
        return self.idx.shape[1] - 1

    def moved_to(self, points: np.ndarray) -> NeighbourTable:
        """The same neighbour sets on moved ``points`` (same order of points, e.g. after the bilateral
        filter), distances recomputed. Valid while the points move by much less than the spacing: the
        sets then still hold every point within ``radius`` minus about the largest move."""
        Pt = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3).T)
        x, y, z = (Pt[j][self.idx] - Pt[j][:, None] for j in range(3))  # one gather per coordinate
        d = np.sqrt(x * x + y * y + z * z)
        d[~np.isfinite(self.dist)] = np.inf
        return NeighbourTable(Pt.T, self.idx, d, self.radius)

    def matches(self, points: np.ndarray, k: int = 0) -> bool:
        """Is this the table of exactly ``points`` (same shape and values), with at least ``k`` neighbours?"""
        P = np.asarray(points)
        if self.k < k or P.shape != self.points.shape:
            return False
        return P is self.points or bool(np.array_equal(P, self.points))


@dataclass(frozen=True)
class ScanStructure:
    """How a cloud was sampled (lengths in m), measured from the cloud alone by
    ``weldcell.plugins.scan_plan.scan_structure.scan_structure``.

    ``line_structured``: the cloud is a stack of planar slices (a swept line scanner), decided by
    ``line_share`` (share of sampled points on a slice). ``spacing`` / ``mean_spacing``: median / mean
    nearest-neighbour distance. ``along_spacing``: between neighbours along a line; ``sheet_gap``: between
    the planes of adjacent slices; ``line_spacing`` / ``line_spacing_hi``: median / upper quartile between
    adjacent lines *on the surface* (for an area scan all four equal ``spacing``, ``line_spacing_hi`` its
    upper quartile). ``sheet_thickness``: RMS of a slice's points off its plane (0 for an area scan).
    ``noise``: the surface's noise, RMS along its normal, over neighbourhoods that span at least two
    lines. ``span_radius``: radius of a neighbourhood that reaches the next line on both sides;
    ``span_neighbours``: points such a disc holds (median). ``sample``: points the estimates are medians
    over.
    """

    line_structured: bool
    line_share: float
    spacing: float
    mean_spacing: float
    along_spacing: float
    sheet_gap: float
    line_spacing: float
    line_spacing_hi: float
    sheet_thickness: float
    noise: float
    span_radius: float
    span_neighbours: int
    sample: int

    @property
    def anisotropy(self) -> float:
        """``line_spacing / along_spacing`` (1 for an area scan)."""
        return self.line_spacing / self.along_spacing

    def scaled(self, factor: float) -> ScanStructure:
        """The same structure with every length multiplied by ``factor`` (a unit change)."""
        lengths = ("spacing", "mean_spacing", "along_spacing", "sheet_gap", "line_spacing", "line_spacing_hi")
        more = ("sheet_thickness", "noise", "span_radius")
        return replace(self, **{k: getattr(self, k) * factor for k in lengths + more})

    def summary(self) -> str:
        """One line for logs and reports (mm)."""
        tail = (
            f"noise {self.noise * 1e3:.3f} mm, span radius {self.span_radius * 1e3:.2f} mm "
            f"({self.span_neighbours} points)"
        )
        share = f"{self.line_share:.0%} of points on slices"
        if not self.line_structured:
            return f"area scan ({share}): spacing {self.spacing * 1e3:.2f} mm, {tail}"
        return (
            f"line scan ({share}): spacing {self.along_spacing * 1e3:.2f} mm along, "
            f"{self.line_spacing * 1e3:.2f} mm across (sheets {self.sheet_gap * 1e3:.2f} mm apart), {tail}"
        )


def _as_viewpoints(views) -> np.ndarray | None:
    """Viewpoints as a finite (V, 3) float array (None for none)."""
    if views is None:
        return None
    try:
        V = np.array(views, dtype=float)
    except (TypeError, ValueError):
        V = np.full(1, np.nan)  # ragged or not numbers: refused below
    if V.size == 0:
        return None
    if V.size % 3 or not np.all(np.isfinite(V)):
        raise DataError(
            f"viewpoints must be finite (V, 3) positions, got {V.size} values of shape {V.shape}",
            "give one x, y, z (metres, in the cloud's frame) per view",
        )
    V = V.reshape(-1, 3)
    V.flags.writeable = False
    return V


@dataclass
class PointCloud:
    """Points (N, 3) in metres in ``frame``; ``normals`` (N, 3) and ``colors`` (N, 3, 0..1) are optional.

    ``viewpoints`` (V, 3, optional): the sensor positions of the views the points came from, in
    ``frame`` (the seam stage orients normals toward them). ``meta``: free-form notes (source file,
    counts) that no stage relies on. :attr:`neighbours`: an optional :class:`NeighbourTable` cache, set
    with :meth:`with_neighbours`, given only while it belongs to ``points``. ``structure`` (optional):
    the scan's :class:`ScanStructure`, measured on the cloud as captured and kept by its crops,
    transforms and filtered versions.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    frame: str = "base"
    meta: dict = field(default_factory=dict)
    viewpoints: np.ndarray | None = None
    structure: ScanStructure | None = None

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
        if "viewpoints" in self.meta:  # until 2026-11 the viewpoints travelled in meta: still honoured
            self.meta = dict(self.meta)  # not the caller's dict
            self.viewpoints = self.meta.pop("viewpoints")
            warnings.warn(
                "PointCloud.meta['viewpoints'] is deprecated: pass PointCloud(..., viewpoints=V)",
                DeprecationWarning,
                stacklevel=3,
            )
        self.viewpoints = _as_viewpoints(self.viewpoints)
        if self.structure is not None and not isinstance(self.structure, ScanStructure):
            raise DataError(
                f"a cloud's structure must be a ScanStructure, got {type(self.structure).__name__}",
                "measure it with weldcell.plugins.scan_plan.scan_structure.scan_structure(points)",
            )
        self._neighbours: NeighbourTable | None = None

    def __len__(self) -> int:
        return len(self.points)

    def sensor_viewpoints(self) -> np.ndarray | None:
        """:attr:`viewpoints`; for code written before they were typed, ``meta["viewpoints"]`` set after
        the cloud was built is still read (with a :class:`DeprecationWarning`), never silently ignored."""
        if self.viewpoints is None and "viewpoints" in self.meta:
            warnings.warn(
                "PointCloud.meta['viewpoints'] is deprecated: set cloud.viewpoints (or use with_viewpoints)",
                DeprecationWarning,
                stacklevel=2,
            )
            return _as_viewpoints(self.meta["viewpoints"])
        return self.viewpoints

    @property
    def neighbours(self) -> NeighbourTable | None:
        """The neighbour table attached by :meth:`with_neighbours`, while it belongs to exactly these
        points (else None, and the stale table is dropped)."""
        table = self._neighbours
        if table is not None and not table.matches(self.points):
            self._neighbours = table = None
        return table

    def with_neighbours(self, table: NeighbourTable | None) -> PointCloud:
        """This cloud (same arrays) with ``table`` attached; DataError when the table is of other points."""
        if table is not None and not isinstance(table, NeighbourTable):
            raise DataError(
                f"a cloud's neighbour table must be a NeighbourTable, got {type(table).__name__}",
                "build it with NeighbourTable.search(points, k, radius)",
            )
        if table is not None and not table.matches(self.points):
            raise DataError(
                f"the neighbour table ({len(table.points)} points) was built for other points than this "
                f"cloud's {len(self)}",
                "build the table from the cloud's own points: NeighbourTable.search(cloud.points, k)",
            )
        out = replace(self, meta=dict(self.meta))
        out._neighbours = table
        return out

    def with_points(
        self, points: np.ndarray, normals: np.ndarray | None = None, colors: np.ndarray | None = None
    ) -> PointCloud:
        """A cloud of other ``points`` from the same scan: same frame, viewpoints and meta; normals and
        colours as given (those of this cloud belong to its old points). A stage that filters or thins a
        cloud builds its output with this, so nothing the next stage needs is lost."""
        return replace(self, points=points, normals=normals, colors=colors, meta=dict(self.meta))

    def with_structure(self, structure: ScanStructure | None) -> PointCloud:
        """This cloud (same arrays, same neighbour table) with the scan's ``structure``."""
        out = replace(self, meta=dict(self.meta), structure=structure)
        out._neighbours = self.neighbours
        return out

    def with_viewpoints(self, viewpoints: np.ndarray | None) -> PointCloud:
        """This cloud (same arrays, same neighbour table) with ``viewpoints`` (V, 3, in ``frame``)."""
        out = replace(self, meta=dict(self.meta), viewpoints=viewpoints)
        out._neighbours = self.neighbours
        return out

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
        """This cloud mapped by ``T`` (``T_new_old``) into ``frame``; the viewpoints move with it."""
        T = np.asarray(T, dtype=float)
        return replace(
            self,
            points=self.points @ T[:3, :3].T + T[:3, 3],
            normals=None if self.normals is None else self.normals @ T[:3, :3].T,
            frame=frame or self.frame,
            meta=dict(self.meta),
            viewpoints=None if self.viewpoints is None else self.viewpoints @ T[:3, :3].T + T[:3, 3],
        )

    def scaled(self, factor: float) -> PointCloud:
        """This cloud with its points and viewpoints multiplied by ``factor`` (a unit change, e.g. mm to m:
        ``UNIT_SCALE["mm"]``); normals and colours as they are."""
        return replace(
            self,
            points=self.points * factor,
            meta=dict(self.meta),
            viewpoints=None if self.viewpoints is None else self.viewpoints * factor,
            structure=None if self.structure is None else self.structure.scaled(factor),
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
    cloud.viewpoints = _viewpoints_of(info.comments, info.path)
    return cloud


def _viewpoints_of(comments: list[str], path: Path) -> np.ndarray | None:
    """The viewpoints stored in a cloud file's header comments (:data:`VIEWPOINT_COMMENT`), or None."""
    rows = []
    for c in comments:
        if c.startswith(VIEWPOINT_COMMENT):
            try:
                rows.append([float(v) for v in c[len(VIEWPOINT_COMMENT) :].split()])
            except ValueError:
                rows.append([])
            if len(rows[-1]) != 3 or not np.all(np.isfinite(rows[-1])):
                raise DataError(
                    f"{path}: header comment {c!r} is not '{VIEWPOINT_COMMENT} x y z'",
                    "fix or delete that comment line (the viewpoints are optional)",
                )
    return np.array(rows) if rows else None


def _add_header_comments(path: Path, lines: list[str]) -> None:
    """Insert comment ``lines`` into the header of the PLY or PCD file Open3D wrote at ``path``: after
    the PLY ``format`` line (RPly wants it second), after the PCD file's first comment line."""
    if not lines:
        return
    data = path.read_bytes()
    ply = data.startswith(b"ply")
    keep = 2 if ply else 1
    head = data.split(b"\n", keep)
    if len(head) <= keep:
        raise DataError(f"could not write point cloud {path}: unexpected header", "report this as a bug")
    mark = "comment " if ply else "# "
    extra = "".join(f"{mark}{line}\n" for line in lines).encode("ascii")
    path.write_bytes(b"\n".join(head[:keep]) + b"\n" + extra + head[keep])


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
    return cloud if units == "m" else cloud.scaled(UNIT_SCALE[units])


def write_cloud(path: str | Path, cloud: PointCloud, binary: bool = True) -> Path:
    """Write a PLY or PCD file (metres) atomically; the viewpoints go into header comments
    (``weldcell viewpoint x y z``, which every reader skips), and :func:`read_cloud` reads them back."""
    import open3d as o3d
    from weldcell.sdk.artifacts import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        tmp_with_ext = tmp.with_suffix(path.suffix)
        ok = o3d.io.write_point_cloud(str(tmp_with_ext), cloud.to_open3d(), write_ascii=not binary)
        if not ok:
            raise DataError(f"could not write point cloud {path}", "check the folder exists and is writable")
        views = [] if cloud.viewpoints is None else cloud.viewpoints.tolist()
        _add_header_comments(tmp_with_ext, [f"{VIEWPOINT_COMMENT} {x!r} {y!r} {z!r}" for x, y, z in views])
        tmp_with_ext.replace(tmp)
    return path
