"""Numeric inverse kinematics for arms without a closed form (the 7-axis Panda).

Damped least squares from the seed (Levenberg-Marquardt damping as in Sugihara 2011, null space pulled
toward ``home``), then trust-region least squares with the joint limits as bounds from more seeds.
:class:`NumericIK` is mixed into :class:`weldcell.hal.kinematics.RobotModel`, which provides the chain
(``fk``, ``jacobian``, ``_chain``, ``_polish``), the limits and the error for unreachable targets.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from weldcell.hal.ik_closed_form import wrap_angle
from weldcell.sdk.geometry import pose_error

if TYPE_CHECKING:
    from weldcell.sdk.errors import SafetyError


def pose_residual(T: np.ndarray, T_target: np.ndarray) -> np.ndarray:
    """6-vector (position error, rotation-vector error) from ``T`` to ``T_target``, base frame."""
    dR = T_target[:3, :3] @ T[:3, :3].T
    return np.concatenate([T_target[:3, 3] - T[:3, 3], Rotation.from_matrix(dR).as_rotvec()])


class NumericIK:
    """The numeric IK methods of :class:`weldcell.hal.kinematics.RobotModel` (a mixin)."""

    if TYPE_CHECKING:  # provided by RobotModel
        dof: int
        home: np.ndarray
        joint_limits: np.ndarray

        def fk(self, q: Any) -> np.ndarray: ...
        def jacobian(self, q: Any) -> np.ndarray: ...
        def within_limits(self, q: Any, margin: float = 0.0) -> bool: ...
        def limit_violations(self, q: Any) -> list[str]: ...
        def _chain(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
        def _polish(self, q: np.ndarray, T: np.ndarray, iters: int = 3) -> np.ndarray: ...
        def _unreachable(self, T: np.ndarray, why: str) -> SafetyError: ...

    def _numeric_seeds(self, n: int) -> np.ndarray:
        rng = np.random.default_rng(12345)
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        return lo + (hi - lo) * (0.1 + 0.8 * rng.random((n, self.dof)))

    def _dls(
        self,
        T: np.ndarray,
        q0: np.ndarray,
        tol_pos: float,
        tol_rot: float,
        *,
        clamp: bool = True,
        max_iter: int = 150,
    ) -> np.ndarray | None:
        """Damped least squares with LM damping ``lambda^2 = E + 1e-9`` and a null-space pull toward home.

        ``dq = J^T (J J^T + lambda^2 I)^-1 e + (I - J^+ J) k (q_home - q)``; joints clamped to the limits.
        The pull stops once the pose error is below 1e-4 so the final steps converge quadratically.
        """
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        q = np.clip(q0, lo, hi) if clamp else np.array(q0, dtype=float)
        eye6 = np.eye(6)
        for _ in range(max_iter):
            frames, axes = self._chain(q[None])
            e = pose_residual(frames[0, -1], T)
            ep, er = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
            if ep < tol_pos * 1e-3 and er < tol_rot * 1e-3:
                break
            z, o = axes[0, :, :3, 2], axes[0, :, :3, 3]
            J = np.concatenate([np.cross(z, frames[0, -1, :3, 3] - o), z], axis=1).T
            lam2 = 0.5 * float(e @ e) + 1e-9
            JJt = J @ J.T
            dq = J.T @ np.linalg.solve(JJt + lam2 * eye6, e)
            if self.dof > 6 and ep + er > 1e-4:  # pull off at the end so the last steps converge exactly
                dq = dq + (np.eye(self.dof) - np.linalg.pinv(J, rcond=1e-6) @ J) @ (0.2 * (self.home - q))
            step = float(np.max(np.abs(dq)))
            if step > 0.5:
                dq *= 0.5 / step
            q = q + dq
            if clamp:
                q = np.clip(q, lo, hi)
        dp, dr = pose_error(self.fk(q), T)
        return q if (dp <= 1e-2 * tol_pos and dr <= 1e-2 * tol_rot) else None

    def _bounded_lsq(
        self, T: np.ndarray, q0: np.ndarray, tol_pos: float, tol_rot: float, *, bounded: bool = True
    ) -> np.ndarray | None:
        """Trust-region reflective least squares on the pose residual with the joint limits as bounds."""
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        x0 = np.clip(q0, lo + 1e-9, hi - 1e-9) if bounded else np.asarray(q0, dtype=float)
        res = least_squares(
            lambda q: -pose_residual(self.fk(q), T),
            x0,
            jac=self.jacobian,
            bounds=(lo, hi) if bounded else (-np.inf, np.inf),
            method="trf",
            xtol=1e-10,
            ftol=1e-12,
            gtol=1e-12,
            max_nfev=100,
        )
        q = res.x
        if bounded:
            polished = self._polish(q, T, iters=4)
            if self.within_limits(polished):
                q = polished
        dp, dr = pose_error(self.fk(q), T)
        return q if (dp <= tol_pos and dr <= tol_rot) else None

    def _ik_numeric(self, T: np.ndarray, seed: np.ndarray, tol_pos: float, tol_rot: float) -> np.ndarray:
        """DLS from the seed (fast, continuous along paths); else bounded least squares from more seeds."""
        q = self._dls(T, seed, tol_pos, tol_rot, max_iter=60)
        if q is not None:
            return q
        for s in [seed, self.home, *self._numeric_seeds(24)]:
            q = self._bounded_lsq(T, s, tol_pos, tol_rot)
            if q is not None:
                return q
        # distinguish "outside the joint limits" from "outside the workspace"
        for s in [seed, self.home, *self._numeric_seeds(6)]:
            q = self._bounded_lsq(T, s, tol_pos, tol_rot, bounded=False)
            if q is not None:
                detail = self.limit_violations(wrap_angle(q)) or ["(a solution lies on a limit)"]
                raise self._unreachable(T, f"; e.g. {detail[0]}")
        raise self._unreachable(T, "reach")
