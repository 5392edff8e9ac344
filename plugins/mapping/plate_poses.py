"""The key frames' pose errors in a plate's box fit: one rigid correction per pass, with a prior from the
estimator's covariance.

Why: the box fit (:mod:`.plate_fit`) measures a plate within 1-7 mm when its views sit at their true
poses, but a plate seen on several passes of the route is seen from key frames whose poses come from
different stretches of the trajectory: after loop closure and the global batch they still disagree by
2-6 cm (VGA, 100 m, seed 0), and a box cannot fit views that disagree. Within one pass the key frames
are tied to each other by the PnP factors (``links`` = 3 key frames back): a rigid motion of the whole
pass leaves 1.6-5.4 mm rms of the views' error (measured against the truth on every pass of the four
plates, seed 0), the passes' offsets 10-60 mm. So each pass gets one rigid correction ξ = [ω, t]
(world-frame rotation vector about the pass's pivot, the mean camera centre, and translation), fitted
jointly with the box, with the prior ξ ~ N(0, Σ): Σ from the key frames' pose covariance
(``KeyFrameRecord.covariance``, gtsam's marginal after the global batch), carried to the pivot.

The marginal is relative to the world (the first key frame), not to the other pass: it includes the
error the passes share, which the box's own position absorbs (AE does not depend on it). Taking the
passes' corrections as independent with their marginals is therefore a looser prior than the passes'
relative covariance: it lets the data decide more, and never claims the passes agree better than the
estimator said.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

PASS_GAP = 3
"""Key frames at most this many indices apart are one pass: the estimator ties each key frame to its
``links`` (3) predecessors by PnP factors; beyond that they are related only through the chain."""


def skew(r: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


def _move(r: np.ndarray) -> np.ndarray:
    """Jacobian of a rigid correction [ω, δx at a point a] to [ω, δx at a + r]: δx' = δx + ω × r."""
    J = np.eye(6)
    J[3:, :3] = -skew(r)
    return J


def camera_pose_cov(T_world_imu: np.ndarray, cov_body: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """The 6x6 covariance of a key frame's pose error as a world-frame correction [ω, δx] at the camera
    centre, from gtsam's Pose3 covariance of ``T_world_imu`` ([rotation, translation] in the body frame:
    T·Exp(ξ), so ω_world = R ω_body and δx_imu = R v_body)."""
    R = np.asarray(T_world_imu, float)[:3, :3]
    G = np.zeros((6, 6))
    G[:3, :3] = G[3:, 3:] = R
    J = _move(np.asarray(T_world_cam, float)[:3, 3] - np.asarray(T_world_imu, float)[:3, 3])
    C = J @ G @ np.asarray(cov_body, float) @ G.T @ J.T
    return (C + C.T) / 2


@dataclass
class PassPrior:
    """Views of one pass (indices into the fit's views, their key frames), the pivot of their common
    correction (the mean camera centre) and the prior covariance of that correction [ω, t at pivot]."""

    views: np.ndarray
    keyframes: tuple[int, ...]
    pivot: np.ndarray
    cov: np.ndarray

    def whiten(self) -> np.ndarray:
        """W with Wᵀ W = cov⁻¹ (the prior residual is W ξ)."""
        return np.linalg.inv(np.linalg.cholesky(self.cov))


def group_passes(views: list) -> list[PassPrior] | None:
    """The views grouped into passes (consecutive key frames, index gaps ≤ PASS_GAP), each with its
    prior; None when a view has no key-frame index or no pose covariance (a store written before the
    covariance was kept): the views then stay at their poses."""
    if not views or any(getattr(w, "pose_cov", None) is None or w.keyframe < 0 for w in views):
        return None
    order = sorted(range(len(views)), key=lambda i: views[i].keyframe)
    groups = [[order[0]]]
    for i in order[1:]:
        if views[i].keyframe - views[groups[-1][-1]].keyframe <= PASS_GAP:
            groups[-1].append(i)
        else:
            groups.append([i])
    out = []
    for g in groups:
        pivot = np.mean([views[i].T_world_cam[:3, 3] for i in g], axis=0)
        covs = []
        for i in g:
            J = _move(pivot - views[i].T_world_cam[:3, 3])
            covs.append(J @ views[i].pose_cov @ J.T)
        C = np.mean(covs, axis=0)
        C = (C + C.T) / 2 + np.eye(6) * 1e-12
        out.append(PassPrior(np.array(g), tuple(views[i].keyframe for i in g), pivot, C))
    return out


def corrections(xi: np.ndarray, passes: list[PassPrior]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per pass the rigid correction x -> R (x - pivot) + pivot + t as (R, offset) with x' = R x + offset."""
    out = []
    for k, ps in enumerate(passes):
        R = Rotation.from_rotvec(xi[6 * k : 6 * k + 3]).as_matrix()
        out.append((R, ps.pivot + xi[6 * k + 3 : 6 * k + 6] - R @ ps.pivot))
    return out


def corrected_pose(T: np.ndarray, R: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """``T_world_cam`` moved by the correction (R, offset)."""
    C = np.eye(4)
    C[:3, :3], C[:3, 3] = R, offset
    return C @ T
