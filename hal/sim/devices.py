"""Simulated devices: the HAL interfaces implemented on the simulated world.

They obey the same lifecycle and safety gate as real adapters and pass the same conformance
suites; a profile selects them exactly like real devices (``robot.sim``, ``camera.sim``, ...). The site
sensors (IMU, GNSS) live in :mod:`weldcell.hal.sim.site_devices` and are re-exported here.
"""

from __future__ import annotations

import time

import numpy as np
from weldcell.hal.interfaces import DepthCamera, DisplacementSensor, GestureSensor, LaserProjector
from weldcell.hal.kinematics import RobotModel
from weldcell.hal.readings import DepthFrame, Displacement, GnssFix, HandsFrame, ImuReading, Intrinsics  # noqa: F401
from weldcell.hal.robot import Robot, RobotMotionSettings
from weldcell.hal.safety import SafetyGate, servo_flange_pose
from weldcell.hal.sim.flange import FlangeGeometry, flange_mesh, posed_mesh
from weldcell.hal.sim.hands import HandScript
from weldcell.hal.sim.laser_model import PRESETS, CouplingError, LaserModel, LaserSpec
from weldcell.hal.sim.site_devices import SimGnss, SimImu  # noqa: F401  (re-exported: the old import path)
from weldcell.hal.sim.trajectory import TimedTrajectory
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
        # timed flange segments: where the flange was at any past simulated time (streaming sensors)
        self.timed = TimedTrajectory(self.model.fk, lambda: self.model.fk(self.q + self.q_error))
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
        dt = self.model.linear_move_time(T0, T_base_flange, speed, accel)
        self.timed.add_linear(self.world.clock.t, dt, T0, self.model.fk(q), speed, accel)
        self.world.clock.advance(dt)
        self.q = np.asarray(q, dtype=float)
        self._record()

    def _move_joint(self, q: np.ndarray, speed: float, accel: float) -> None:
        self._check_link()
        dt = self.model.joint_move_time(self.q, q, speed_scale=min(1.0, speed))
        q_true = np.asarray(q, dtype=float) + self.q_error
        self.timed.add_joint(self.world.clock.t, dt, self.q + self.q_error, q_true)
        self.world.clock.advance(dt)
        self.q = np.asarray(q, dtype=float)
        self._record()

    def _follow_path(self, poses: np.ndarray, speed: float, accel: float, blend: float) -> None:
        for T in poses:
            self._move_linear(T, speed, accel)

    def _speed_linear(self, twist: np.ndarray, accel: float, duration: float) -> None:
        """Hold the flange twist for ``duration``: the flange origin moves on a line at ``v`` while the
        orientation turns at ``w`` (what a ``speedl``-style controller does, and what the safety gate
        checked, :func:`~weldcell.hal.safety.servo_flange_pose`). Resolved-rate steps every 2 ms
        (``dq = J^+ twist dt``), each corrected onto that exact motion, so the joints stay continuous."""
        self._check_link()
        twist = np.asarray(twist, dtype=float)
        T0 = self.model.fk(self.q)
        steps = max(1, int(np.ceil(duration / 0.002)))
        dt = duration / steps
        for k in range(1, steps + 1):
            J = self.model.jacobian(self.q)
            q = self.q + np.linalg.lstsq(J, twist, rcond=1e-6)[0] * dt
            self.q = self.model._polish(q, servo_flange_pose(T0, twist, k * dt), iters=3)  # noqa: SLF001
        self.world.clock.advance(duration)
        self._record()

    def _stop(self, decel: float) -> None:
        """Motions complete instantly in simulation; nothing is in flight to stop."""


class SimDepthCamera(DepthCamera):
    """A ray-cast depth camera with a real camera's resolution, range and noise (see camera presets)."""

    # parameters: the world, the preset and the mount, then one keyword per field of the camera.sim
    # device settings (plugins/sim/settings.py), each with its default
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
        color: bool = False,
        resolution: str | None = None,
    ) -> None:
        super().__init__(name, frame=name)
        self.world = world
        self.color = color
        if resolution is not None:  # a ZED's video mode (HD720, VGA, ...): hal.sim.camera_model.zed_mode
            from weldcell.hal.sim.camera_model import zed_mode

            preset = zed_mode(resolution, preset)
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

        if self.color:  # colour + registered depth (procedurally textured surfaces, see hal.sim.rgbd)
            from weldcell.hal.sim.rgbd import RgbdCamera

            self.camera = RgbdCamera(self.preset, self.world.meshes(), decimation=self.decimation)
        else:
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
        if self.color:
            t_capture, T_capture = self.world.clock.t, self.T_world_camera
            img, rgb = self.camera.render_rgbd(T_capture, rng=self.rng, noise=self.noise)
            self.world.clock.advance(self.frame_time)
            site = getattr(self.world, "site", None)
            return DepthFrame(
                stamp=(site.epoch + t_capture) if site is not None else time.time(),
                depth=img.depth,
                intrinsics=self._intrinsics(),
                frame=self.name,
                color=rgb,
                meta={
                    "sim_time": self.world.clock.t,
                    "capture_sim_time": t_capture,
                    "T_world_camera": T_capture,
                },
            )
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
    """A 1-D laser triangulation sensor (optoNCDT 1402 class, :mod:`weldcell.hal.sim.laser_model`).

    ``read()`` gives one reading now. The stream (:mod:`weldcell.hal.stream`) samples on a grid of the
    sensor's ``rate`` along the carrying robot's timed trajectory (:mod:`weldcell.hal.sim.trajectory`),
    stamped on the simulated clock ``latency`` seconds late (the sensor's output delay, which
    acquisition must estimate). When mounted on a robot flange the sensor's true pose carries the
    robot-sensor coupling error.
    """

    stream_rate_hz = 200.0  # how often the reader thread looks at the simulated clock (wall time)

    def __init__(
        self,
        world: SimWorld,
        T_parent_sensor: np.ndarray,
        parent: str = "world",
        name: str = "laser",
        spec: LaserSpec | None = None,
        seed: int = 0,
        latency: float = 0.0,
        stop_after: float | None = None,
    ) -> None:
        super().__init__(name, frame=name)
        self.world = world
        self.T_parent_sensor = np.asarray(T_parent_sensor, dtype=float)
        self.parent = parent
        self.spec = spec or PRESETS["ild1402-200"]
        self.min_range, self.max_range = self.spec.min_range, self.spec.max_range
        self.seed = seed
        self.latency = float(latency)
        self.stop_after = stop_after
        self.model: LaserModel | None = None
        self._scene_key: tuple = ()
        robot = parent.split(".")[0] if parent.endswith(".flange") else None
        self.robot_role = robot
        self.coupling = CouplingError(self.spec.coupling if robot else 0.0, seed + 101)
        self._next_k: int | None = None
        self.connected = True

    def on_configure(self) -> None:
        self._scene()

    def on_recover(self) -> None:
        self.connected = True
        self.stop_after = None

    def _scene(self) -> LaserModel:
        """The ray-casting scene, rebuilt when the world's workpieces change (a part was placed)."""
        key = tuple(id(w) for w in self.world.workpieces)
        if self.model is None or key != self._scene_key:
            self.model = LaserModel(self.spec, self.world.meshes(), seed=self.seed)
            self._scene_key = key
        return self.model

    def poses_at(self, t: np.ndarray) -> np.ndarray:
        """True sensor poses ``T_world_sensor`` (N, 4, 4) at simulated times ``t`` (coupling included)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        robot = self.world.robots.get(self.robot_role) if self.robot_role else None
        if robot is not None:
            T = robot.T_world_base @ robot.timed.poses(t) @ self.T_parent_sensor
        else:
            T = np.tile(self.world.T_world(self.parent) @ self.T_parent_sensor, (len(t), 1, 1))
        T[:, :3, 3] += self.coupling(t)
        return T

    def _read(self, timeout: float) -> Displacement:
        if self.stop_after is not None and self.world.clock.t > self.stop_after:
            self.connected = False
        if not self.connected:
            raise self.fault("simulated sensor stopped answering (cable pulled?)")
        t = self.world.clock.t
        d = float(self._scene().measure(self.poses_at(np.array([t])))[0])
        return Displacement(t + self.latency, d if np.isfinite(d) else None, self.name)

    # -- streaming (the buffered reader of weldcell.hal.stream calls _read_burst) --------------------
    def start_stream(self, capacity: int = 65536) -> None:
        """Start sampling now (simulated clock), then the buffered reader."""
        self.require_active()
        if not self.streaming:
            self._next_k = int(np.ceil(self.world.clock.t * self.spec.rate - 1e-9))
        super().start_stream(capacity)

    def _read_burst(self, timeout: float) -> list[Displacement]:
        """Every sample on the ``rate`` grid since the last call, up to the simulated clock now.

        A sensor carried by a robot samples along the robot's timed trajectory and waits for simulated
        time to pass (the robot's motions); a fixed sensor lets simulated time run at its own rate.
        """
        if not self.connected:
            raise self.fault("simulated sensor stopped answering (cable pulled?)")
        rate = self.spec.rate
        if self._next_k is None:
            self._next_k = int(np.ceil(self.world.clock.t * rate - 1e-9))
        end = self.world.clock.t
        if self.robot_role is None and end < (self._next_k + 1) / rate:
            end = self.world.clock.advance((self._next_k + 1) / rate - end)
        if self.stop_after is not None and end > self.stop_after:
            end = self.stop_after
            self.connected = False  # what was measured until the cable was pulled is still delivered
        k = np.arange(self._next_k, int(np.floor(end * rate + 1e-9)) + 1)
        if len(k) == 0:
            return []
        self._next_k = int(k[-1]) + 1
        t = k / rate
        d = self._scene().measure(self.poses_at(t), index=k)
        return [
            Displacement(float(a), float(b) if np.isfinite(b) else None, self.name)
            for a, b in zip(t + self.latency, d, strict=True)
        ]

    def stop_stream(self) -> list:
        out = super().stop_stream()
        self._next_k = None
        return out


class SimProjector(LaserProjector):
    """A video laser projector (ShowWX+ class) as a pinhole "inverse camera" on a world frame.

    ``project(segments)`` renders the world segments into the projector's image with the model the
    cell *believes* (``calibration``: intrinsics K and the mount, as calibrated; default the true ones)
    and then ray-casts the lit pixels with the *true* intrinsics and mount onto the scene: ``lit`` holds
    where the light really lands (what the worker sees). ``project_pixels`` lights given pixels (a dot
    pattern for the calibration) and returns where they land. ``drawn`` keeps what was asked.
    """

    def __init__(
        self,
        world: SimWorld | None = None,
        T_parent_projector: np.ndarray | None = None,
        parent: str = "world",
        name: str = "projector",
        intrinsics: Intrinsics | None = None,
        step: float = 0.002,
    ) -> None:
        super().__init__(name, frame="world")
        self.world = world
        self.T_parent_projector = np.eye(4) if T_parent_projector is None else np.asarray(T_parent_projector)
        self.parent = parent
        self.intrinsics = intrinsics or Intrinsics(848, 480, 1000.0, 1000.0, 424.0, 240.0)
        self.calibration: tuple[np.ndarray, np.ndarray] | None = None  # (K, T_parent_projector) believed
        self.step = step
        self.drawn: list[tuple[str, np.ndarray]] = []
        self.lit: np.ndarray = np.zeros((0, 3))
        self.image_points: np.ndarray = np.zeros((0, 2))
        self._scene = None

    @property
    def T_world_projector(self) -> np.ndarray:
        base = self.world.T_world(self.parent) if self.world is not None else np.eye(4)
        return base @ self.T_parent_projector

    def _believed(self) -> tuple[np.ndarray, np.ndarray]:
        if self.calibration is not None:
            K, T_pp = self.calibration
        else:
            K, T_pp = self.intrinsics.K, self.T_parent_projector
        base = self.world.T_world(self.parent) if self.world is not None else np.eye(4)
        return np.asarray(K), base @ np.asarray(T_pp)

    def render(self, segments: np.ndarray) -> np.ndarray:
        """Pixels (M, 2) the believed model lights for world segments (N, 2, 3), sampled every ``step`` m;
        points behind the projector or outside the image are dropped."""
        K, T_wp = self._believed()
        pts = []
        for a, b in np.asarray(segments, dtype=float):
            n = max(2, int(np.ceil(np.linalg.norm(b - a) / self.step)) + 1)
            pts.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
        P = transform_points(invert(T_wp), np.vstack(pts)) if pts else np.zeros((0, 3))
        P = P[P[:, 2] > 1e-6]
        uv = (P[:, :2] / P[:, 2:3]) @ K[:2, :2].T + K[:2, 2]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < self.intrinsics.width) & (uv[:, 1] >= 0)
        return uv[inside & (uv[:, 1] < self.intrinsics.height)]

    def project_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Light pixels ``uv`` (M, 2): where each lands in the world (M, 3), NaN where it hits nothing."""
        import open3d as o3d

        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        K = self.intrinsics.K
        d = np.column_stack([(uv - K[:2, 2]) / np.diag(K)[:2], np.ones(len(uv))])
        T = self.T_world_projector
        dirs = d @ T[:3, :3].T
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        key = tuple(id(w) for w in self.world.workpieces)
        if self._scene is None or self._scene[0] != key:  # rebuilt when a part was placed
            scene = o3d.t.geometry.RaycastingScene()
            for m in self.world.meshes():
                scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(m))
            self._scene = (key, scene)
        scene = self._scene[1]
        rays = np.column_stack([np.tile(T[:3, 3], (len(uv), 1)), dirs]).astype(np.float32)
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(float)
        return np.where(np.isfinite(t)[:, None], T[:3, 3] + t[:, None] * dirs, np.nan)

    def _project(self, segments: np.ndarray, label: str) -> None:
        self.drawn = [(label, segments.copy())]
        if self.world is not None:
            self.image_points = self.render(segments)
            self.lit = self.project_pixels(self.image_points) if len(self.image_points) else np.zeros((0, 3))

    def _clear(self) -> None:
        self.drawn = []
        self.lit = np.zeros((0, 3))
        self.image_points = np.zeros((0, 2))


def T_world_to_base(world: SimWorld, robot_role: str) -> np.ndarray:
    """``T_base_world`` of a simulated robot (for ground truth in the robot base frame)."""
    return invert(world.T_world(f"{robot_role}.base"))
