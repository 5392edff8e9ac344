"""Parametric workpieces of the simulated cell, each with its ground-truth weld seams.

Every builder returns a :class:`Workpiece`: an Open3D triangle mesh in metres in the workpiece frame
(z up, resting on z = 0, centred on the origin in x and y) and a list of :class:`SeamTruth`. Seams
are computed from the analytic geometry (never read back from the mesh), sampled densely along travel
(``seam_spacing``, 0.5 mm by default), with a nominal torch approach direction that points from free
space into the joint (the bisector of the two faces for fillet-like joints) and a unit travel direction.
The torch frame of a seam point is ``z = approach``, ``x = travel``, ``y = z × x`` (see
:meth:`SeamTruth.torch_frames`).

Builders (``WORKPIECES``): ``v-groove-butt``, ``fillet-t``, ``lap``, ``corner``, ``cylinder-on-plate``,
``y-pipe``. ``make_workpiece(kind, **params)`` builds one by name. See docs/simulated-cell.md.

This module is the registry; the code is in :mod:`~weldcell.hal.sim.workpiece_model` (what a workpiece
and a seam are), :mod:`~weldcell.hal.sim.plate_joints`, :mod:`~weldcell.hal.sim.pipe_joints` (the
builders) and :mod:`~weldcell.hal.sim.mesh_tools` (their mesh pieces and argument checks).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

from weldcell.hal.sim.pipe_joints import cylinder_on_plate, y_pipe
from weldcell.hal.sim.plate_joints import corner, fillet_t, lap, v_groove_butt
from weldcell.hal.sim.workpiece_model import JOINTS, SEAM_SPACING, SeamTruth, Workpiece, rad
from weldcell.sdk.errors import DataError

__all__ = [
    "JOINTS",
    "SEAM_SPACING",
    "WORKPIECES",
    "SeamTruth",
    "Workpiece",
    "corner",
    "cylinder_on_plate",
    "fillet_t",
    "lap",
    "make_workpiece",
    "rad",
    "v_groove_butt",
    "workpiece_parameters",
    "y_pipe",
]


WORKPIECES: dict[str, Callable[..., Workpiece]] = {
    "v-groove-butt": v_groove_butt,
    "fillet-t": fillet_t,
    "lap": lap,
    "corner": corner,
    "cylinder-on-plate": cylinder_on_plate,
    "y-pipe": y_pipe,
}


def workpiece_parameters(kind: str) -> dict[str, object]:
    """The keyword parameters of a workpiece kind and their defaults (metres / radians)."""
    builder = _builder(kind)
    return {n: p.default for n, p in inspect.signature(builder).parameters.items()}


def _builder(kind: str) -> Callable[..., Workpiece]:
    key = str(kind).strip().lower().replace("_", "-")
    if key not in WORKPIECES:
        raise DataError(f"unknown workpiece kind '{kind}'", f"use one of {', '.join(WORKPIECES)}")
    return WORKPIECES[key]


def make_workpiece(kind: str, **params: float) -> Workpiece:
    """Build the workpiece ``kind`` (a key of ``WORKPIECES``) with the given keyword parameters."""
    builder = _builder(kind)
    valid = list(inspect.signature(builder).parameters)
    unknown = sorted(set(params) - set(valid))
    if unknown:
        raise DataError(
            f"workpiece '{kind}' has no parameter {', '.join(repr(u) for u in unknown)}",
            f"use only {', '.join(valid)} (metres / radians)",
        )
    return builder(**params)
