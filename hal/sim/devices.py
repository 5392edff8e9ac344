"""Simulated devices: the HAL interfaces implemented on the simulated world.

They obey the same lifecycle and safety gate as real adapters and pass the same conformance
suites; a profile selects them exactly like real devices (``robot.sim``, ``camera.sim``, ...).
"""

from __future__ import annotations

import time

import numpy as np
from weldcell.hal.interfaces import DepthCamera, DisplacementSensor, GestureSensor, Gnss, Imu, LaserProjector
from weldcell.hal.readings import DepthFrame, Displacement, GnssFix, HandsFrame, ImuReading, Intrinsics  # noqa: F401
from weldcell.hal.robot import Robot, RobotMotionSettings
from weldcell.hal.safety import SafetyGate
from weldcell.hal.sim.flange import FlangeGeometry, flange_mesh, posed_mesh
from weldcell.hal.sim.hands import HandScript
from weldcell.hal.sim.kinematics import RobotModel
from weldcell.hal.sim.world import SimWorld
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.geometry import invert, transform_points


class SimRobot(Robot):
    """A kinematic robot: commands move its joints instantly, simulated time advances by the motion time."""

    def __init__(
        self,
        model: RobotModel,
        world: SimWorld,
        T_world_base: np.ndarray | None = None,
        name: str = "robot",
        gate: SafetyGate | None = None,
        motion: RobotMotionSettings | None = None,
        dry_run: bool = False,
        q_start: np.ndarray | None = None,
        flange: FlangeGeometry | None = None,
        q_error: np.ndarray | None = None,
    ) -> None:
        super().__init__(name, gate or SafetyGate(model=model), motion, dry_run)
        self.model = model
        # the real arm's joint zero offsets: it reports fk(q) but physically stands at fk(q + q_error)
        self.q_error = np.zeros(model.dof) if q_error is None else np.asarray(q_error, dtype=float)
        self.world = world
        self.T_world_base = np.eye(4) if T_world_base is None else np.asarray(T_world_base, dtype=float)
        self.q = np.array(model.home if q_start is None else q_start, dtype=float)
        self.trajectory: list[tuple[float, np.ndarray]] = []
        self.connected = True
        world.add_frame(f"{name}.base", lambda: self.T_world_base)
        world.add_frame(f"{name}.flange", lambda: self.T_world_base @ self.model.fk(self.q + self.q_error))
        world.robots[name] = self
        if flange is not None:  # the flange plate and last link, seen by the depth cameras
            world.attach(f"{name}.flange-geometry", f"{name}.flange", *flange_mesh(flange))

    def on_configure(self) -> None:
        self._check_link()
        self.model.check_limits(self.q)

    def on_recover(self) -> None:
        self.connected = True

    def _check_link(self) -> None:
        if not self.connected:
            raise self.fault("simulated controller connection lost")

    def _read_state(self):
        self._check_link()
        return self.q.copy(), self.model.fk(self.q), {"moving": False}

    def _record(self) -> None:
        self.trajectory.append((self.world.clock.t, self.q.copy()))

    def _move_linear(self, T_base_flange: np.ndarray, speed: float, accel: float) -> None:
        self._check_link()
        T0 = self.model.fk(self.q)
        # the safety gate has already checked the whole line for reach, limits and continuity
        q = self.model.ik(T_base_flange, self.q)
        self.world.clock.advance(self.model.linear_move_time(T0, T_base_flange, speed, accel))
        self.q = np.asarray(q, dtype=float)
        self._record()

    def _move_joint(self, q: np.ndarray, speed: float, accel: float) -> None:
        self._check_link()
        self.world.clock.advance(self.model.joint_move_time(self.q, q, speed_scale=min(1.0, speed)))
        self.q = np.asarray(q, dtype=float)
        self._record()

    def _follow_path(self, poses: np.ndarray, speed: float, accel: float, blend: float) -> None:
        for T in poses:
            self._move_linear(T, speed, accel)

    def _speed_linear(self, twist: np.ndarray, accel: float, duration: float) -> None:
        """Integrate the flange twist for ``duration`` with the Jacobian (resolved-rate control)."""
        self._check_link()
        steps = max(1, int(np.ceil(duration / 0.002)))
        dt = duration / steps
        for _ in range(steps):
            J = self.model.jacobian(self.q)
            dq = np.linalg.lstsq(J, twist, rcond=1e-6)[0]
            self.q = self.q + dq * dt
        self.world.clock.advance(duration)
        self._record()

    def _stop(self, decel: float) -> None:
        """Motions complete instantly in simulation; nothing is in flight to stop."""


class SimDepthCamera(DepthCamera):
    """A ray-cast depth camera with a real camera's resolution, range and noise (see camera presets)."""

    def __init__(
        self,
        world: SimWorld,
        preset: str,
        T_parent_camera: np.ndarray,
        parent: str = "world",
        name: str = "camera",
        noise: bool = True,
        decimation: int = 1,
        seed: int = 0,
        frame_time: float = 1 / 30,
    ) -> None:
        super().__init__(name, frame=name)
        self.world = world
        self.preset = preset
        self.parent = parent
        self.T_parent_camera = np.asarray(T_parent_camera, dtype=float)
        self.noise = noise
        self.decimation = decimation
        self.rng = np.random.default_rng(seed)
        self.frame_time = frame_time
        self.camera = None
        self.delivering = True
        self._attached: dict[str, tuple[int, np.ndarray]] = {}

    def on_configure(self) -> None:
        from weldcell.hal.sim.camera_model import RaycastCamera

        self.camera = RaycastCamera(self.preset, self.world.meshes(), decimation=self.decimation)
        self._attached = {}

    def _pose_attached(self) -> None:
        """Add, re-pose or remove the world's attached meshes (robot flanges) in the ray-cast scene."""
        for name, att in self.world.attachments.items():
            T = self.world.T_world(att.frame)
            known = self._attached.get(name)
            if known is None:
                self._attached[name] = (self.camera.add(posed_mesh(att.vertices, att.triangles, T)), T)
            elif not np.array_equal(known[1], T):
                self.camera.replace(known[0], posed_mesh(att.vertices, att.triangles, T))
                self._attached[name] = (known[0], T)
        for name in [n for n in self._attached if n not in self.world.attachments]:
            self.camera.remove(self._attached.pop(name)[0])

    def on_recover(self) -> None:
        self.delivering = True
        self.camera = None

    @property
    def T_world_camera(self) -> np.ndarray:
        return self.world.T_world(self.parent) @ self.T_parent_camera

    def _intrinsics(self) -> Intrinsics:
        if self.camera is None:
            raise DeviceError(f"camera '{self.name}' is not configured", "configure() it first")
        return self.camera.intrinsics

    def _capture(self, timeout: float) -> DepthFrame:
        if not self.delivering:
            raise self.fault(f"no frame within {timeout:.1f} s")
        self._pose_attached()
        img = self.camera.render(self.T_world_camera, rng=self.rng, noise=self.noise)
        self.world.clock.advance(self.frame_time)
        return DepthFrame(
            stamp=time.time(),
            depth=img.depth,
            intrinsics=self._intrinsics(),
            frame=self.name,
            meta={"sim_time": self.world.clock.t, "T_world_camera": self.T_world_camera},
        )


class SimGestureSensor(GestureSensor):
    """A Leap-like hand tracker playing a scripted hand motion (see :mod:`weldcell.hal.sim.hands`)."""

    def __init__(
        self,
        world: SimWorld,
        script: list[dict],
        rate: float = 60.0,
        name: str = "gesture",
        seed: int = 0,
        disconnect_after: int | None = None,
    ) -> None:
        super().__init__(name, frame=name)
        self.world = world
        self.steps = script
        self.rate = rate
        self.seed = seed
        self.player = HandScript(script, rate=rate, seed=seed)
        self.disconnect_after = disconnect_after
        self.connected = True
        self._t0: float | None = None

    def on_configure(self) -> None:
        if not self.connected:
            raise DeviceError("simulated gesture service is not reachable", "recover() reconnects")

    def on_recover(self) -> None:
        self.connected = True
        self.disconnect_after = None

    @property
    def finished(self) -> bool:
        return self.player.finished

    def _read(self, timeout: float) -> HandsFrame:
        if self.disconnect_after is not None and self.player.index >= self.disconnect_after:
            self.connected = False
        if not self.connected:
            raise self.fault("simulated gesture service disconnected")
        self.world.clock.advance(1.0 / self.rate)
        # stamps follow the script's own timeline (frames exactly 1/rate apart), anchored at the start
        if self._t0 is None:
            self._t0 = time.time()
        return self.player.next_frame(self._t0 + self.player.index / self.rate)


class SimDisplacementSensor(DisplacementSensor):
    """A 1-D laser displacement sensor ray-cast against the world (range and noise from settings)."""

    def __init__(
        self,
        world: SimWorld,
        T_parent_sensor: np.ndarray,
        parent: str = "world",
        name: str = "laser",
        min_range: float = 0.03,
        max_range: float = 0.3,
        noise: float = 2e-6,
        seed: int = 0,
    ) -> None:
        super().__init__(name, frame=name)
        self.world = world
        self.T_parent_sensor = np.asarray(T_parent_sensor, dtype=float)
        self.parent = parent
        self.min_range, self.max_range, self.noise = min_range, max_range, noise
        self.rng = np.random.default_rng(seed)
        self.scene = None

    def on_configure(self) -> None:
        import open3d as o3d

        self.scene = o3d.t.geometry.RaycastingScene()
        for m in self.world.meshes():
            self.scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))

    def _read(self, timeout: float) -> Displacement:
        import open3d as o3d

        T = self.world.T_world(self.parent) @ self.T_parent_sensor
        ray = np.concatenate([T[:3, 3], T[:3, 2]]).astype(np.float32)[None]
        t_hit = float(self.scene.cast_rays(o3d.core.Tensor(ray))["t_hit"].numpy()[0])
        if not np.isfinite(t_hit) or not (self.min_range <= t_hit <= self.max_range):
            return Displacement(time.time(), None, self.name)
        return Displacement(time.time(), t_hit + float(self.rng.normal(0.0, self.noise)), self.name)


class SimProjector(LaserProjector):
    """A projector that records what it was asked to draw (the picture is rendered in reports)."""

    def __init__(self, name: str = "projector") -> None:
        super().__init__(name, frame="world")
        self.drawn: list[tuple[str, np.ndarray]] = []

    def _project(self, segments: np.ndarray, label: str) -> None:
        self.drawn = [(label, segments.copy())]

    def _clear(self) -> None:
        self.drawn = []


class SimImu(Imu):
    """An IMU rigidly attached to a world frame: gravity, rotation rate from frame differences, noise."""

    def __init__(
        self,
        world: SimWorld,
        parent: str = "world",
        T_parent_imu: np.ndarray | None = None,
        name: str = "imu",
        accel_noise: float = 0.02,
        gyro_noise: float = 0.002,
        seed: int = 0,
    ) -> None:
        super().__init__(name, frame=name)
        self.world = world
        self.parent = parent
        self.T_parent_imu = np.eye(4) if T_parent_imu is None else T_parent_imu
        self.accel_noise, self.gyro_noise = accel_noise, gyro_noise
        self.rng = np.random.default_rng(seed)
        self._last: tuple[float, np.ndarray] | None = None

    def _read(self, timeout: float) -> ImuReading:
        from scipy.spatial.transform import Rotation

        T = self.world.T_world(self.parent) @ self.T_parent_imu
        t = self.world.clock.advance(0.005)
        gyro = np.zeros(3)
        if self._last is not None and t > self._last[0]:
            dR = self._last[1][:3, :3].T @ T[:3, :3]
            gyro = Rotation.from_matrix(dR).as_rotvec() / (t - self._last[0])
        self._last = (t, T)
        accel = T[:3, :3].T @ np.array([0.0, 0.0, 9.80665])
        return ImuReading(
            time.time(),
            accel + self.rng.normal(0, self.accel_noise, 3),
            gyro + self.rng.normal(0, self.gyro_noise, 3),
            mag=T[:3, :3].T @ np.array([0.0, 22.0, -42.0]),
            orientation=Rotation.from_matrix(T[:3, :3]).as_quat(),
            frame=self.name,
        )


class SimGnss(Gnss):
    """A GNSS receiver at a frame of the world; the world origin is at ``origin`` (lat, lon, alt)."""

    def __init__(
        self,
        world: SimWorld,
        parent: str = "world",
        name: str = "gnss",
        origin: tuple[float, float, float] = (22.5966, 113.9976, 30.0),
        sigma: float = 0.02,
        seed: int = 0,
    ) -> None:
        super().__init__(name, frame="enu")
        self.world = world
        self.parent = parent
        self.origin = origin
        self.sigma = sigma
        self.rng = np.random.default_rng(seed)

    def _read(self, timeout: float) -> GnssFix:
        p = transform_points(self.world.T_world(self.parent), np.zeros((1, 3)))[0]
        enu = p + self.rng.normal(0.0, self.sigma, 3)
        lat0, lon0, alt0 = self.origin
        r = 6378137.0
        lat = lat0 + np.degrees(enu[1] / r)
        lon = lon0 + np.degrees(enu[0] / (r * np.cos(np.radians(lat0))))
        return GnssFix(
            time.time(),
            float(lat),
            float(lon),
            float(alt0 + enu[2]),
            enu=enu,
            covariance=np.eye(3) * self.sigma**2,
        )


def T_world_to_base(world: SimWorld, robot_role: str) -> np.ndarray:
    """``T_base_world`` of a simulated robot (for ground truth in the robot base frame)."""
    return invert(world.T_world(f"{robot_role}.base"))
