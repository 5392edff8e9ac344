"""Verification of a hand-eye estimate: the ICP error metric (eq. 13), cost metrics (§3.1, §4.2)
and compensation (eq. 21).

Conventions: ``H`` is the estimate of ``T_dst_camera`` (eye-on-base: ``T_base_camera``). The error
``e`` is the 4x4 transform ``T_cam'_cam`` between the calculated camera frame {Cam'} and the true
one {Cam}, so that the true transform is ``H @ e`` — which is exactly the compensation of eq. 21.
In simulation ``e = inv(H) @ H_true`` (§3.1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from weldcell.sdk.geometry import T_to_rpy, invert
from weldcell.sdk.pointfit import scaled_svd_fit
from weldcell.sdk.repeatable import open3d_serial

Verifier = Callable[[np.ndarray], "np.ndarray | None"]
Cost = Callable[["np.ndarray | None"], float]


def translation_cost(e: np.ndarray | None) -> float:
    """``||δt||₂`` (§3.1): the paper's cost; +inf when verification failed."""
    return float("inf") if e is None else float(np.linalg.norm(e[:3, 3]))


def radius_cost(work_radius: float) -> Cost:
    """``||(δx, δy, δz, δroll·r, δpitch·r, δyaw·r)||₂`` (§4.2) for a work radius ``r`` (m)."""

    def cost(e: np.ndarray | None) -> float:
        if e is None:
            return float("inf")
        return float(np.linalg.norm(np.r_[e[:3, 3], work_radius * T_to_rpy(e)]))

    return cost


def compensate(H: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Eq. 21: ``H_compensated = H_optimal @ e_optimal``."""
    return np.asarray(H) @ np.asarray(e)


def error_components(e: np.ndarray | None) -> dict:
    """δx, δy, δz (m) and δroll, δpitch, δyaw (rad) of an error transform (NaN when failed)."""
    if e is None:
        return {k: float("nan") for k in ("dx", "dy", "dz", "droll", "dpitch", "dyaw")}
    rpy = T_to_rpy(e)
    return {"dx": e[0, 3], "dy": e[1, 3], "dz": e[2, 3], "droll": rpy[0], "dpitch": rpy[1], "dyaw": rpy[2]}


@dataclass
class GroundTruthVerifier:
    """Simulation verifier of §3.1: ``e = inv(H) @ H_true``."""

    H_true: np.ndarray

    def __call__(self, H: np.ndarray) -> np.ndarray:
        return invert(H) @ self.H_true


@dataclass
class IcpVerifier:
    """The ICP error metric of eq. 13.

    ``model``: flange model points (M, 3) in the feature frame (:mod:`flange_model`);
    ``D_v``: the known 4x4 mapping the feature frame into the ``H`` target frame at the verification
    pose (eye-on-base: ``T_base_flange_v``); ``cloud_v``: the measured verification cloud (K, 3) in
    the camera frame. The model is predicted into the camera by ``inv(H) @ D_v`` and registered to
    the measurement by point-to-point ICP; ``E`` (cam' -> cam) gives ``e = inv(E)``. ICP failure
    (fitness below ``min_fitness`` or an RMSE above ``max_rmse``) returns None, i.e. ``e = +inf``.
    """

    model: np.ndarray
    D_v: np.ndarray
    cloud_v: np.ndarray
    max_distance: float = 0.005
    min_fitness: float = 0.3
    max_rmse: float = 0.002
    iterations: int = 50

    voxel: float = 0.0  # > 0: thin the verification scan to this voxel (m) first

    def __post_init__(self) -> None:
        import open3d as o3d

        cloud = np.asarray(self.cloud_v, float).reshape(-1, 3)
        cloud = cloud[np.all(np.isfinite(cloud), axis=1)]
        self._target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
        if self.voxel:  # the model is already thinned (clean_flange_model); the scan builds one KD-tree
            self._target = self._target.voxel_down_sample(self.voxel)
        model = np.asarray(self.model, float).reshape(-1, 3)
        self._model = model[np.all(np.isfinite(model), axis=1)]
        self.calls = 0
        self.failures = 0
        self.best: dict = {}

    def diagnosis(self) -> str:
        """Why ICP failed, from the best attempt: fitness (share of model points matched) and RMSE."""
        b = self.best
        if not b:
            return "never called"
        return (
            f"best fitness {b['fitness']:.2f} (needs {self.min_fitness}), RMSE {b['rmse'] * 1e3:.2f} mm "
            f"(needs <= {self.max_rmse * 1e3:.1f} mm) over {self.calls} tries"
        )

    def __call__(self, H: np.ndarray) -> np.ndarray | None:
        import open3d as o3d

        pred = invert(H) @ np.asarray(self.D_v, float)
        src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self._model @ pred[:3, :3].T + pred[:3, 3]))
        with open3d_serial():  # repeatable: the threaded correspondence sums vary with the host's load
            reg = o3d.pipelines.registration.registration_icp(
                src,
                self._target,
                self.max_distance,
                np.eye(4),
                o3d.pipelines.registration.TransformationEstimationPointToPoint(),
                o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=self.iterations),
            )
        self.calls += 1
        if not self.best or reg.fitness > self.best["fitness"]:
            self.best = {"fitness": float(reg.fitness), "rmse": float(reg.inlier_rmse)}
        if reg.fitness < self.min_fitness or reg.inlier_rmse > self.max_rmse:
            self.failures += 1
            return None
        E = np.asarray(reg.transformation)  # T_cam_cam' (moves the predicted model onto the measurement)
        return invert(E)  # H_true = H @ inv(E), so e = inv(E) (eq. 21)


@dataclass
class ConsensusVerifier:
    """Verification without a verification cloud (point-pair data sets): the error of ``H`` against
    a trimmed least-squares fit to every pair collected so far (the first ``n_seen``); pairs with
    residual above ``n_sigma`` robust sigmas under ``H`` are left out. ``e = inv(H) @ H_consensus``.
    Fewer than ``min_support`` consistent pairs give None (+inf): with only the four pairs of the
    pool the consensus is the pool's own fit, e = I and cost 0, which would stop Algorithm 1 at
    e_required = 0 after four pairs (16 of 100 runs of the §3.1 outlier study did before this guard)."""

    src: np.ndarray
    dst: np.ndarray
    n_sigma: float = 2.5
    min_support: int = 5

    def __call__(self, H: np.ndarray, n_seen: int | None = None) -> np.ndarray | None:
        src, dst = self.src[:n_seen], self.dst[:n_seen]
        r = np.linalg.norm(src @ H[:3, :3].T + H[:3, 3] - dst, axis=1)
        thr = self.n_sigma * 1.4826 * float(np.median(r)) + 1e-12
        keep = r <= thr
        if keep.sum() < max(3, self.min_support):
            return None
        return invert(H) @ scaled_svd_fit(src[keep], dst[keep]).T
