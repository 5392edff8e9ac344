"""The simulation protocol of §3.1 as a reusable generator.

Eye-on-base cell: the ground-truth ``T_base_camera`` of eq. 19 (the printed matrix: rpy [π, 0, -π/2],
t = [0.6, -0.0125, 1] m); 75 flange poses on a 5 x 5 x 3 grid spanning a 0.3 x 0.3 x 0.2 m box with
random orientations (roll, pitch, yaw each within ±0.3 rad of flange-facing-the-camera); camera
points ``p_cam = T_cam_base p_base + N(0, σ)`` (eq. 20) for σ from 0.2 to 10 mm, 100 noise
realizations per level.

Where the paper is silent, the authors' published Gazebo scripts (github.com/ancorasir/
flange_handeye_calibration, ``calibration_grid`` / simulation test scripts) fix the details: the grid
is x ∈ [0.45, 0.75], y ∈ [-0.15, 0.15], z ∈ [0.2, 0.4] m in the base (``linspace`` with 5, 5, 3
nodes), orientations ``quaternion_from_euler(0.3·U(-1, 1), ...)``, the error is ``inv(Ĥ) @ H_true``
(δt = its translation, in mm) and Algorithm 1 runs over a fresh random permutation of the pairs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.plugins.handeye.flange_model import iso9409_model
from weldcell.plugins.handeye.verification import IcpVerifier
from weldcell.sdk.geometry import invert

#: eq. 19, as printed (the rpy [3.1415, 0, -1.57] of the text rounded to this exact matrix)
PAPER_T_BASE_CAMERA = np.array(
    [[0.0, -1.0, 0.0, 0.6], [-1.0, 0.0, 0.0, -0.0125], [0.0, 0.0, -1.0, 1.0], [0.0, 0.0, 0.0, 1.0]]
)
#: σ_noise of §3.1: 0.2 mm to 10 mm in 0.2 mm steps (m)
PAPER_SIGMAS = np.round(np.arange(0.2, 10.0 + 1e-9, 0.2), 1) * 1e-3
#: centre of the authors' Gazebo grid (x 0.45-0.75, y ±0.15, z 0.2-0.4 m in the base)
PAPER_GRID_CENTER = (0.6, 0.0, 0.3)


@dataclass
class SimCell:
    """A simulated eye-on-base data set: robot poses, true TCP positions and the truth."""

    T_base_camera: np.ndarray
    T_base_flange: np.ndarray  # (n, 4, 4)
    p_base: np.ndarray  # (n, 3) flange centres in the base
    p_cam_true: np.ndarray  # (n, 3) the same in the camera

    def noisy_p_cam(
        self, sigma: float, rng: np.random.Generator, model: Literal["isotropic", "ray"] = "isotropic"
    ) -> np.ndarray:
        """Eq. 20: ``p_cam = T_cam_base p_base + N(0, σ)``, σ in metres. ``"isotropic"`` (the paper)
        adds N(0, σ) to each coordinate; ``"ray"`` puts N(0, σ) along the line of sight only, the
        depth-dominant error of a structured-light or ToF scanner (a sensitivity check)."""
        if model == "isotropic":
            return self.p_cam_true + rng.normal(0.0, sigma, self.p_cam_true.shape)
        if model == "ray":
            u = self.p_cam_true / np.linalg.norm(self.p_cam_true, axis=1, keepdims=True)
            return self.p_cam_true + u * rng.normal(0.0, sigma, (len(u), 1))
        raise ValueError(f"unknown noise model {model!r}")

    def board_poses(
        self,
        sigma: float,
        rng: np.random.Generator,
        T_flange_target: np.ndarray | None = None,
        board_size: float = 0.08,
        grid: int = 5,
    ) -> np.ndarray:
        """Noisy target poses ``T_cam_target`` (n, 4, 4) for the target-based solvers: a ``grid`` x
        ``grid`` board of ``board_size`` m on the flange, each corner measured with the same N(0, σ)
        3-D noise, and the pose fitted to the corners — the same noise model as the flange points."""
        from weldcell.sdk.pointfit import rigid_fit_batch

        T_ft = np.eye(4) if T_flange_target is None else T_flange_target
        g = np.linspace(-board_size / 2, board_size / 2, grid)
        X, Y = np.meshgrid(g, g)
        corners = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
        T_ct = np.einsum("ij,njk,kl->nil", invert(self.T_base_camera), self.T_base_flange, T_ft)
        meas = np.einsum("nij,kj->nki", T_ct[:, :3, :3], corners) + T_ct[:, None, :3, 3]
        meas = meas + rng.normal(0.0, sigma, meas.shape)
        return rigid_fit_batch(np.broadcast_to(corners, meas.shape), meas)


def simulate_cell(
    n_poses: int = 75,
    box: tuple[float, float, float] = (0.3, 0.3, 0.2),
    center: tuple[float, float, float] = PAPER_GRID_CENTER,
    max_angle: float = 0.3,
    T_base_camera: np.ndarray | None = None,
    grid: bool = True,
    rng: np.random.Generator | int | None = 0,
) -> SimCell:
    """Flange poses of the §3.1 protocol. With ``grid`` the positions are the first ``n_poses``
    nodes of a 5 x 5 x 3 grid spanning ``box`` around ``center`` (75 nodes, shuffled; the authors'
    Gazebo grid by default), else uniform in the box. The flange z axis faces the camera (base +z for
    the eq. 19 camera looking down), rotated by roll, pitch, yaw uniform in ±``max_angle``. Only the
    flange centres enter the point fit; the orientations matter for board poses and scans."""
    rng = np.random.default_rng(rng)
    T_bc = PAPER_T_BASE_CAMERA if T_base_camera is None else np.asarray(T_base_camera, float)
    b, c = np.asarray(box, float), np.asarray(center, float)
    if grid:
        nx = int(np.ceil((n_poses / 3) ** 0.5))
        gx, gy, gz = (np.linspace(-0.5, 0.5, nx), np.linspace(-0.5, 0.5, nx), np.linspace(-0.5, 0.5, 3))
        G = np.stack(np.meshgrid(gx, gy, gz, indexing="ij"), -1).reshape(-1, 3)
        G = G[rng.permutation(len(G))]
        while len(G) < n_poses:
            G = np.vstack([G, rng.uniform(-0.5, 0.5, (n_poses - len(G), 3))])
        pos = c + G[:n_poses] * b
    else:
        pos = c + rng.uniform(-0.5, 0.5, (n_poses, 3)) * b
    # flange z toward the camera: camera z axis in the base, reversed
    face = Rotation.from_matrix(T_bc[:3, :3]) * Rotation.from_euler("x", np.pi)
    jitter = Rotation.from_euler("xyz", rng.uniform(-max_angle, max_angle, (n_poses, 3)))
    R = (face * jitter).as_matrix()
    T = np.tile(np.eye(4), (n_poses, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, pos
    p_cam = pos @ invert(T_bc)[:3, :3].T + invert(T_bc)[:3, 3]
    return SimCell(T_bc, T, pos, p_cam)


def workspace_error(H: np.ndarray, H_true: np.ndarray, points: np.ndarray) -> float:
    """RMS displacement (m) of ``points`` (n, 3, in the frame {Cam}) mapped by ``H`` instead of
    ``H_true``: the error a user of the calibration sees in the work volume, unlike δt of
    ``inv(H) @ H_true``, which is the displacement of the camera origin."""
    P = np.asarray(points, float)
    d = P @ (H[:3, :3] - H_true[:3, :3]).T + (H[:3, 3] - H_true[:3, 3])
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def render_flange_scan(
    T_cam_flange: np.ndarray,
    model: np.ndarray,
    sigma: float = 0.0001,
    n_outliers: int = 0,
    clutter: bool = False,
    rng: np.random.Generator | int | None = 0,
) -> np.ndarray:
    """A synthetic raw scan (N, 3, m, camera frame) of a flange model at ``T_cam_flange``: the
    model's camera-facing points with N(0, σ) noise, optional uniform outliers around the flange,
    and optional clutter (a table plane 0.15 m behind the flange and a wrist cylinder)."""
    rng = np.random.default_rng(rng)
    P = model @ T_cam_flange[:3, :3].T + T_cam_flange[:3, 3]
    P = P + rng.normal(0, sigma, P.shape)
    parts = [P]
    c = T_cam_flange[:3, 3]
    if n_outliers:
        parts.append(c + rng.uniform(-0.05, 0.05, (n_outliers, 3)))
    if clutter:
        z = T_cam_flange[:3, 2]
        u = np.cross(z, [1.0, 0, 0]) if abs(z[0]) < 0.9 else np.cross(z, [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(z, u)
        ab = rng.uniform(-0.25, 0.25, (20000, 2))
        parts.append(c - 0.15 * z + ab[:, :1] * u + ab[:, 1:] * v + rng.normal(0, sigma, (20000, 3)))
        th = rng.uniform(0, 2 * np.pi, 6000)
        h = rng.uniform(0.02, 0.12, 6000)
        parts.append(c - h[:, None] * z + 0.037 * (np.cos(th)[:, None] * u + np.sin(th)[:, None] * v))
    return np.vstack(parts)


def _pair_jacobian(p_cam: np.ndarray) -> np.ndarray:
    """``J_i = [I, -[q_i]×]`` (n, 3, 6): d(e·q_i)/dξ at ξ = (δt, δθ) = 0."""
    q = np.asarray(p_cam, float).reshape(-1, 3)
    skew = np.zeros((len(q), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -q[:, 2], q[:, 1], -q[:, 0]
    skew -= skew.transpose(0, 2, 1)
    return np.concatenate([np.broadcast_to(np.eye(3), skew.shape), -skew], axis=2)


def pairs_crlb(p_cam: np.ndarray, sigma: float) -> np.ndarray:
    """Cramér–Rao bound (6, 6) on the covariance of ξ = (δt, δθ) of ``e = inv(Ĥ) @ H_true`` for any
    unbiased estimate from point pairs alone: ``p_cam`` (n, 3) the true camera points, each measured
    with N(0, σ²I) (eq. 20), robot side exact. To first order the pairs see ``e·q ≈ q + δt - [q]×δθ``,
    so the Fisher information is ``Σ J_iᵀJ_i / σ²``."""
    J = _pair_jacobian(p_cam)
    return np.linalg.inv(np.einsum("nki,nkj->ij", J, J) / sigma**2)


def crlb_workspace_rms(cov: np.ndarray, points: np.ndarray) -> float:
    """``sqrt(E[rms²])`` (m) of :func:`workspace_error` over ``points`` (n, 3, camera frame) for an
    error ξ = (δt, δθ) with covariance ``cov`` (e.g. :func:`pairs_crlb`), to first order."""
    J = _pair_jacobian(points)
    return float(np.sqrt(np.mean(np.einsum("nki,ij,nkj->n", J, cov, J))))


def verification_pose(cell: SimCell, center: tuple[float, float, float] = PAPER_GRID_CENTER) -> np.ndarray:
    """``T_base_flange_v``: the flange at ``center`` facing the camera square on (Algorithm 1's
    verification pose, "where the robot arm will mostly work around", §2.1.4)."""
    face = Rotation.from_matrix(cell.T_base_camera[:3, :3]) * Rotation.from_euler("x", np.pi)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = face.as_matrix(), center
    return T


def scan_verifier(
    cell: SimCell,
    sigma: float,
    rng: np.random.Generator | int | None = 0,
    d1_mm: float = 50.0,
    model_spacing: float = 0.0015,
    scan_spacing: float = 0.0007,
) -> IcpVerifier:
    """The realistic eq. 13 verifier of a simulated cell: an ISO 9409-1 flange (``d1_mm``) scanned at
    :func:`verification_pose` with N(0, σ) on every point (``scan_spacing`` grid, ~5600 points for
    d1 = 50 mm), registered by :class:`~weldcell.plugins.handeye.verification.IcpVerifier` with a model
    sampled on a different grid (``model_spacing``, ~1200 points); the ICP gates widen with σ
    (correspondences within 5 mm + 3σ, RMSE up to 2 mm + 3σ)."""
    T_bf = verification_pose(cell)
    T_cf = invert(cell.T_base_camera) @ T_bf
    scan = render_flange_scan(T_cf, iso9409_model(d1_mm, spacing=scan_spacing), sigma=sigma, rng=rng)
    model = iso9409_model(d1_mm, spacing=model_spacing)
    return IcpVerifier(model, T_bf, scan, max_distance=0.005 + 3 * sigma, max_rmse=0.002 + 3 * sigma)
