"""The simulated cell's shared world: the workpieces, the frame tree and the simulated clock.

Simulated devices of one run share one :class:`SimWorld` (through the run's ``shared`` dict, under
:data:`weldcell.hal.sim.WORLD_KEY`): device factories build it with :func:`shared_world`; jobs and
stages that compare against the simulated truth read it with :func:`weldcell.hal.sim.world_of` (None on
hardware).
The world frame is the cell's fixed frame; each robot registers its base (its mount) and a live
flange frame ``<role>.flange``; a camera mounted on ``<role>.flange`` follows the robot.
Fixtures (:data:`FIXTURES`, e.g. a fixed ISO 9409-1 flange plate a flange-mounted camera calibrates
against) are placed like workpieces but carry no seams.
Meshes can be *attached* to a live frame (a robot's flange and last link): depth cameras re-pose them
before every render, so they move with the robot.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from weldcell.hal.sim import WORLD_KEY
from weldcell.hal.sim.flange import plate_workpiece
from weldcell.hal.sim.workpieces import Workpiece, make_workpiece, workpiece_parameters
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy

#: scene parts that are not weld workpieces (no seams), placed like workpieces in [[sim.workpieces]]
FIXTURES: dict[str, Callable[..., Workpiece]] = {"iso9409-plate": plate_workpiece}


def scene_part(kind: str, **params: float) -> Workpiece:
    """A workpiece (``make_workpiece``) or a fixture of :data:`FIXTURES`, built by kind."""
    if kind not in FIXTURES:
        scene_parameters(kind)  # an unknown kind: one error listing workpieces and fixtures
        return make_workpiece(kind, **params)
    unknown = sorted(set(params) - set(scene_parameters(kind)))
    if unknown:
        raise DataError(
            f"'{kind}' has no parameter {', '.join(repr(u) for u in unknown)}",
            f"use only {', '.join(scene_parameters(kind))} (d1 in mm, the rest in metres)",
        )
    return FIXTURES[kind](**params)


def scene_parameters(kind: str) -> dict[str, object]:
    """The keyword parameters of a workpiece or fixture kind and their defaults."""
    if kind in FIXTURES:
        return {n: p.default for n, p in inspect.signature(FIXTURES[kind]).parameters.items()}
    try:
        return workpiece_parameters(kind)
    except DataError as e:
        raise DataError(e.message, f"{e.fix}, or a fixture: {', '.join(FIXTURES)}") from None


class SimClock:
    """Simulated time (s): advanced by simulated motions and sensor frames, never by the wall clock."""

    def __init__(self) -> None:
        self.t = 0.0

    def advance(self, dt: float) -> float:
        self.t += max(0.0, float(dt))
        return self.t


@dataclass(frozen=True)
class Attachment:
    """A rigid mesh (vertices in ``frame``) that moves with a live frame of the world."""

    frame: str
    vertices: np.ndarray
    triangles: np.ndarray


class SimWorld:
    """Workpieces placed in the world, live frames of robots, and the ray-casting scene."""

    def __init__(self, workpieces: list[Workpiece], seed: int = 0, table_height: float = 0.0) -> None:
        self.workpieces = workpieces
        self.table_height = table_height
        self.clock = SimClock()
        self.rng = np.random.default_rng(seed)
        self._frames: dict[str, Callable[[], np.ndarray]] = {"world": lambda: np.eye(4)}
        self._scene = None
        self.robots: dict[str, object] = {}
        self.attachments: dict[str, Attachment] = {}

    @classmethod
    def from_section(cls, section, seed: int = 0) -> SimWorld:
        """Build from a profile's ``[sim]`` section (:class:`weldcell.sdk.profile.SimSection`)."""
        parts = []
        for i, w in enumerate(section.workpieces):
            try:
                wp = scene_part(w.kind, **w.params)
            except DataError as e:
                raise DataError(f"[sim] workpieces[{i}]: {e.message}", e.fix) from None
            parts.append(wp.placed(T_from_rpy(w.rpy, w.xyz)))
        return cls(parts, seed=seed, table_height=section.table_height)

    # -- frames ----------------------------------------------------------------------------------
    def add_frame(self, name: str, fn: Callable[[], np.ndarray]) -> None:
        """Register a live frame: ``fn()`` returns ``T_world_<name>`` now."""
        self._frames[name] = fn

    def T_world(self, frame: str) -> np.ndarray:
        """``T_world_frame`` now ('world', 'base' = the first robot's base, '<role>.flange', ...)."""
        if frame == "base" and "base" not in self._frames:
            bases = [k for k in self._frames if k.endswith(".base")]
            if bases:
                frame = bases[0]
            else:
                return np.eye(4)
        if frame not in self._frames:
            raise DataError(
                f"the simulated cell has no frame '{frame}'; frames: {', '.join(self._frames)}",
                "mount the device on 'world' or on '<robot role>.flange'",
            )
        return self._frames[frame]()

    # -- geometry --------------------------------------------------------------------------------
    def attach(self, name: str, frame: str, vertices: np.ndarray, triangles: np.ndarray) -> None:
        """Attach a mesh (vertices (N, 3) in ``frame``, triangles (M, 3)) to a live frame under ``name``."""
        V = np.asarray(vertices, dtype=float).reshape(-1, 3)
        F = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        if len(F) == 0 or F.min() < 0 or F.max() >= len(V) or not np.all(np.isfinite(V)):
            raise DataError(
                f"attached mesh '{name}' is empty or has bad indices/vertices",
                "give finite vertices and triangles indexing them",
            )
        self.attachments[name] = Attachment(frame, V, F)

    def detach(self, name: str) -> None:
        """Remove an attached mesh (nothing happens if there is none of that name)."""
        self.attachments.pop(name, None)

    def meshes(self) -> list:
        """Every workpiece mesh in the world frame, plus the table top as a large thin box."""
        import open3d as o3d

        meshes = [w.mesh_in_world() for w in self.workpieces]
        table = o3d.geometry.TriangleMesh.create_box(3.0, 3.0, 0.02)
        table.translate([-1.5, -1.5, self.table_height - 0.02 - 1e-4])
        meshes.append(table)
        return meshes

    def seams_in_world(self) -> list:
        """Ground-truth seams of every workpiece, in the world frame."""
        out = []
        for i, w in enumerate(self.workpieces):
            for s in w.seams_in_world():
                out.append((f"{i}:{w.kind}", s))
        return out


def shared_world(ctx) -> SimWorld:
    """The run's simulated world, built once from the profile's ``[sim]`` section on first use.

    For simulated device factories (``ctx`` a :class:`~weldcell.sdk.jobs.DeviceContext`): every
    simulated device of the run gets the same world. Sensors on a robot ``base`` with no arm in the cell
    stand on the simulated site (a mobile robot's base)."""
    if WORLD_KEY not in ctx.shared:
        w = SimWorld.from_section(ctx.profile.profile.sim, seed=ctx.seed)
        devs = ctx.profile.profile.devices.values()
        on_base = any(e.mount.parent == "base" for e in devs)
        if on_base and not any(e.plugin.startswith("robot.") for e in devs):
            from weldcell.hal.sim.site import install_site

            install_site(w, seed=ctx.seed)
        ctx.shared[WORLD_KEY] = w
    return ctx.shared[WORLD_KEY]
