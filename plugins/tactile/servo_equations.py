"""The deformation servo's equations one by one (paper 003 §2.2.2, eqs. 14-18, Algorithm 2 lines 13, 16-24):
tool directions, torch position, REFINE, the SERVO velocity, the torch's angular velocity ω and the quintic
stop profile. The stateful controller that uses them is :mod:`weldcell.plugins.tactile.servo`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def tool_directions(alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """``t_d = [cos α, sin α]``, ``n_d = [-sin α, cos α]`` (§2.2.2)."""
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([c, s]), np.array([-s, c])


def torch_position(P_r: np.ndarray, t_d: np.ndarray, torch_offset: float) -> np.ndarray:
    """Eq. 14 / Alg. 2 line 9: ``P_t = P_r - ‖d‖ t_d``."""
    return np.asarray(P_r, dtype=float)[:2] - torch_offset * np.asarray(t_d, dtype=float)


def refine_point(P_r: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """REFINE (Alg. 2 line 17, eq. 15): ``P_s = P_r - δ``, δ = δ^{n_s} n_s + δ^{t_s} t_s (plane vector)."""
    return np.asarray(P_r, dtype=float)[:2] - np.asarray(delta, dtype=float)[:2]


def split_deformation(delta: np.ndarray, t_s: np.ndarray, n_s: np.ndarray) -> tuple[float, float]:
    """δ^{n_s}, δ^{t_s}: projections of the plane deformation on the seam normal and tangent (eq. 15)."""
    d = np.asarray(delta, dtype=float)[:2]
    return float(d @ n_s), float(d @ t_s)


def servo_velocity(
    t_v: np.ndarray,
    n_v: np.ndarray,
    delta_n: float,
    delta_d: float,
    speed: float,
    k_p: float,
    max_normal_speed: float = math.inf,
) -> np.ndarray:
    """SERVO (eq. 16, Alg. 2 line 24): ``V_r = V_const t_v - k_p (δ^{n_s} - δ_d) n_v`` (normal clamped)."""
    vn = float(np.clip(-k_p * (delta_n - delta_d), -max_normal_speed, max_normal_speed))
    return speed * np.asarray(t_v, dtype=float) + vn * np.asarray(n_v, dtype=float)


@dataclass(frozen=True)
class OmegaSolution:
    """ω from eqs. 17-18 and how close to the n_d ⟂ n_t singularity it was computed."""

    omega: float
    cos_nd_nt: float  # n_d · n_t
    weight: float  # 1 = regular, 0 = at the singularity
    exact: float  # the undamped value (may be ±inf at the singularity)


# parameters: the terms of eqs. 14-18 (velocities, frames, torch offset, gains); called from one place
def torch_angular_velocity(
    V_r: np.ndarray,
    t_d: np.ndarray,
    n_d: np.ndarray,
    n_t: np.ndarray,
    torch_offset: float,
    lateral_error: float = 0.0,
    torch_gain: float = 0.0,
    singular_cos: float = 0.35,
    damping: float = 0.3,
    heading_error: float = 0.0,
    align_gain: float = 0.0,
    omega_max: float = math.inf,
) -> OmegaSolution:
    """ω of the end effector so the torch moves along the refined path (eqs. 17-18, Alg. 2 line 13).

    Regular case: ``V_t·n_t = -k_t e_t`` with ``V_t = V_r - ω‖d‖n_d`` gives
    ``ω = (V_r·n_t + k_t e_t) / (‖d‖ n_d·n_t)`` (k_t = 0: the paper's eq. 18).
    Near ``n_d ⟂ n_t`` (|n_d·n_t| < singular_cos) the division is damped — ``ω = a b / (a² + λ²)`` with
    ``a = ‖d‖ n_d·n_t``, ``λ² = (damping ‖d‖)² (1 - (c/singular_cos)²)`` — and blended with a heading
    re-alignment ``align_gain · heading_error`` (the angle from t_d to the path tangent t_t, turning
    which raises |n_d·n_t|) by the weight ``|c|/singular_cos``. The result is finite for every input
    and saturated at ``omega_max``.
    """
    n_t = np.asarray(n_t, dtype=float)
    c = float(np.asarray(n_d, dtype=float) @ n_t)
    a = torch_offset * c
    b = float(np.asarray(V_r, dtype=float)[:2] @ n_t) + torch_gain * lateral_error
    exact = b / a if a != 0.0 else (math.copysign(math.inf, b) if b != 0 else 0.0)
    if abs(c) >= singular_cos:
        w, omega = 1.0, exact
    else:
        lam2 = (damping * torch_offset) ** 2 * (1.0 - (c / singular_cos) ** 2)
        w = abs(c) / singular_cos
        omega = w * (a * b / (a * a + lam2)) + (1.0 - w) * align_gain * heading_error
    omega = float(np.clip(omega, -omega_max, omega_max))
    return OmegaSolution(omega, c, w, exact)


def quintic_ramp_down(tau: float) -> float:
    """1 → 0 over tau ∈ [0, 1] with zero 1st and 2nd derivatives at both ends (bounded jerk)."""
    x = min(max(tau, 0.0), 1.0)
    return 1.0 - x**3 * (10.0 - 15.0 * x + 6.0 * x * x)
