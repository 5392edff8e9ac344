"""Visual-inertial-GNSS pose estimation on key frames (paper 004 §II-B, eqs. 1-2), with gtsam.

State (eq. 1) per key frame k: ``X(k)`` = [R_t, T_t] (Pose3 of the IMU in the world), ``V(k)`` the
velocity, ``B(k)`` the IMU biases. The world frame is the first IMU frame, gravity-aligned (roll and
pitch from the accelerometer during the initial standstill, yaw 0, origin at the IMU).

Factors:
* ``CombinedImuFactor`` between consecutive key frames (IMU preintegration with bias random walk);
* ``BetweenFactorPose3`` from RANSAC PnP with depth between the new key frame and up to ``links``
  previous key frames (relative-pose factors, not points: depth fixes the metric structure, so the
  reprojection BA of eq. 5 over points adds little accuracy for a much larger graph — the pose
  factors are its Gauss-Newton summary; see docs/methods/mapping.md);
* ``GPSFactor`` when a GNSS fix exists, once the local ENU frame is aligned to the world (4-DoF).
The graph is solved by gtsam's ``IncrementalFixedLagSmoother`` (iSAM2 with marginalisation of key
frames older than ``window`` seconds), so the cost per key frame is bounded. Every factor is also kept
in a :class:`~.globalopt.GlobalGraph` with loop closures (a new key frame re-observing a marginalised
one); :meth:`VioEstimator.finalize` solves it in one batch at the end of the drive (eq. 5 over all key
frames). PnP factors carry the covariance of the sensor models (ORB octave, stereo depth noise), GNSS
factors the receiver's accuracy weighted by its error's correlation time.
Between key frames, each camera frame is tracked by PnP against the last key frame with the IMU
prediction as initial guess; when that fails for ``lost_after`` frames tracking is reported lost
and the IMU alone propagates (a key frame without visual factor) until PnP succeeds again.
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X
from weldcell.hal.readings import Intrinsics
from weldcell.plugins.mapping.frontend import OrbFrontEnd, PnPResult, fill_missing_depth
from weldcell.plugins.mapping.globalopt import GlobalGraph, close_loops
from weldcell.plugins.mapping.interp import umeyama
from weldcell.plugins.mapping.keyframe import FrameResult, KeyFrame, TrackedFrame
from weldcell.sdk.errors import DataError

GRAVITY = 9.80665


def _time_now() -> float:
    import time

    return time.perf_counter()


def _pose3(T: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(T[:3, :3]), gtsam.Point3(*T[:3, 3]))


def _mat(p: gtsam.Pose3) -> np.ndarray:
    return p.matrix()


def gravity_alignment(acc_mean: np.ndarray) -> np.ndarray:
    """R_world_imu with yaw 0 such that the specific force at rest ``acc_mean`` maps onto +z."""
    a = acc_mean / np.linalg.norm(acc_mean)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(a, z)
    s, c = np.linalg.norm(v), float(a @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    R = np.eye(3) + vx + vx @ vx * ((1 - c) / s**2)
    yaw = np.arctan2(R[1, 0], R[0, 0])  # remove the yaw so the world x follows the initial heading
    cz, sz = np.cos(-yaw), np.sin(-yaw)
    return np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ R


class VioEstimator:
    """Key-frame visual-inertial(-GNSS) smoother. Feed IMU with :meth:`add_imu`, GNSS with
    :meth:`add_gnss`, camera frames with :meth:`process_frame` (in time order)."""

    def __init__(
        self,
        settings,
        frontend: OrbFrontEnd,
        T_imu_cam: np.ndarray,
        imu_noise,
        T_imu_antenna: np.ndarray | None = None,
    ) -> None:
        self.s = settings
        self.fe = frontend
        self.T_imu_cam = np.asarray(T_imu_cam, float)
        self.T_cam_imu = np.linalg.inv(self.T_imu_cam)
        self.lever = np.zeros(3) if T_imu_antenna is None else np.asarray(T_imu_antenna, float)[:3, 3]
        k = imu_noise.inflate
        p = gtsam.PreintegrationCombinedParams.MakeSharedU(GRAVITY)
        p.setGyroscopeCovariance(np.eye(3) * (k * imu_noise.gyro_noise_density) ** 2)
        p.setAccelerometerCovariance(np.eye(3) * (k * imu_noise.accel_noise_density) ** 2)
        p.setIntegrationCovariance(np.eye(3) * 1e-8)
        p.setBiasOmegaCovariance(np.eye(3) * (k * imu_noise.gyro_random_walk) ** 2)
        p.setBiasAccCovariance(np.eye(3) * (k * imu_noise.accel_random_walk) ** 2)
        self.pim_params = p
        self.imu: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._imu_t: list[float] = []
        self.gnss: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.keyframes: list[KeyFrame] = []
        self.smoother = gtsam.IncrementalFixedLagSmoother(settings.window, gtsam.ISAM2Params())
        self.events: list[dict] = []
        self.lost = 0
        self.is_lost = False
        self.T_world_enu: np.ndarray | None = None
        self._gnss_pairs: list[tuple[np.ndarray, int]] = []
        self._gnss_last_t: float | None = None
        self._live: set[int] = set()
        self.frame_poses: list[tuple[float, np.ndarray, bool]] = []
        self.timing: dict[str, list[float]] = {"frontend": [], "backend": []}
        self.global_graph = GlobalGraph()

    # -- inputs ------------------------------------------------------------------------------------
    def add_imu(self, t: np.ndarray, acc: np.ndarray, gyro: np.ndarray) -> None:
        """IMU samples (sensor time, s); samples older than the newest one are refused."""
        last = self.imu[-1][0] if self.imu else -np.inf
        for ti, a, g in zip(np.atleast_1d(t), np.atleast_2d(acc), np.atleast_2d(gyro), strict=False):
            if ti <= last:
                continue
            self.imu.append((float(ti), np.asarray(a, float), np.asarray(g, float)))
            self._imu_t.append(float(ti))
            last = ti

    def add_gnss(self, t: float, enu: np.ndarray, sigma: np.ndarray) -> None:
        """A GNSS fix in the local ENU frame with its 1-sigma per axis (m)."""
        self.gnss.append((float(t), np.asarray(enu, float), np.asarray(sigma, float)))

    @property
    def imu_span(self) -> tuple[float, float] | None:
        return (self.imu[0][0], self.imu[-1][0]) if self.imu else None

    def _event(self, t: float, kind: str, message: str) -> str:
        self.events.append({"t": round(t, 3), "kind": kind, "message": message})
        return f"{kind}: {message}"

    # -- initialisation ----------------------------------------------------------------------------
    def _initialise(self, t: float, rgb, depth, K: Intrinsics, truth) -> KeyFrame:
        samples = [s for s in self.imu if s[0] <= t and s[0] >= t - self.s.init_time]
        if len(samples) < 10 and not self.s.use_imu:  # visual-only (e.g. an RGB-D sequence without IMU)
            return self._initialise_without_imu(t, rgb, depth, K, truth)
        if len(samples) < 10:
            raise DataError(
                f"only {len(samples)} IMU samples before the first camera frame at t={t:.2f} s",
                "start the IMU stream before the camera and keep the robot still for init_time seconds",
            )
        acc = np.array([s[1] for s in samples])
        gyr = np.array([s[2] for s in samples])
        if np.std(gyr, axis=0).max() > 0.05 or abs(np.linalg.norm(acc.mean(0)) - GRAVITY) > 0.5:
            self._event(
                t, "warning", "the robot moved during initialisation: gravity and gyro bias are rough"
            )
        T0 = np.eye(4)
        T0[:3, :3] = gravity_alignment(acc.mean(0))
        bias = np.concatenate([np.zeros(3), gyr.mean(0)])
        feats = self.fe.extract(rgb, depth, K)
        self.fe.add_depth_sigmas(feats, depth, K)
        kf = KeyFrame(0, t, t, rgb, depth, K, feats, T0, np.zeros(3), bias, True, truth)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        graph.add(
            gtsam.PriorFactorPose3(
                X(0),
                _pose3(T0),
                gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, 1e-3, 1e-3, 1e-3, 1e-3])),
            )
        )
        graph.add(gtsam.PriorFactorVector(V(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 0.02)))
        graph.add(
            gtsam.PriorFactorConstantBias(
                B(0),
                self._bias(bias),
                gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.1, 0.005, 0.005, 0.005])),
            )
        )
        values.insert(X(0), _pose3(T0))
        values.insert(V(0), np.zeros(3))
        values.insert(B(0), self._bias(bias))
        self._update(graph, values, {0: t})
        self.keyframes.append(kf)
        self._event(t, "info", "initialised: world = first IMU frame, gravity-aligned")
        return kf

    def _initialise_without_imu(self, t: float, rgb, depth, K: Intrinsics, truth) -> KeyFrame:
        """Visual-only start (``use_imu = false`` and no IMU data): the world is the first body frame,
        not gravity-aligned; poses, velocities and (unused) biases get priors."""
        feats = self.fe.extract(rgb, depth, K)
        self.fe.add_depth_sigmas(feats, depth, K)
        kf = KeyFrame(0, t, t, rgb, depth, K, feats, np.eye(4), np.zeros(3), np.zeros(6), True, truth)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)))
        graph.add(gtsam.PriorFactorVector(V(0), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
        graph.add(
            gtsam.PriorFactorConstantBias(
                B(0), self._bias(np.zeros(6)), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
            )
        )
        values.insert(X(0), gtsam.Pose3())
        values.insert(V(0), np.zeros(3))
        values.insert(B(0), self._bias(np.zeros(6)))
        self._update(graph, values, {0: t})
        self.keyframes.append(kf)
        self._event(t, "info", "initialised without IMU: world = first body frame (not gravity-aligned)")
        return kf

    @staticmethod
    def _bias(b: np.ndarray) -> gtsam.imuBias.ConstantBias:
        return gtsam.imuBias.ConstantBias(np.asarray(b[:3]), np.asarray(b[3:]))

    # -- IMU ---------------------------------------------------------------------------------------
    def _preintegrate(self, t0: float, t1: float, bias: np.ndarray):
        """Preintegrated IMU between ``t0`` and ``t1`` (zero-order hold, partial first/last steps) and
        whether the IMU data reach ``t1`` (within 20 ms)."""
        import bisect

        pim = gtsam.PreintegratedCombinedMeasurements(self.pim_params, self._bias(bias))
        if not self.imu:
            return pim, False
        i0 = max(0, bisect.bisect_right(self._imu_t, t0) - 1)
        i1 = bisect.bisect_right(self._imu_t, t1)
        t_prev = t0
        for i in range(i0, i1):
            ti, a, g = self.imu[i]
            t_next = self._imu_t[i + 1] if i + 1 < len(self._imu_t) else t1
            t_end = min(t_next, t1)
            dt = t_end - max(ti, t_prev)
            if dt > 0:
                pim.integrateMeasurement(a, g, dt)
                t_prev = t_end
        return pim, self._imu_t[-1] >= t1 - 0.02

    # -- main step ---------------------------------------------------------------------------------
    def process_frame(
        self,
        t: float,
        rgb: np.ndarray,
        depth: np.ndarray | None,
        K: Intrinsics,
        truth: np.ndarray | None = None,
    ) -> FrameResult:
        """Track one camera frame (sensor time ``t``); returns its camera pose and whether it became a
        key frame. A frame older than the IMU stream or than the previous frame is refused."""
        import time as _time

        events: list[str] = []
        if self.imu and t < self.imu[0][0]:
            raise DataError(
                f"camera frame at t={t:.3f} s is older than the IMU stream (starts {self.imu[0][0]:.3f} s)",
                "check the camera/IMU time synchronisation; the frame was dropped",
            )
        if not self.keyframes:
            return self._first_frame(t, rgb, depth, K, truth)
        last = self.keyframes[-1]
        if t <= last.t:
            raise DataError(
                f"camera frame at t={t:.3f} s is not newer than the last key frame",
                "feed frames in time order",
            )
        if depth is None or not np.any(depth > 0):
            msg = "frame without depth: PnP on the key frame's points; its 3-D from triangulation (eq. 4)"
            events.append(self._event(t, "warning", msg))
        t0 = _time.perf_counter()
        pim, covered, T_pred, v_pred = self._predict(last, t, events)
        feats = self.fe.extract(rgb, depth, K)
        pnp, T_world_imu = self._track(last, t, feats, K, T_pred, events, self.s.use_imu and covered)
        tracked = pnp is not None and pnp.ok
        self.timing["frontend"].append(_time.perf_counter() - t0)
        kf = None
        if self._need_keyframe(last, t, T_world_imu):
            t1 = _time.perf_counter()
            self.fe.add_depth_sigmas(feats, depth, K)
            if tracked:  # eq. 4: features of the new key frame without depth get a triangulated one
                fill_missing_depth(last.features, feats, pnp, K)
            frame = TrackedFrame(t, rgb, depth, K, feats, T_world_imu, v_pred, pim, covered, pnp, truth)
            kf = self._add_keyframe(frame)
            self.timing["backend"].append(_time.perf_counter() - t1)
            T_world_imu = kf.T_world_imu
        T = T_world_imu @ self.T_imu_cam
        self.frame_poses.append((t, T, tracked))
        return FrameResult(t, T, kf, tracked, events)

    def _first_frame(self, t, rgb, depth, K, truth) -> FrameResult:
        if self.imu and t - self.imu[0][0] < self.s.init_time:
            first = not any(e["kind"] == "initialising" for e in self.events)
            msg = self._event(t, "initialising", "collecting IMU data at standstill") if first else None
            return FrameResult(t, None, None, False, [msg] if msg else [])
        kf = self._initialise(t, rgb, depth, K, truth)
        T = kf.T_world_imu @ self.T_imu_cam
        self.frame_poses.append((t, T, True))
        return FrameResult(t, T, kf, True, [])

    def _predict(self, last: KeyFrame, t: float, events: list[str]):
        """IMU prediction from the last key frame (constant velocity without IMU coverage)."""
        pim, covered = self._preintegrate(last.t, t, last.bias)
        if not covered and self.s.use_imu:
            events.append(self._event(t, "warning", "IMU data do not cover this frame (IMU stopped?)"))
        if self.s.use_imu and covered:
            nav = pim.predict(gtsam.NavState(_pose3(last.T_world_imu), last.velocity), self._bias(last.bias))
            return pim, covered, _mat(nav.pose()), np.asarray(nav.velocity())
        T_pred = last.T_world_imu.copy()
        T_pred[:3, 3] += last.velocity * (t - last.t)
        return pim, covered, T_pred, last.velocity

    def _track(self, last: KeyFrame, t: float, feats, K, T_pred: np.ndarray, events: list[str], guided: bool):
        """PnP against the last key frame with the prediction as guess (matching by projection only when
        the IMU predicted it: a constant-velocity guess is too rough, its window would hold wrong
        matches biased towards the guess); lost/recovered bookkeeping."""
        pnp = None
        T_world_cam_last = last.T_world_imu @ self.T_imu_cam
        if self.s.use_vision:
            guess = np.linalg.inv(T_world_cam_last) @ T_pred @ self.T_imu_cam
            pnp = self.fe.relative_pose(last.features, feats, K, guess, guided=guided)
        if pnp is not None and pnp.ok:
            if self.is_lost:
                msg = "visual tracking re-initialised against the last key frame"
                events.append(self._event(t, "recovered", msg))
            self.lost, self.is_lost = 0, False
            return pnp, T_world_cam_last @ pnp.T_ref_cur @ self.T_cam_imu
        self.lost += 1
        if self.s.use_vision and self.lost >= self.s.lost_after and not self.is_lost:
            self.is_lost = True
            msg = (
                f"visual tracking lost ({pnp.inliers if pnp else 0} PnP inliers): "
                "IMU-only propagation until features are matched again"
            )
            events.append(self._event(t, "lost", msg))
        return pnp, T_pred

    def _need_keyframe(self, last: KeyFrame, t: float, T_world_imu: np.ndarray) -> bool:
        """The paper's 0.2 m / 0.05 rad, the longest interval, or the first frame of a tracking loss."""
        dT = np.linalg.inv(last.T_world_imu) @ T_world_imu
        dist = float(np.linalg.norm(dT[:3, 3]))
        ang = float(np.arccos(np.clip((np.trace(dT[:3, :3]) - 1) / 2, -1, 1)))
        return (
            dist >= self.s.keyframe_distance
            or ang >= self.s.keyframe_angle
            or t - last.t >= self.s.keyframe_max_interval
            or (self.is_lost and self.lost == self.s.lost_after)
        )

    def _add_keyframe(self, f: TrackedFrame) -> KeyFrame:
        """The tracked frame ``f`` becomes key frame k: its motion factor from the last key frame, visual
        and GNSS factors, one smoother update, then the loop check."""
        last = self.keyframes[-1]
        k = len(self.keyframes)
        v_pred = np.asarray(f.velocity, float)
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        values.insert(X(k), _pose3(f.T_world_imu))
        values.insert(V(k), v_pred)
        values.insert(B(k), self._bias(last.bias))
        self._motion_factors(graph, k, f, last)
        visual = False
        if self.s.use_vision:
            visual = self._visual_factors(graph, k, f.features, f.intrinsics, f.pnp, f.T_world_imu)
        self._gnss_factor(graph, k, f.t, f.T_world_imu)
        kf = KeyFrame(
            k,
            f.t,
            f.t,
            f.rgb,
            f.depth,
            f.intrinsics,
            f.features,
            f.T_world_imu,
            v_pred,
            last.bias.copy(),
            visual,
            f.truth,
        )
        self.keyframes.append(kf)
        self._update(graph, values, {k: f.t})
        if visual and self.s.loop_closure:
            self._close_loops(kf)
        return kf

    def _motion_factors(self, graph, k: int, f: TrackedFrame, last: KeyFrame) -> None:
        """The IMU preintegration factor from key frame k-1 to k, or without IMU coverage a weak motion
        prior from the prediction (bias held) that keeps the graph connected."""
        if self.s.use_imu and f.imu_covered:
            graph.add(
                gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k), f.preintegrated)
            )
            return
        dT = np.linalg.inv(last.T_world_imu) @ f.T_world_imu
        graph.add(
            gtsam.BetweenFactorPose3(X(k - 1), X(k), _pose3(dT), gtsam.noiseModel.Isotropic.Sigma(6, 0.5))
        )
        graph.add(
            gtsam.BetweenFactorConstantBias(
                B(k - 1), B(k), self._bias(np.zeros(6)), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
            )
        )
        graph.add(
            gtsam.PriorFactorVector(
                V(k), np.asarray(f.velocity, float), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)
            )
        )

    def _pnp_sigmas(self, res: PnPResult) -> np.ndarray:
        """1-sigma (rotation x3 rad, translation x3 m) of a PnP relative pose: its own reprojection
        covariance, floored by the settings (depth noise and correlated errors are not in the residuals)."""
        sr = max(self.s.pnp_sigma_r, res.sigma_r if np.isfinite(res.sigma_r) else 1.0)
        st = max(self.s.pnp_sigma_t, res.sigma_t if np.isfinite(res.sigma_t) else 1.0)
        return np.array([sr] * 3 + [st] * 3)

    def _close_loops(self, kf: KeyFrame) -> None:
        """Loop closure against marginalised key frames near ``kf`` (:func:`.globalopt.close_loops`)."""
        close_loops(self, kf)

    def finalize(self) -> bool:
        """Global optimisation (eq. 5 over every key frame, with the loop closures): all key frames get
        their batch estimate. False (and a warning event) when it could not run."""
        if not self.s.global_optimization or len(self.keyframes) < 2:
            return False
        t0 = _time_now()
        try:
            est = self.global_graph.optimise(self.keyframes)
        except RuntimeError as e:
            est = None
            why = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        else:
            why = "the factor graph does not cover every key frame (resumed run)"
        if est is None:
            self._event(self.keyframes[-1].t, "warning", f"global optimisation skipped: {why}")
            return False
        for kf in self.keyframes:
            kf.T_world_imu = est.atPose3(X(kf.index)).matrix()
            kf.velocity = np.asarray(est.atVector(V(kf.index)))
            b = est.atConstantBias(B(kf.index))
            kf.bias = np.concatenate([b.accelerometer(), b.gyroscope()])
        self._pose_covariances(est)
        self.timing["global"] = [_time_now() - t0]
        self._event(
            self.keyframes[-1].t,
            "info",
            f"global optimisation: {len(self.keyframes)} key frames, "
            f"{len(self.global_graph.loops)} loop closures, {1000 * self.timing['global'][0]:.0f} ms",
        )
        return True

    def _pose_covariances(self, est: gtsam.Values) -> None:
        """Each key frame's pose covariance from the global batch (gtsam ``Marginals`` at the batch
        estimate): 6x6 in gtsam's Pose3 tangent space, [rotation, translation] of the IMU body frame (the
        perturbation T_world_imu · Exp(ξ)). It is the marginal relative to the world (the first key frame's
        prior), so it grows with the distance driven where GNSS and loops do not hold it. Left None (with a
        warning event) when the marginals cannot be computed."""
        try:
            marg = gtsam.Marginals(self.global_graph.graph, est)
            for kf in self.keyframes:
                kf.covariance = np.asarray(marg.marginalCovariance(X(kf.index)), float)
        except RuntimeError as e:
            why = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            self._event(self.keyframes[-1].t, "warning", f"key-frame pose covariances not computed: {why}")

    def _visual_factors(self, graph, k: int, feats, K, pnp, T_world_imu: np.ndarray) -> bool:
        any_ok = False
        for j in range(max(0, k - self.s.links), k):
            if j not in self._live:  # marginalised (older than the window) or before a resume
                continue
            ref = self.keyframes[j]
            if j == k - 1 and pnp is not None:
                res = pnp
            else:
                guess = self.T_cam_imu @ np.linalg.inv(ref.T_world_imu) @ T_world_imu @ self.T_imu_cam
                res = self.fe.relative_pose(ref.features, feats, K, guess)
            if not res.ok:
                continue
            T_rel = self.T_imu_cam @ res.T_ref_cur @ self.T_cam_imu
            sig = self._pnp_sigmas(res)
            graph.add(
                gtsam.BetweenFactorPose3(
                    X(j),
                    X(k),
                    _pose3(T_rel),
                    gtsam.noiseModel.Robust.Create(
                        gtsam.noiseModel.mEstimator.Huber.Create(1.345), gtsam.noiseModel.Diagonal.Sigmas(sig)
                    ),
                )
            )
            any_ok = True
        return any_ok

    def _gnss_factor(self, graph, k: int, t: float, T_world_imu: np.ndarray) -> None:
        if not self.s.use_gnss or not self.gnss:
            return
        near = [g for g in self.gnss if abs(g[0] - t) <= 0.11]
        if not near:
            return
        tg, enu, sig = min(near, key=lambda g: abs(g[0] - t))
        self._gnss_pairs.append((enu, k))
        if self.T_world_enu is None:
            self._align_gnss()
        if self.T_world_enu is None:
            return
        p_world = self.T_world_enu[:3, :3] @ enu + self.T_world_enu[:3, 3]
        p_imu = p_world - T_world_imu[:3, :3] @ self.lever
        # the receiver's error is time-correlated (standalone: a slowly wandering bias), so fixes
        # within one correlation time are not independent: each factor carries 1/n of the information
        # of an independent fix, n = fixes used per correlation time
        gap = t - self._gnss_last_t if self._gnss_last_t is not None else self.s.gnss_correlation_time
        n = max(1.0, self.s.gnss_correlation_time / max(gap, 1e-3))
        self._gnss_last_t = t
        graph.add(
            gtsam.GPSFactor(
                X(k),
                gtsam.Point3(*p_imu),
                gtsam.noiseModel.Diagonal.Sigmas(np.maximum(sig, 0.005) * np.sqrt(n)),
            )
        )

    def _align_gnss(self) -> None:
        """4-DoF alignment (yaw + translation) of the local ENU frame to the world (fix/key-frame pairs)."""
        if len(self._gnss_pairs) < 5:
            return
        enu = np.array([p[0] for p in self._gnss_pairs])
        w = np.array(
            [
                self.keyframes[k].T_world_imu[:3, :3] @ self.lever + self.keyframes[k].T_world_imu[:3, 3]
                if k < len(self.keyframes)
                else np.full(3, np.nan)
                for _, k in self._gnss_pairs
            ]
        )
        ok = np.isfinite(w).all(1)
        enu, w = enu[ok], w[ok]
        if len(enu) < 5 or np.ptp(enu[:, :2], axis=0).max() < self.s.gnss_min_spread:
            return
        T2, _ = umeyama(
            np.column_stack([enu[:, :2], np.zeros(len(enu))]), np.column_stack([w[:, :2], np.zeros(len(w))])
        )
        T = np.eye(4)
        T[:2, :2] = T2[:2, :2]
        T[:2, 3] = T2[:2, 3]
        T[2, 3] = float(np.mean(w[:, 2] - enu[:, 2]))
        self.T_world_enu = T
        self._event(
            self.keyframes[-1].t if self.keyframes else 0.0,
            "info",
            f"GNSS aligned to the world frame from {len(enu)} fixes",
        )

    def _update(self, graph, values, stamps: dict[int, float]) -> None:
        ts = gtsam.FixedLagSmootherKeyTimestampMap()
        for k, t in stamps.items():
            for sym in (X(k), V(k), B(k)):
                ts.insert((sym, t))
        try:
            self.smoother.update(graph, values, ts)
            self.global_graph.add(graph)
        except RuntimeError as e:  # gtsam: indeterminate / ill-conditioned system
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise DataError(
                f"the trajectory estimate became ill-posed at t={max(stamps.values()):.2f} s ({first})",
                "too few constraints: keep vision on (use_vision), give the IMU, or check that the camera "
                "sees "
                "texture; the key frames written so far are kept (--resume continues)",
            ) from None
        est = self.smoother.calculateEstimate()
        self._live = set()
        for kf in self.keyframes[-int(self.s.window * 20) - 2 :]:
            if est.exists(X(kf.index)):
                self._live.add(kf.index)
                kf.T_world_imu = est.atPose3(X(kf.index)).matrix()
                kf.velocity = np.asarray(est.atVector(V(kf.index)))
                b = est.atConstantBias(B(kf.index))
                kf.bias = np.concatenate([b.accelerometer(), b.gyroscope()])

    def restore(self, keyframes: list[KeyFrame]) -> None:
        """Continue after an interruption: the stored key frames come back, the last one's state
        (pose, velocity, biases) is the prior of the new smoother (re-initialisation, reported)."""
        if not keyframes:
            return
        last = keyframes[-1]
        self.keyframes = list(keyframes)
        k = last.index
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        graph.add(
            gtsam.PriorFactorPose3(X(k), _pose3(last.T_world_imu), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3))
        )
        graph.add(gtsam.PriorFactorVector(V(k), last.velocity, gtsam.noiseModel.Isotropic.Sigma(3, 0.05)))
        graph.add(
            gtsam.PriorFactorConstantBias(
                B(k),
                self._bias(last.bias),
                gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.05, 0.002, 0.002, 0.002])),
            )
        )
        values.insert(X(k), _pose3(last.T_world_imu))
        values.insert(V(k), last.velocity)
        values.insert(B(k), self._bias(last.bias))
        self._update(graph, values, {k: last.t})
        self._event(last.t, "recovered", f"resumed from key frame {k} (t={last.t:.2f} s)")

    # -- outputs -----------------------------------------------------------------------------------
    def keyframe_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Key-frame times (N,) and camera poses T_world_cam (N, 4, 4)."""
        t = np.array([k.t for k in self.keyframes])
        T = np.array([k.T_world_imu @ self.T_imu_cam for k in self.keyframes])
        return t, T
