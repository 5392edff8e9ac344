"""What a simulated workpiece is: a triangle mesh with its ground-truth weld seams.

:class:`Workpiece` holds an Open3D mesh in metres in the workpiece frame (z up, resting on z = 0) and
its :class:`SeamTruth` list; :meth:`Workpiece.placed` puts it in the world. The builders are in
:mod:`~weldcell.hal.sim.plate_joints` and :mod:`~weldcell.hal.sim.pipe_joints`, the registry in
:mod:`~weldcell.hal.sim.workpieces`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import open3d as o3d
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import is_rigid, transform_points, transform_vectors

JOINTS = ("butt", "fillet", "lap", "corner", "saddle", "pipe-junction")
SEAM_SPACING = 0.0005
"""Default distance (m) between consecutive ground-truth seam points."""


def rad(deg: float) -> float:
    """Degrees to radians (for readable defaults)."""
    return math.radians(deg)


def _unit_rows(v: np.ndarray, what: str) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    if np.any(n < 1e-12) or not np.all(np.isfinite(v)):
        raise DataError(f"seam {what} has zero-length or non-finite vectors", "give unit direction vectors")
    return v / n


@dataclass
class SeamTruth:
    """A ground-truth seam: points (K, 3) ordered along travel, unit approach and travel (K, 3).

    ``closed`` seams are loops: the last point connects back to the first (the first point is not
    repeated). ``approach`` points from free space toward the work (torch z); ``travel`` is torch x.
    """

    id: str
    joint: str
    points: np.ndarray
    approach: np.ndarray
    travel: np.ndarray
    closed: bool = False

    def __post_init__(self) -> None:
        if self.joint not in JOINTS:
            raise DataError(
                f"seam '{self.id}': unknown joint '{self.joint}'", f"use one of {', '.join(JOINTS)}"
            )
        self.points = np.asarray(self.points, dtype=float).reshape(-1, 3)
        k = len(self.points)
        if k < 2:
            raise DataError(
                f"seam '{self.id}' has {k} points; at least 2 are needed", "sample the seam densely"
            )
        for name in ("approach", "travel"):
            v = np.asarray(getattr(self, name), dtype=float).reshape(-1, 3)
            if len(v) != k:
                raise DataError(
                    f"seam '{self.id}' has {k} points but {len(v)} {name} vectors", "give one per point"
                )
            setattr(self, name, _unit_rows(v, name))

    def __len__(self) -> int:
        return len(self.points)

    @property
    def length(self) -> float:
        """Length of the seam (m), including the closing segment of a loop."""
        return float(self.segment_lengths().sum())

    def segment_lengths(self) -> np.ndarray:
        """Distances between consecutive points (and last→first for a closed seam)."""
        p = np.vstack([self.points, self.points[:1]]) if self.closed else self.points
        return np.linalg.norm(np.diff(p, axis=0), axis=1)

    def transformed(self, T: np.ndarray) -> SeamTruth:
        """This seam mapped by ``T`` (``T_new_old``)."""
        return replace(
            self,
            points=transform_points(T, self.points),
            approach=transform_vectors(T, self.approach),
            travel=transform_vectors(T, self.travel),
        )

    def torch_frames(self) -> np.ndarray:
        """(K, 4, 4) torch frames: z = approach, x = travel orthogonalised, y = z × x, origin = point."""
        z = self.approach
        x = self.travel - np.sum(self.travel * z, axis=1, keepdims=True) * z
        x = _unit_rows(x, "travel (orthogonal to approach)")
        y = np.cross(z, x)
        T = np.zeros((len(self), 4, 4))
        T[:, :3, 0], T[:, :3, 1], T[:, :3, 2], T[:, :3, 3] = x, y, z, self.points
        T[:, 3, 3] = 1.0
        return T


@dataclass
class Workpiece:
    """A workpiece mesh (workpiece frame, metres) with its ground-truth seams and where it is placed."""

    name: str
    kind: str
    mesh: o3d.geometry.TriangleMesh
    seams: list[SeamTruth]
    params: dict = field(default_factory=dict)
    T_world_workpiece: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        self.T_world_workpiece = _check_T(self.T_world_workpiece, "T_world_workpiece")

    def placed(self, T_world_workpiece: np.ndarray) -> Workpiece:
        """A new workpiece, the same part placed at ``T_world_workpiece`` (the mesh is copied)."""
        return Workpiece(
            self.name,
            self.kind,
            o3d.geometry.TriangleMesh(self.mesh),
            list(self.seams),
            dict(self.params),
            _check_T(T_world_workpiece, "T_world_workpiece"),
        )

    def mesh_in_world(self) -> o3d.geometry.TriangleMesh:
        """A copy of the mesh transformed into the world frame."""
        m = o3d.geometry.TriangleMesh(self.mesh)
        m.transform(self.T_world_workpiece)
        return m

    def seams_in_world(self) -> list[SeamTruth]:
        """The seams transformed into the world frame."""
        return [s.transformed(self.T_world_workpiece) for s in self.seams]

    def seam(self, seam_id: str) -> SeamTruth:
        """The seam called ``seam_id`` (workpiece frame)."""
        for s in self.seams:
            if s.id == seam_id:
                return s
        raise DataError(
            f"workpiece '{self.name}' has no seam '{seam_id}'",
            f"use one of {', '.join(s.id for s in self.seams)}",
        )

    def sample_surface(
        self, n: int, rng: np.random.Generator | int | None = None, frame: str = "world"
    ) -> PointCloud:
        """``n`` points sampled uniformly by area on the surface, with face normals, in ``frame``
        ('world' or 'workpiece')."""
        if frame not in ("world", "workpiece"):
            raise DataError(f"unknown frame '{frame}'", "use 'world' or 'workpiece'")
        if n < 1:
            raise DataError(f"cannot sample {n} points", "ask for at least one point")
        rng = np.random.default_rng(rng)
        V = np.asarray(self.mesh.vertices)
        F = np.asarray(self.mesh.triangles)
        a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
        cr = np.cross(b - a, c - a)
        area = np.linalg.norm(cr, axis=1)
        idx = rng.choice(len(F), size=n, p=area / area.sum())
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        w0, w1, w2 = 1.0 - s, s * (1.0 - r2), s * r2
        pts = w0[:, None] * a[idx] + w1[:, None] * b[idx] + w2[:, None] * c[idx]
        nrm = cr[idx] / np.maximum(area[idx], 1e-300)[:, None]
        cloud = PointCloud(pts, normals=nrm, frame="workpiece", meta={"workpiece": self.name})
        if frame == "world":
            cloud = cloud.transformed(self.T_world_workpiece, frame="world")
        return cloud


def _check_T(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if not is_rigid(T):
        raise DataError(
            f"{what} is not a rigid 4x4 transform", "give a 4x4 matrix with an orthonormal rotation"
        )
    return T.copy()
