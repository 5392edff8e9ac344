"""``tactile.sim``: the in-finger camera of a simulated SRM tool on a simulated robot's flange.

Every capture reads the robot's current flange pose from the simulated world, places the SRM tool
(the device's mount on ``<robot>.flange``: its frame is the tool frame, origin = the tip's undeformed
centre ``P_r``, z toward the work, x the travel axis), computes the quasi-static contact of the soft tip
with the nearest side wall of the world's seams (:func:`~weldcell.plugins.tactile.srm_model.contact`,
friction from the tool's velocity between captures), moves the ArUco tag accordingly and renders the
camera frame (:mod:`~weldcell.plugins.tactile.render`). Jobs read these images through the same
detection and PnP code as a real camera's.

Walls: a seam of joint ``fillet`` or ``lap`` (settings ``joints``) has a vertical wall standing on it,
on the side its torch approach points to (the approach's horizontal part points into the joint, i.e. at
the wall). Images are stamped with the **simulated** clock (seconds since the run started), which the
simulated robot advances when it moves; a capture does not advance it.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field
from weldcell.hal.interfaces import TactileCamera
from weldcell.hal.readings import Image, Intrinsics
from weldcell.sdk.errors import DeviceError
from weldcell.sdk.geometry import invert, transform_points
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length

from .marker import CameraIntrinsics
from .render import InFingerCamera, _background
from .srm_model import ContactState, SRMParams, Workpiece, contact, tag_pose


class SimTactileSettings(Settings):
    """The simulated SRM finger (its mechanics) and its in-finger camera."""

    width: int = Field(640, ge=64, description="image width [px]")
    height: int = Field(480, ge=48, description="image height [px]")
    focal: float = Field(420.0, gt=0, description="focal length [px] (principal point at the image centre)")
    supersample: int = Field(2, ge=1, le=4, description="render super-sampling (1 = fastest)")
    blur_sigma: float = Field(0.7, ge=0, description="optical blur [px]")
    noise_std: float = Field(2.0, ge=0, description="sensor noise [grey levels]")
    marker_size: Length = Field(0.010, gt=0, description="side of the tag's black square [m]")
    marker_id: int = Field(0, ge=0, description="ArUco id of the tag")
    dictionary: str = Field("DICT_4X4_50", description="ArUco dictionary of the tag")
    tag_distance: Length = Field(0.025, gt=0, description="camera-to-tag distance at rest [m]")
    tip_radius: Length = Field(0.002, gt=0, description="radius of the spherical soft tip [m]")
    stiffness: tuple[float, float, float] = Field(
        (400.0, 400.0, 2000.0), description="finger stiffness along tool x, y, z [N/m]"
    )
    friction: float = Field(0.15, ge=0, description="Coulomb friction coefficient tip-wall")
    max_deflection: Length = Field(0.006, gt=0, description="deflection range of the finger [m]")
    tag_gain: float = Field(0.85, gt=0, description="tag translation per metre of lateral tip deflection")
    tag_axial_gain: float = Field(0.6, gt=0, description="tag translation per metre of axial tip deflection")
    tag_tilt_gain: float = Field(15.0, ge=0, description="tag tilt per metre of lateral deflection [rad/m]")
    wall_height: Length = Field(0.015, gt=0, description="height of the seams' side walls above the seam [m]")
    joints: tuple[str, ...] = Field(
        ("fillet", "lap"), description="seam joints that have a side wall to touch"
    )
    lose_marker_after: int | None = Field(
        None, ge=0, description="fault injection: the tag disappears from the image after this many captures"
    )

    def srm(self) -> SRMParams:
        return SRMParams(
            tip_radius=self.tip_radius,
            stiffness=tuple(self.stiffness),
            friction=self.friction,
            max_deflection=self.max_deflection,
            wall_height=self.wall_height,
            tag_gain=self.tag_gain,
            tag_axial_gain=self.tag_axial_gain,
            tag_tilt_gain=self.tag_tilt_gain,
        )


class SimTactileCamera(TactileCamera):
    """The simulated SRM tool's in-finger camera (see the module docstring)."""

    def __init__(
        self,
        world,
        robot_role: str,
        T_flange_tool: np.ndarray,
        settings: SimTactileSettings | None = None,
        name: str = "tactile",
        seed: int = 0,
    ) -> None:
        super().__init__(name, frame=name)
        self.world = world
        self.robot_role = robot_role
        self.T_flange_tool = np.asarray(T_flange_tool, dtype=float)
        self.s = settings or SimTactileSettings()
        self.params = self.s.srm()
        self.seed = seed
        self.connected = True
        self.captures = 0
        self.camera: InFingerCamera | None = None
        self.walls: list[tuple[str, Workpiece]] = []
        self.truth_log: list[dict] = []
        self._last: tuple[float, np.ndarray] | None = None
        self.last_contact: ContactState | None = None

    # -- lifecycle -------------------------------------------------------------------------------
    def on_configure(self) -> None:
        if not self.connected:
            raise DeviceError(
                f"simulated tactile camera '{self.name}' is not reachable", "recover() reconnects"
            )
        if self.robot_role not in self.world.robots:
            raise DeviceError(
                f"tactile camera '{self.name}' is mounted on '{self.robot_role}.flange', but the simulated "
                f"cell has no robot '{self.robot_role}'",
                f"add [devices.{self.robot_role}] (robot.sim) before [devices.{self.name}]",
            )
        K = np.array(
            [
                [self.s.focal, 0.0, (self.s.width - 1) / 2.0],
                [0.0, self.s.focal, (self.s.height - 1) / 2.0],
                [0.0, 0.0, 1.0],
            ]
        )
        self.camera = InFingerCamera(
            CameraIntrinsics(K, np.zeros(5), self.s.width, self.s.height),
            marker_size=self.s.marker_size,
            marker_id=self.s.marker_id,
            dictionary=self.s.dictionary,
            tag_distance=self.s.tag_distance,
            blur_sigma=self.s.blur_sigma,
            noise_std=self.s.noise_std,
            supersample=self.s.supersample,
            seed=self.seed,
        )
        self.walls = []
        for name, seam in self.world.seams_in_world():
            if seam.joint not in self.s.joints:
                continue
            normals = -np.asarray(seam.approach, dtype=float).copy()
            normals[:, 2] = 0.0
            if np.any(np.linalg.norm(normals, axis=1) < 1e-6):
                continue  # an approach straight down: no side wall
            self.walls.append(
                (f"{name}/{seam.id}", Workpiece(seam.points, normals, wall_height=self.s.wall_height))
            )
        self._last = None

    def on_recover(self) -> None:
        self.connected = True

    # -- frames ----------------------------------------------------------------------------------
    @property
    def intrinsics(self) -> Intrinsics:
        return Intrinsics(
            self.s.width,
            self.s.height,
            self.s.focal,
            self.s.focal,
            (self.s.width - 1) / 2.0,
            (self.s.height - 1) / 2.0,
        )

    @property
    def T_world_tool(self) -> np.ndarray:
        return self.world.T_world(f"{self.robot_role}.flange") @ self.T_flange_tool

    def _nearest_wall(self, p: np.ndarray) -> int | None:
        if not self.walls:
            return None
        d = [float(w.seam.distances(p[None])[0]) for _, w in self.walls]
        return int(np.argmin(d))

    def _capture(self, timeout: float) -> Image:
        if not self.connected:
            raise self.fault("simulated in-finger camera disconnected")
        t = self.world.clock.t
        T = self.T_world_tool
        v = np.zeros(3)
        if self._last is not None and t > self._last[0] + 1e-9:
            v = (T[:3, 3] - self._last[1]) / (t - self._last[0])
        self._last = (t, T[:3, 3].copy())
        k = self._nearest_wall(T[:3, 3])
        if k is None:  # no wall anywhere in the cell: the finger is free
            nan = np.full(3, np.nan)
            c = ContactState(False, 0.0, np.zeros(3), T[:3, 3].copy(), nan, nan, 0.0, False, False, 0.0)
        else:
            c = contact(T, self.walls[k][1], self.params, v)
        self.last_contact = c
        self.captures += 1
        self.truth_log.append(
            {
                "t": t,
                "tip": c.tip_position.copy(),
                "tcp": T[:3, 3].copy(),
                "in_contact": c.in_contact,
                "wall": k,
                "deflection_tool": c.deflection_tool.copy(),
            }
        )
        cam = self.camera
        if self.s.lose_marker_after is not None and self.captures > self.s.lose_marker_after:
            img = _background(self.s.height, self.s.width, 85.0) + cam._rng.normal(
                0, self.s.noise_std, (self.s.height, self.s.width)
            )
            img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        else:
            img = cam.render(tag_pose(c.deflection_tool, self.params, cam.T_cam_tag_rest))
        return Image(stamp=t, image=img, intrinsics=self.intrinsics, frame=self.name)

    # -- ground truth (simulation only) ------------------------------------------------------------
    def truth(self) -> dict:
        """Ground truth in the robot base frame: the wall touched most, the tip centres of every capture."""
        T_base_world = invert(self.world.T_world(f"{self.robot_role}.base"))
        log = self.truth_log
        walls = [e["wall"] for e in log if e["in_contact"] and e["wall"] is not None]
        k = max(set(walls), key=walls.count) if walls else self._nearest_wall(self.T_world_tool[:3, 3])
        out: dict = {"T_base_world": T_base_world, "wall": None, "seam": None, "wall_normals": None}
        if k is not None:
            name, wp = self.walls[k]
            out.update(
                wall=name,
                seam=transform_points(T_base_world, wp.seam.points),
                wall_normals=wp.vertex_normals @ T_base_world[:3, :3].T,
            )
        if log:
            out["t"] = np.array([e["t"] for e in log])
            out["tip"] = transform_points(T_base_world, np.array([e["tip"] for e in log]))
            out["in_contact"] = np.array([e["in_contact"] for e in log])
        return out


def factory(settings: SimTactileSettings, ctx) -> SimTactileCamera:
    """Build from the profile: the mount must be ``<robot role>.flange`` (the tool frame's offset)."""
    from weldcell.hal.sim.world import shared_world

    parent = ctx.mount.parent
    if not parent.endswith(".flange"):
        raise DeviceError(
            f"tactile.sim '{ctx.role}' is mounted on '{parent}'; the SRM tool sits on a robot's flange",
            'set mount = { parent = "robot.flange", xyz = [0, 0, <tip offset>] }',
        )
    return SimTactileCamera(
        shared_world(ctx),
        parent[: -len(".flange")],
        ctx.T_parent_device,
        settings,
        name=ctx.role,
        seed=ctx.seed + 29,
    )
