"""The simulated cell: devices, workpieces, world, sensor models (no vendor library).

A run's simulated devices share one :class:`~weldcell.hal.sim.world.SimWorld` in the run's ``shared``
dict under :data:`WORLD_KEY`. Jobs and stages that compare against the simulated truth read it with
:func:`world_of` (None on hardware); simulated device factories build it with
:func:`weldcell.hal.sim.world.shared_world`. This module imports nothing heavy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from weldcell.hal.sim.world import SimWorld

#: the key of the run's ``shared`` dict that holds the simulated world (read it with :func:`world_of`)
WORLD_KEY = "sim.world"


def world_of(ctx: Any) -> SimWorld | None:
    """The run's simulated world, or None when the cell is hardware (no simulated device built one).

    ``ctx`` is anything with a ``shared`` dict: a job's run context or a device context."""
    return ctx.shared.get(WORLD_KEY)


def true_camera_mount(ctx: Any, config: str = "eye-on-base", role: str = "camera") -> np.ndarray | None:
    """The simulated depth camera's true mount, what a hand-eye calibration estimates: ``T_base_camera``
    for a camera fixed in the cell (``eye-on-base``, base = the ``robot`` device's base), else
    ``T_flange_camera``; None on hardware (no simulated world, or ``role`` is not a simulated camera).

    ``ctx`` is a run context (``shared`` and ``devices``)."""
    world = world_of(ctx)
    camera = ctx.devices.get(role)
    if world is None or not hasattr(camera, "T_world_camera"):
        return None
    if config == "eye-in-hand":
        return np.asarray(camera.T_parent_camera, float)
    from weldcell.sdk.geometry import invert

    return invert(world.T_world("robot.base")) @ camera.T_world_camera


__all__ = ["WORLD_KEY", "true_camera_mount", "world_of"]
