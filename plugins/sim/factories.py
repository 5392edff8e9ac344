"""Factories that build simulated devices from their settings and the run's device context."""

from __future__ import annotations

import numpy as np
from weldcell.hal.kinematics import get_model
from weldcell.hal.safety import SafetyGate
from weldcell.hal.sim import devices as d
from weldcell.hal.sim.flange import flange_for
from weldcell.hal.sim.hands import load_script
from weldcell.hal.sim.world import SimWorld, shared_world
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rotvec, T_from_rpy


def world(ctx) -> SimWorld:
    """The run's simulated world (built once from the profile's [sim] section): :func:`shared_world`."""
    return shared_world(ctx)


def _parent(ctx) -> str:
    return ctx.mount.parent


def robot(settings, ctx) -> d.SimRobot:
    model = get_model(settings.model)
    w = world(ctx)
    q_start = None
    if settings.start_xyz is not None:
        q_start = model.ik(T_from_rpy(settings.start_rpy, settings.start_xyz), model.home)
    return d.SimRobot(
        model,
        w,
        T_world_base=w.T_world(ctx.mount.parent) @ ctx.T_parent_device,
        name=ctx.role,
        gate=SafetyGate(ctx.safety, model=model),
        motion=settings,
        dry_run=ctx.dry_run,
        q_start=q_start,
        flange=flange_for(model.name) if settings.flange_geometry else None,
        q_error=np.random.default_rng(ctx.seed + 11).normal(0.0, settings.joint_offset_error, model.dof),
    )


def camera(settings, ctx) -> d.SimDepthCamera:
    T_true = ctx.T_parent_device
    if settings.mount_error > 0 or settings.mount_error_angle > 0:
        rng = np.random.default_rng(ctx.seed + 17)
        axis = rng.normal(size=3)
        direction = rng.normal(size=3)
        dT = T_from_rotvec(
            axis / np.linalg.norm(axis) * settings.mount_error_angle,
            direction / np.linalg.norm(direction) * settings.mount_error,
        )
        T_true = T_true @ dT
    cam = d.SimDepthCamera(
        world(ctx),
        settings.preset,
        T_true,
        parent=ctx.mount.parent,
        name=ctx.role,
        noise=settings.noise,
        decimation=settings.decimation,
        seed=ctx.seed + 1,
        frame_time=1.0 / settings.fps,
        color=settings.color,
        resolution=settings.resolution,
    )
    if settings.stop_after is not None:
        _stop_after(cam, settings.stop_after)
    return cam


def _stop_after(cam: d.SimDepthCamera, n: int) -> None:
    original = cam._capture
    count = {"n": 0}

    def capture(timeout: float):
        count["n"] += 1
        if count["n"] > n:
            cam.delivering = False
        return original(timeout)

    cam._capture = capture


def gesture(settings, ctx) -> d.SimGestureSensor:
    return d.SimGestureSensor(
        world(ctx),
        load_script(settings.script),
        rate=settings.rate,
        name=ctx.role,
        seed=ctx.seed + 2,
        disconnect_after=settings.disconnect_after,
    )


def displacement(settings, ctx) -> d.SimDisplacementSensor:
    from weldcell.hal.sim.laser_model import preset

    spec = preset(settings.model).with_overrides(
        min_range=settings.min_range,
        max_range=settings.max_range,
        accuracy=settings.noise,
        spot_diameter=settings.spot_diameter,
        coupling=settings.coupling,
        edge_dropout=settings.edge_dropout,
        rate=settings.rate,
    )
    return d.SimDisplacementSensor(
        world(ctx),
        ctx.T_parent_device,
        parent=ctx.mount.parent,
        name=ctx.role,
        spec=spec,
        seed=ctx.seed + 3,
        latency=settings.latency,
        stop_after=settings.stop_after,
    )


def projector(settings, ctx) -> d.SimProjector:
    from weldcell.hal.readings import Intrinsics

    s = settings if settings is not None else _projector_settings()
    cx = s.width / 2 if s.cx is None else s.cx
    cy = s.height / 2 if s.cy is None else s.cy
    T_true = ctx.T_parent_device
    if s.mount_error > 0 or s.mount_error_angle > 0:
        rng = np.random.default_rng(ctx.seed + 19)
        axis, direction = rng.normal(size=3), rng.normal(size=3)
        T_true = T_true @ T_from_rotvec(
            axis / np.linalg.norm(axis) * s.mount_error_angle,
            direction / np.linalg.norm(direction) * s.mount_error,
        )
    return d.SimProjector(
        world(ctx),
        T_true,
        parent=ctx.mount.parent,
        name=ctx.role,
        intrinsics=Intrinsics(s.width, s.height, s.fx, s.fy, cx, cy),
    )


def _projector_settings():
    from weldcell.plugins.sim.settings import SimProjectorSettings

    return SimProjectorSettings()


def imu(settings, ctx) -> d.SimImu:
    from weldcell.hal.sim.inertial import ImuModel

    fields = (
        "rate",
        "gyro_noise_density",
        "accel_noise_density",
        "gyro_random_walk",
        "accel_random_walk",
        "gyro_turn_on_bias",
        "accel_turn_on_bias",
        "hard_iron",
        "soft_iron",
        "steel_strength",
    )
    return d.SimImu(
        world(ctx),
        parent=ctx.mount.parent,
        T_parent_imu=ctx.T_parent_device,
        name=ctx.role,
        model=ImuModel(**{f: getattr(settings, f) for f in fields}),
        seed=ctx.seed + 4,
        stop_after=settings.stop_after,
    )


def gnss(settings, ctx) -> d.SimGnss:
    from weldcell.hal.sim.gnss_model import GnssModel

    return d.SimGnss(
        world(ctx),
        parent=ctx.mount.parent,
        name=ctx.role,
        origin=(settings.latitude, settings.longitude, settings.altitude),
        model=GnssModel(
            rate=settings.rate,
            mode=settings.mode,
            sigma_h=settings.sigma,
            rtk_sigma_h=settings.rtk_sigma,
            rtk_sigma_v=2 * settings.rtk_sigma,
        ),
        seed=ctx.seed + 5,
        T_parent_antenna=ctx.T_parent_device,
    )


def probe(settings) -> str:
    return "simulated (always reachable)"


def check_sim_section(loaded) -> list[tuple[tuple[str, ...], str]]:
    """Workpiece kinds and parameter names of the [sim] section (cheap: nothing is built)."""
    from weldcell.hal.sim.world import scene_parameters

    problems = []
    uses_sim = any(e.plugin.endswith(".sim") for e in loaded.profile.devices.values())
    for i, w in enumerate(loaded.profile.sim.workpieces):
        key = ("sim", "workpieces", str(i))
        try:
            valid = scene_parameters(w.kind)
        except DataError as e:
            problems.append(((*key, "kind"), f"{e.message}; {e.fix}"))
            continue
        for name in w.params:
            if name not in valid:
                problems.append(
                    (
                        (*key, "params", name),
                        f"'{w.kind}' has no parameter '{name}'; its parameters are: {', '.join(valid)}",
                    )
                )
    if uses_sim and not loaded.profile.sim.workpieces and loaded.profile.job.name in ("scan-and-plan",):
        problems.append(
            (("sim", "workpieces"), "the simulated cell has no workpiece to scan; add [[sim.workpieces]]")
        )
    gesture = loaded.profile.devices.get("gesture")
    if gesture is not None and gesture.plugin == "gesture.sim":
        try:
            load_script(gesture.settings.get("script", "survey"))
        except DataError as e:
            problems.append((("devices", "gesture", "settings", "script"), f"{e.message}; {e.fix}"))
    return problems
