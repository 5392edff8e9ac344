"""Global optimisation over every key frame (paper 004 eq. 5 "globally optimized") and loop closure.

The fixed-lag smoother (:mod:`.estimator`) keeps the cost per key frame bounded by marginalising key
frames older than its window, so the poses it has let go of are never corrected again: drift
accumulates. :class:`GlobalGraph` keeps a copy of every factor the smoother received (priors, IMU
preintegration, PnP relative poses, GNSS) and adds loop-closure factors: when a new key frame comes
back near a marginalised one (the route re-visits a place), ORB matching + RANSAC PnP against the old
key frame's stored features gives a relative pose, verified by its inlier count and reprojection
error. :meth:`GlobalGraph.optimise` solves the whole graph by Levenberg-Marquardt (a full batch, the
exact maximum a posteriori instead of the smoother's linearised marginals), started at the smoother's
estimates; it runs once at the end of the drive (and whenever the job asks for it).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X


@dataclass
class LoopClosure:
    """A verified loop: key frame ``new`` re-observes the place of key frame ``old``."""

    old: int
    new: int
    inliers: int
    rmse_px: float
    T_old_new: np.ndarray
    """IMU pose of ``new`` in the IMU frame of ``old``."""


LOOP_EVERY = 5
"""Key frames between two loop-closure attempts once a loop is found (~1 m at the paper's 0.2 m)."""


class GlobalGraph:
    """Every factor of the run plus loop closures; batch Levenberg-Marquardt over all key frames."""

    def __init__(self) -> None:
        self.graph = gtsam.NonlinearFactorGraph()
        self.loops: list[LoopClosure] = []

    def add(self, graph: gtsam.NonlinearFactorGraph) -> None:
        for i in range(graph.size()):
            f = graph.at(i)
            if f is not None:
                self.graph.add(f)

    def add_loop(self, loop: LoopClosure, sigma_r: float, sigma_t: float) -> None:
        """A relative-pose factor between the two key frames' IMU poses. Gaussian, not robust: at the
        drifted starting point a true loop's residual is tens of sigmas, which a robust kernel would
        discount as an outlier; the loop was verified (inliers, plausible drift) before it got here."""
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma_r] * 3 + [sigma_t] * 3))
        T = loop.T_old_new
        pose = gtsam.Pose3(gtsam.Rot3(T[:3, :3]), gtsam.Point3(*T[:3, 3]))
        self.graph.add(gtsam.BetweenFactorPose3(X(loop.old), X(loop.new), pose, noise))
        self.loops.append(loop)

    def optimise(self, keyframes: list, max_iterations: int = 50) -> gtsam.Values | None:
        """Batch LM over the key frames' poses, velocities and biases, from their current estimates;
        None when the graph does not cover the key frames (e.g. after a resume without history)."""
        values = gtsam.Values()
        for kf in keyframes:
            T = kf.T_world_imu
            values.insert(X(kf.index), gtsam.Pose3(gtsam.Rot3(T[:3, :3]), gtsam.Point3(*T[:3, 3])))
            values.insert(V(kf.index), np.asarray(kf.velocity, float))
            values.insert(B(kf.index), gtsam.imuBias.ConstantBias(kf.bias[:3], kf.bias[3:]))
        keys = set(self.graph.keyVector())
        if not keys or any(k not in keys for k in (X(kf.index) for kf in keyframes)):
            return None
        if any(not values.exists(k) for k in keys):
            return None
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(max_iterations)
        params.setRelativeErrorTol(1e-6)
        return gtsam.LevenbergMarquardtOptimizer(self.graph, values, params).optimize()


def loop_candidates(keyframes: list, k: int, live: set[int], T_cam_imu: np.ndarray, settings) -> list[int]:
    """Older key frames (already marginalised, with visual features) whose estimated camera is within
    ``loop_radius`` of key frame ``k``'s and looks the same way (optical axes < 40° apart); nearest
    first, at most 2."""
    cur = keyframes[k]
    T_imu_cam = np.linalg.inv(T_cam_imu)
    Tc = cur.T_world_imu @ T_imu_cam
    out = []
    for kf in keyframes[: max(0, k - 1)]:
        if kf.index in live or not kf.visual or kf.features is None or len(kf.features.pixels) == 0:
            continue
        To = kf.T_world_imu @ T_imu_cam
        d = float(np.linalg.norm(To[:3, 3] - Tc[:3, 3]))
        if d > settings.loop_radius:
            continue
        if float(To[:3, 2] @ Tc[:3, 2]) < np.cos(np.radians(40.0)):
            continue
        out.append((d, kf.index))
    return [i for _, i in sorted(out)[:2]]


def close_loops(est, kf) -> None:
    """Match the new key frame against marginalised key frames near it (the route came back): a
    verified PnP pose becomes a loop-closure factor of the global graph (reported as an event)."""
    loops = est.global_graph.loops
    if loops and kf.index - loops[-1].new < LOOP_EVERY:
        return  # one loop factor per LOOP_EVERY key frames suffices; matching is the cost
    t0 = time.perf_counter()
    for j in loop_candidates(est.keyframes, kf.index, est._live, est.T_cam_imu, est.s):
        old = est.keyframes[j]
        T_est = np.linalg.inv(old.T_world_imu) @ kf.T_world_imu  # drifted estimate, for the guess
        guess = est.T_cam_imu @ T_est @ est.T_imu_cam
        res = est.fe.relative_pose(old.features, kf.features, kf.intrinsics, guess, guided=False)
        if not res.ok or res.inliers < 2 * est.fe.s.min_inliers:
            continue
        T_rel = est.T_imu_cam @ res.T_ref_cur @ est.T_cam_imu
        dT = np.linalg.inv(T_est) @ T_rel
        ang = float(np.degrees(np.arccos(np.clip((np.trace(dT[:3, :3]) - 1) / 2, -1, 1))))
        if np.linalg.norm(dT[:3, 3]) > est.s.loop_radius or ang > 10.0:
            continue  # inconsistent with any plausible drift: a false match
        sig = est._pnp_sigmas(res)
        loop = LoopClosure(j, kf.index, res.inliers, res.rmse_px, T_rel)
        est.global_graph.add_loop(loop, sig[0], sig[3])
        est._event(
            kf.t,
            "loop",
            f"key frame {kf.index} re-observes key frame {j} ({res.inliers} inliers, "
            f"{res.rmse_px:.2f} px; drift {np.linalg.norm(dT[:3, 3]):.3f} m, {ang:.2f} deg)",
        )
        break
    est.timing.setdefault("loop", []).append(time.perf_counter() - t0)
