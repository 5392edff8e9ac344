"""Video laser projector as a fullscreen display output (device ``projector.window``). Registration only:
no vendor import here (pygame is imported by the adapter, extra ``projector``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from weldcell.sdk.descriptors import DeviceSpec
from weldcell.sdk.errors import MissingExtraError, ProfileError
from weldcell.sdk.geometry import T_from_rpy
from weldcell.sdk.hookspecs import hookimpl

NAME = "projector.window"


def world_pose(ctx, frame: str, _depth: int = 0) -> Callable[[], np.ndarray]:
    """``T_world_frame`` as a function evaluated when called: 'world', '<role>.base' (the robot's mount)
    or '<role>.flange' (the robot's mount times its flange pose read from the open device)."""
    if _depth > 8:
        raise ProfileError(f"mount chain through '{frame}' is circular", "check the devices' mount.parent")
    if frame in ("world", "base") and frame not in ctx.profile.profile.devices:
        return lambda: np.eye(4)
    role, _, part = frame.partition(".")
    entries = ctx.profile.profile.devices
    if role not in entries or part not in ("base", "flange"):
        raise ProfileError(
            f"device '{ctx.role}' is mounted on '{frame}', which is no frame of this cell",
            "use mount.parent = 'world' or '<robot role>.flange'",
        )
    m = entries[role].mount
    T_parent_base = T_from_rpy(m.rpy, m.xyz)
    parent = world_pose(ctx, m.parent, _depth + 1)

    def pose() -> np.ndarray:
        robot = ctx.device(role)
        T_wb = getattr(robot, "T_world_base", None)
        T = np.asarray(T_wb, dtype=float) if T_wb is not None else parent() @ T_parent_base
        return T @ robot.state().T_base_flange if part == "flange" else T

    return pose


def _factory(settings, ctx):
    try:
        from weldcell.plugins.projector.adapter import WindowProjector
    except ImportError as e:
        raise MissingExtraError(f"device '{NAME}'", e.name or "pygame", "projector") from None
    parent = world_pose(ctx, ctx.mount.parent)
    T_pd = ctx.T_parent_device
    return WindowProjector(settings, name=ctx.role, T_world_projector=lambda: parent() @ T_pd)


@hookimpl
def weldcell_register_devices(register):
    from weldcell.plugins.projector.settings import WindowProjectorSettings

    register(
        DeviceSpec(
            name=NAME,
            kind="laser_projector",
            summary="video laser projector (Microvision ShowWX+ class) as a fullscreen display (pygame)",
            settings=WindowProjectorSettings,
            factory=_factory,
            requires={"pygame": "projector"},
        )
    )
