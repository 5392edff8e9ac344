"""Continuous joint tracking for the safety gate: the joints followed along a flange curve.

:class:`JointTracking` is mixed into :class:`weldcell.hal.safety.SafetyGate`. From the joints at the
start, Newton steps reach each next flange pose on the curve (predicted from the last step's slope), in
steps of at most :data:`DQ_STEP` rad per joint: a larger jump means a singularity or a change of arm
configuration and is refused. At every check the joints are inside their limits and their speeds (exact
at the checks, and the mean over each step) under the gate's joint speed limits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from weldcell.hal.safety_inputs import _log_rot
from weldcell.sdk.errors import SafetyError

DQ_STEP = 0.05  # rad: the largest joint change between two checks of a tracked motion
TINY = 1e-9  # m: a step this short cannot be subdivided further


class JointTracking:
    """The joint-tracking methods of :class:`weldcell.hal.safety.SafetyGate` (a mixin)."""

    if TYPE_CHECKING:  # provided by SafetyGate
        model: Any

        @property
        def joint_speed_limits(self) -> np.ndarray | None: ...
        def _budget(self, n: int, what: str) -> None: ...
        def solve(
            self, T_base_flange: np.ndarray, q_seed: np.ndarray | None, what: str = "target"
        ) -> np.ndarray | None: ...

    def _fkj(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = self.model
        fkj = getattr(m, "fk_jacobian", None)
        if fkj is not None:
            return fkj(q)
        if not hasattr(m, "jacobian"):
            raise SafetyError(
                f"the {m.name} kinematic model has no Jacobian, so the gate cannot follow the joints along "
                "the motion",
                "give the model a jacobian(q) method (see weldcell.hal.kinematics.RobotModel)",
            )
        return m.fk(q), m.jacobian(q)

    def _newton(self, T: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Joints reaching flange pose ``T`` continuously from ``q`` (a few Newton steps) and the Jacobian
        there, or None."""
        for _ in range(8):
            F, J = self._fkj(q)
            e = np.concatenate([T[:3, 3] - F[:3, 3], _log_rot(T[:3, :3] @ F[:3, :3].T)])
            if float(np.max(np.abs(e))) < 1e-9:
                return q, J
            dq = np.linalg.lstsq(J, e, rcond=1e-10)[0]
            step = float(np.max(np.abs(dq))) if np.all(np.isfinite(dq)) else math.inf
            if step > 0.5:
                return None
            q = q + dq
            if step < 1e-9:  # quadratic convergence: the remaining error is ~step^2
                return q, J
        return None

    def _joint_rates(self, J: np.ndarray, twist: np.ndarray) -> np.ndarray:
        """Joint velocities (per unit of the path parameter) that give the flange ``twist`` at ``J``."""
        with np.errstate(all="ignore"):
            u = np.linalg.lstsq(J, twist, rcond=1e-12)[0]
        return np.where(np.isfinite(u), u, np.inf)

    def _track(
        self,
        flange_at: Callable[[float], np.ndarray],
        twist_at: Callable[[float, np.ndarray], np.ndarray],
        q0: np.ndarray,
        h0: float,
        sdot: float,
        scale: float,
        label: Callable[[float], str],
    ) -> np.ndarray:
        """Track the joints along a flange curve ``s -> T(s)`` from ``q0`` and return the final joints.

        ``twist_at(s, T)`` is the flange twist ``dT/ds`` (base frame, origin velocity and angular
        velocity), ``sdot`` the path rate (1/s) and ``scale`` the Cartesian size of the curve. Steps of at
        most ``DQ_STEP`` rad per joint (halved until they are); each solution inside the joint limits;
        the joint speeds, exact at every check (``J^+ twist * sdot``) and as the mean over each step,
        under :attr:`joint_speed_limits`; steps refined where the speed has an interior peak or changes
        fast near the limit.
        """
        lim = np.asarray(self.model.joint_limits, dtype=float)
        vmax = self.joint_speed_limits
        s, q, h, n = 0.0, q0, min(1.0, h0), 0
        slope = np.zeros_like(q0)  # dq/ds of the last step: the predictor
        F0, J0 = self._fkj(q0)
        u_a = self._joint_rates(J0, twist_at(0.0, F0)) * sdot
        self._check_rates(np.abs(u_a), vmax, label(0.0))
        while s < 1.0:
            n += 1
            self._budget(n, label(s))
            h = min(h, 1.0 - s)
            b = 1.0 if s + h >= 1.0 - 1e-15 else s + h
            T = flange_at(b)
            got = self._newton(T, q + slope * (b - s))
            if got is None and np.any(slope):
                got = self._newton(T, q)
            dq = None if got is None else np.abs(got[0] - q)
            small = (b - s) * scale <= TINY
            if dq is None or float(np.max(dq)) > DQ_STEP:
                if not small:
                    h /= 2.0
                    continue
                self.solve(T, q, label(b))  # the precise reason when the pose is unreachable ...
                raise SafetyError(  # ... else the arm would have to jump to another configuration
                    f"{label(b)}: the joints would jump (a singularity or a change of arm configuration)",
                    "split the motion with a joint move, or change the approach orientation",
                )
            qb, Jb = got
            u_b = self._joint_rates(Jb, twist_at(b, T)) * sdot
            mean = (qb - q) / (b - s) * sdot
            ends = np.maximum(np.abs(u_a), np.abs(u_b))
            peak = np.maximum(ends, np.abs(mean))  # the mean over the step is a lower bound of its peak
            bump = np.abs(mean) > ends + 0.01 * vmax  # the speed peaks inside the step
            steep = (np.abs(u_b - u_a) > 0.1 * vmax) & (ends > 0.5 * vmax)
            if (
                np.all(peak <= vmax)
                and np.any(bump | steep)
                and float(np.max(dq)) > DQ_STEP / 32
                and not small
            ):
                h /= 2.0  # resolve the peak finely before judging it
                continue
            self._check_rates(peak, vmax, label(b))
            out = np.nonzero((qb < lim[:, 0] - 1e-9) | (qb > lim[:, 1] + 1e-9))[0]
            if len(out):
                j = int(out[0])
                raise SafetyError(
                    f"{label(b)}: joint {j + 1} would reach {np.degrees(qb[j]):.1f} deg, outside its limits "
                    f"[{np.degrees(lim[j, 0]):.1f}, {np.degrees(lim[j, 1]):.1f}] deg",
                    "choose another configuration or path",
                )
            slope, u_a = (qb - q) / (b - s), u_b
            s, q = b, qb
            h = min(h0, 2.0 * h) if float(np.max(dq)) < DQ_STEP / 4 else h
        return q

    @staticmethod
    def _check_rates(rate: np.ndarray, vmax: np.ndarray, where: str) -> None:
        bad = np.nonzero(rate > vmax)[0]
        if len(bad):
            j = int(bad[0])
            speed = f"{np.degrees(rate[j]):.0f} deg/s" if np.isfinite(rate[j]) else "unbounded speed"
            raise SafetyError(
                f"{where}: joint {j + 1} would turn at {speed}, over its limit of {np.degrees(vmax[j]):.0f} "
                "deg/s (near a singularity, or too fast)",
                "lower the speed, or avoid the singular configuration (change the tool orientation or "
                "the path), or raise [cell.safety] max_joint_speed within the robot's hardware limits",
            )
