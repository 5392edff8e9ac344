"""One hand-eye correction for all views of a reconstruction (beyond paper 000; see
docs/methods/reconstruction.md, "Hand-eye error found by reconstruction").

View ``i`` is placed by eq. 1 at ``B_i = T_base_flange_i . X^`` (X^ the hand-eye transform in use);
ICP against the growing model moves it to ``A_i = C_i . B_i``. ICP fixes the views relative to each
other only, so if the true mount is ``X`` the registered poses satisfy ``A_i = G . B_i . D`` with
``D = X^-1 . X`` (the hand-eye correction, camera frame) and one unknown ``G`` (where the registered
model sits in the base frame) common to all views. With rotational diversity among the flange poses
both are identifiable; ``B_i . D`` then places each view in the true base frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.geometry import invert, rotation_angle, skew

#: the views' flange rotations must differ by at least this much about every axis (rad)
MIN_SPREAD = np.deg2rad(10.0)
#: views whose ICP matched less than this share of their points are left out
MIN_OVERLAP = 0.2


@dataclass
class HandEyeFit:
    """Outcome of :func:`fit_hand_eye`.

    ``D`` (``T_camera_camera'``) is the hand-eye correction: the corrected hand-eye is
    ``T_flange_camera @ D``. ``G`` (``T_base_model``) is where the frame of the registered poses ``A_i``
    the fit was given sat in the base frame. ``views`` are the indices used, ``weights`` their final
    weights (ICP overlap x robust weight).
    ``spread_deg``: the views' rotational diversity about the least diverse axis (deg); ``sigma_mm`` /
    ``sigma_deg``: the correction's standard error (largest direction) from the residual scatter;
    ``residual_mm`` / ``residual_deg``: RMS over the used views of what one correction leaves of the
    per-view ICP placements (at the camera). ``passes``: leave-one-out re-registration passes behind
    this fit (see :func:`~.reconstruct.reconstruct`). ``applied`` is False when the correction was not
    identifiable (``note`` says why) and the caller fell back.
    """

    D: np.ndarray = field(default_factory=lambda: np.eye(4))
    G: np.ndarray = field(default_factory=lambda: np.eye(4))
    views: list[int] = field(default_factory=list)
    weights: list[float] = field(default_factory=list)
    spread_deg: float = 0.0
    sigma_mm: float = float("nan")
    sigma_deg: float = float("nan")
    residual_mm: float = float("nan")
    residual_deg: float = float("nan")
    iterations: int = 0
    passes: int = 0
    applied: bool = False
    note: str = ""

    @property
    def translation_mm(self) -> float:
        """Size of the correction's translation (mm)."""
        return float(np.linalg.norm(self.D[:3, 3]) * 1e3)

    @property
    def rotation_deg(self) -> float:
        """Size of the correction's rotation (deg)."""
        return float(np.degrees(rotation_angle(self.D[:3, :3])))

    def describe(self) -> str:
        """One line for an operator: the correction found, or why there is none."""
        if not self.applied:
            return f"not corrected: {self.note} (model placed by the mean anchor)"
        return (
            f"correction {self.translation_mm:.2f} mm / {self.rotation_deg:.3f} deg "
            f"(+/- {self.sigma_mm:.2f} mm / {self.sigma_deg:.3f} deg) from {len(self.views)} views, "
            f"rotation spread {self.spread_deg:.0f} deg; "
            "corrected T_flange_camera = the one used @ this correction"
        )

    def summary(self) -> dict:
        """JSON-friendly figures (mm, deg; None where not estimated)."""

        def num(v: float, digits: int) -> float | None:
            return round(float(v), digits) if np.isfinite(v) else None

        return {
            "applied": self.applied,
            "translation_mm": round(self.translation_mm, 4),
            "rotation_deg": round(self.rotation_deg, 4),
            "T_camera_camera": np.round(self.D, 9).tolist(),
            "views": self.views,
            "passes": self.passes,
            "spread_deg": num(self.spread_deg, 2),
            "sigma_mm": num(self.sigma_mm, 4),
            "sigma_deg": num(self.sigma_deg, 4),
            "residual_mm": num(self.residual_mm, 4),
            "residual_deg": num(self.residual_deg, 4),
            "note": self.note,
        }


def twist_of(T: np.ndarray) -> np.ndarray:
    """``(rotation vector, translation)`` of a transform: for a small motion, the displacement of a point
    ``s`` is ``omega x s + p``, the convention of the ICP step."""
    return np.concatenate([Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]])


def transform_of(x: np.ndarray) -> np.ndarray:
    """Inverse of :func:`twist_of`."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
    T[:3, 3] = x[3:]
    return T


def adjoint(T: np.ndarray) -> np.ndarray:
    """6x6 map of a twist ``(omega, p)`` in frame b to frame a for ``T = T_a_b``: ``T exp(x) T^-1``."""
    R, t = T[:3, :3], T[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = Ad[3:, 3:] = R
    Ad[3:, :3] = skew(t) @ R
    return Ad


def rotation_spread(Rs: Sequence[np.ndarray]) -> float:
    """Rotational diversity of a set of rotations about their least diverse axis (rad).

    ``2 asin(sqrt(lambda_min))`` of ``mean_i (R_i - R_mean)^T (R_i - R_mean)``: 0 when all rotations
    differ only about one common axis (then a correction about that axis is not observable; two
    rotations always do), 0.2 rad for I, Rx(0.3), Ry(0.3), 0.42 rad for Rx(+-0.3), Ry(+-0.3).
    """
    R = np.asarray(Rs, dtype=float)
    d = R - R.mean(axis=0)
    M = np.einsum("nji,njk->ik", d, d) / len(R)
    lam = max(float(np.linalg.eigvalsh(M)[0]), 0.0)
    return float(2.0 * np.arcsin(min(1.0, np.sqrt(lam))))


def _normal_equations(
    A: list[np.ndarray], B: list[np.ndarray], H: list[np.ndarray], w: np.ndarray, G: np.ndarray, D: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N 12x12, rhs, residual twists) of ``G' = exp(g) G``, ``D' = D exp(d)`` linearised at (G, D)."""
    N, rhs, res = np.zeros((12, 12)), np.zeros(12), []
    for Ai, Bi, Hi, wi in zip(A, B, H, w, strict=True):
        M = G @ Bi @ D
        r = twist_of(M @ invert(Ai))
        J = np.hstack([np.eye(6), adjoint(M)])
        N += wi * J.T @ Hi @ J
        rhs -= wi * J.T @ Hi @ r
        res.append(r)
    return N, rhs, np.asarray(res)


def _pinv_solve(N: np.ndarray, rhs: np.ndarray, rcond: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-norm solution of ``N x = rhs`` (symmetric N) and the pseudo-inverse of N."""
    e, V = np.linalg.eigh(N)
    keep = e > rcond * max(float(e.max()), 1e-300)
    Ni = (V[:, keep] / e[keep]) @ V[:, keep].T
    return Ni @ rhs, Ni


def _huber(m: np.ndarray) -> np.ndarray:
    """Huber weights of per-view residual norms ``m`` (scale 1.345 x 1.4826 MAD, floor 1e-6)."""
    s = 1.345 * max(1.4826 * float(np.median(m)), 1e-6)
    return np.where(m <= s, 1.0, s / np.maximum(m, 1e-300))


def fit_hand_eye(
    A: Sequence[np.ndarray],
    B: Sequence[np.ndarray],
    information: Sequence[np.ndarray],
    confidence: Sequence[float],
    *,
    min_spread: float = MIN_SPREAD,
    iterations: int = 20,
) -> HandEyeFit:
    """Solve ``A_i = G . B_i . D`` for one ``G`` and one ``D`` over the views (weighted least squares).

    ``A_i``: registered camera poses (ICP), ``B_i``: kinematic camera poses (eq. 1), ``information``:
    each view's 6x6 point-to-plane information (:attr:`IcpResult.information`, twist ``(omega, p)``
    about the base origin), ``confidence``: a weight per view (e.g. the ICP's inlier fraction; 0 leaves
    the view out). The residual of view i is the twist of ``G B_i D A_i^-1``, weighed by its
    information: directions the view's geometry hardly constrains (rotation about a cylinder) count
    little. Starts from the identity (the first Gauss-Newton step is the closed-form linear solve), and
    re-weights views by a Huber kernel on their residual's RMS point displacement.
    Returns ``applied=False`` with a note (and ``D`` = identity) when fewer than 3 views remain or their
    rotations are less diverse than ``min_spread`` (rad) about some axis.
    """
    keep = [i for i, c in enumerate(confidence) if c > 0]
    out = HandEyeFit(views=keep)
    if len(keep) < 3:
        out.note = f"{len(keep)} usable view(s): the hand-eye correction needs at least 3 with ICP"
        return out
    out.spread_deg = float(np.degrees(rotation_spread([B[i][:3, :3] for i in keep])))
    if out.spread_deg < np.degrees(min_spread):
        out.note = (
            f"the views' rotations differ by only {out.spread_deg:.1f} deg about some axis (need "
            f"{np.degrees(min_spread):.0f}): the hand-eye correction is not observable; scan from more "
            "varied tool orientations"
        )
        return out
    Av, Bv = [np.asarray(A[i], float) for i in keep], [np.asarray(B[i], float) for i in keep]
    Hv = [0.5 * (h + h.T) for h in (np.asarray(information[i], float) for i in keep)]
    conf = np.array([confidence[i] for i in keep], dtype=float)
    G, D, w = np.eye(4), np.eye(4), conf.copy()
    for it in range(iterations):
        N, rhs, res = _normal_equations(Av, Bv, Hv, w, G, D)
        x, _ = _pinv_solve(N, rhs)
        G, D = transform_of(x[:6]) @ G, D @ transform_of(x[6:])
        out.iterations = it + 1
        m = np.sqrt(np.abs(np.einsum("ni,nij,nj->n", res, np.asarray(Hv), res)))
        w = conf * _huber(m)
        if np.linalg.norm(x) < 1e-10:
            break
    N, _, res = _normal_equations(Av, Bv, Hv, w, G, D)
    chi2 = float(np.einsum("n,ni,nij,nj->", w, res, np.asarray(Hv), res))
    dof = 6 * len(keep) - 12
    _, Ni = _pinv_solve(N, np.zeros(12))
    if dof > 0:
        cov = Ni[6:, 6:] * chi2 / dof
        out.sigma_deg = float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3])[-1], 0.0))))
        out.sigma_mm = float(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:])[-1], 0.0)) * 1e3)
    Bc = [Bi @ D for Bi in Bv]  # the views as one correction places them, in the model's frame via G
    dev = [G @ b @ invert(a) for a, b in zip(Av, Bc, strict=True)]
    out.residual_deg = float(np.degrees(np.sqrt(np.mean([rotation_angle(d[:3, :3]) ** 2 for d in dev]))))
    shift = [d[:3, :3] @ a[:3, 3] + d[:3, 3] - a[:3, 3] for d, a in zip(dev, Av, strict=True)]
    out.residual_mm = float(np.sqrt(np.mean(np.sum(np.square(shift), axis=1))) * 1e3)
    out.D, out.G, out.weights, out.applied = D, G, [float(v) for v in w], True
    return out
