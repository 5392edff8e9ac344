"""A fake ``franky.Robot`` (franky-control 2.x) driving a kinematic Panda, for the Franka adapter tests.

Only the robot connection is faked: motions, poses, twists, joint states, dynamics factors, modes and
exceptions are franky's own classes, so the adapter is exercised against franky's real value API.
Signatures mirror
``franky._franky._RobotInternal`` (checked in the tests against the pybind11 docstrings):
``Robot(fci_hostname,
relative_dynamics_factor=1.0, default_torque_threshold=20.0, default_force_threshold=30.0, ...)``,
``move(motion, asynchronous=False, limit_rate=False, cutoff_frequency=100.0)``, ``join_motion(timeout=None)``,
``poll_motion()``, ``stop()``, ``recover_from_errors()``, properties ``state`` (``q``, ``dq``, ``O_T_EE``,
``F_T_EE``, ``F_T_NE``, ``NE_T_EE``, ``robot_mode``, ``current_errors``), ``current_joint_state``,
``current_cartesian_state``, ``has_errors``, ``relative_dynamics_factor``, ``fci_hostname``.
Motions complete instantly (the kinematic model jumps to the target); velocity motions are integrated over
their ``duration``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import franky
import numpy as np
from weldcell.hal.kinematics import get_model
from weldcell.sdk.geometry import T_from_rotvec, invert

#: Franka hand as NE (Desk default when the gripper is configured): 45 deg about z, 0.1034 m along z
F_T_NE_HAND = np.array(
    [[0.7071068, 0.7071068, 0, 0], [-0.7071068, 0.7071068, 0, 0], [0, 0, 1, 0.1034], [0, 0, 0, 1.0]]
)


@dataclass
class _State:
    q: np.ndarray
    dq: np.ndarray
    O_T_EE: franky.Affine
    F_T_EE: franky.Affine
    F_T_NE: franky.Affine
    NE_T_EE: franky.Affine
    robot_mode: franky.RobotMode
    current_errors: str
    last_motion_errors: str


@dataclass
class FrankaWorld:
    """The simulated arm shared by every fake connection (so recovery/reconnect see the same robot)."""

    model_name: str = "franka-panda"
    F_T_NE: np.ndarray = field(default_factory=lambda: F_T_NE_HAND.copy())
    NE_T_EE: np.ndarray = field(default_factory=lambda: np.eye(4))
    q: np.ndarray | None = None
    mode: franky.RobotMode = franky.RobotMode.Idle
    errors: str = ""
    reachable: bool = True
    fail_recovery: bool = False
    motions: list = field(default_factory=list)
    connections: list = field(default_factory=list)
    recover_calls: int = 0

    def __post_init__(self) -> None:
        self.model = get_model(self.model_name)
        if self.q is None:
            self.q = self.model.home.copy()

    def robot(
        self,
        fci_hostname: str,
        relative_dynamics_factor=1.0,
        default_torque_threshold: float = 20.0,
        default_force_threshold: float = 30.0,
        **kwargs,
    ) -> FakeFrankyRobot:
        return FakeFrankyRobot(
            fci_hostname,
            relative_dynamics_factor,
            default_torque_threshold,
            default_force_threshold,
            world=self,
            **kwargs,
        )

    def reflex(self, what: str = "cartesian_reflex") -> None:
        """What the control unit does on a collision: abort, enter Reflex, keep the error until recovery."""
        self.mode = franky.RobotMode.Reflex
        self.errors = what

    @property
    def F_T_EE(self) -> np.ndarray:
        return self.F_T_NE @ self.NE_T_EE

    def flange(self) -> np.ndarray:
        return self.model.fk(self.q)


class FakeFrankyRobot:
    control_rate = 0.001
    degrees_of_freedom = 7

    def __init__(
        self,
        fci_hostname: str,
        relative_dynamics_factor=1.0,
        default_torque_threshold: float = 20.0,
        default_force_threshold: float = 30.0,
        *,
        world: FrankaWorld,
        **kwargs,
    ) -> None:
        if not world.reachable:
            raise franky.NetworkException("libfranka: Connection to FCI refused.")
        self._w = world
        self._fci = fci_hostname
        self._rdf = relative_dynamics_factor
        self.thresholds = (default_torque_threshold, default_force_threshold)
        world.connections.append(self)
        self.closed = False

    # -- properties as in franky --------------------------------------------------------------------
    @property
    def fci_hostname(self) -> str:
        return self._fci

    @property
    def relative_dynamics_factor(self):
        return self._rdf

    @relative_dynamics_factor.setter
    def relative_dynamics_factor(self, v) -> None:
        self._rdf = v

    def _check_link(self) -> None:
        if not self._w.reachable:
            raise franky.NetworkException("libfranka: UDP receive: Timeout")

    @property
    def state(self) -> _State:
        self._check_link()
        w = self._w
        return _State(
            q=w.q.copy(),
            dq=np.zeros(7),
            O_T_EE=franky.Affine(w.flange() @ w.F_T_EE),
            F_T_EE=franky.Affine(w.F_T_EE),
            F_T_NE=franky.Affine(w.F_T_NE),
            NE_T_EE=franky.Affine(w.NE_T_EE),
            robot_mode=w.mode,
            current_errors=w.errors,
            last_motion_errors=w.errors,
        )

    @property
    def current_joint_state(self) -> franky.JointState:
        return franky.JointState(self.state.q)

    @property
    def current_cartesian_state(self) -> franky.CartesianState:
        return franky.CartesianState(self.state.O_T_EE)

    @property
    def has_errors(self) -> bool:
        return bool(self._w.errors)

    # -- commands ---------------------------------------------------------------------------------
    def move(
        self, motion, asynchronous: bool = False, limit_rate: bool = False, cutoff_frequency: float = 100.0
    ) -> None:
        self._check_link()
        w = self._w
        if w.mode == franky.RobotMode.Reflex:
            raise franky.ControlException(f"libfranka: Move command rejected: robot in reflex ({w.errors})")
        w.motions.append(motion)
        EE_T_F = invert(w.F_T_EE)
        if isinstance(motion, franky.JointMotion):
            w.q = np.asarray(motion.target.position, dtype=float).copy()
        elif isinstance(motion, franky.CartesianVelocityMotion):
            tw = motion.target.end_effector_twist
            dt = motion.duration.to_sec()
            T_ee = w.flange() @ w.F_T_EE
            T_ee_new = T_from_rotvec(np.asarray(tw.angular) * dt) @ np.eye(4)
            R = T_ee_new[:3, :3] @ T_ee[:3, :3]
            T_new = np.eye(4)
            T_new[:3, :3] = R
            T_new[:3, 3] = T_ee[:3, 3] + np.asarray(tw.linear) * dt
            w.q = w.model.ik(T_new @ EE_T_F, w.q)
        elif isinstance(motion, franky.CartesianWaypointMotion):
            for wp in motion.waypoints:
                target = np.asarray(wp.target.pose.end_effector_pose.matrix, dtype=float)
                if wp.reference_type == franky.ReferenceType.Relative:
                    target = (w.flange() @ w.F_T_EE) @ target
                w.q = w.model.ik(target @ EE_T_F, w.q)
        else:
            raise franky.InvalidMotionTypeException(f"unsupported motion {type(motion).__name__}")
        if w.errors:  # a reflex raised while this motion ran
            raise franky.ControlException(f"libfranka: Motion aborted by reflex! [{w.errors}]")

    def join_motion(self, timeout: float | None = None) -> bool:
        self._check_link()
        return True

    def poll_motion(self) -> bool:
        return False

    def stop(self) -> None:
        self._check_link()

    def recover_from_errors(self) -> bool:
        self._check_link()
        self._w.recover_calls += 1
        if self._w.fail_recovery:
            return False
        self._w.errors = ""
        self._w.mode = franky.RobotMode.Idle
        return True
