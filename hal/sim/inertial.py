"""A 9-axis MEMS IMU model: gyroscope and accelerometer with white noise, bias random walk and a
turn-on bias, magnetometer with hard- and soft-iron distortion and local disturbance near steel.

Continuous-time densities (the Kalibr / IEEE-952 convention)::

    gyro  : w_meas = w_true + b_g + n_g,   n_g ~ N(0, sigma_g^2 / dt),   b_g' = n_bg ~ sigma_bg
    accel : f_meas = f_true + b_a + n_a,   n_a ~ N(0, sigma_a^2 / dt),   b_a' = n_ba ~ sigma_ba

with ``f_true = R_world_imu^T (a_world - g_world)`` the specific force (g_world = [0, 0, -9.80665]).
Defaults are those of a BMI088/ICM-20948-class consumer IMU (the Handsfree A9 class): gyro noise
0.014 deg/s/sqrt(Hz) = 2.4e-4 rad/s/sqrt(Hz), accelerometer 175 ug/sqrt(Hz) = 1.7e-3 m/s^2/sqrt(Hz),
bias instabilities of a few deg/h and tens of ug giving random walks 2e-5 rad/s^2/sqrt(Hz) and
3e-4 m/s^3/sqrt(Hz); turn-on biases 0.3 deg/s and 5 mg (1 sigma, after factory calibration).
Outputs saturate at the ranges
(2000 deg/s, 16 g). The magnetometer measures ``S (R^T (m_earth + m_local)) + h`` (S soft iron, h
hard iron, both in the sensor frame) with 0.3 uT noise; ``m_local`` is a dipole-like anomaly of
``steel_strength`` uT at 1 m from the nearest steel mass, falling with 1/d^3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from weldcell.hal.sim.site import GRAVITY

_NOISE_BLOCK = 256
"""Samples of noise drawn at a time (see :meth:`ImuSimulator._noise`)."""


@dataclass
class ImuModel:
    """Noise and bias parameters of an IMU (SI units, densities per sqrt(Hz))."""

    rate: float = 200.0
    gyro_noise_density: float = 2.4e-4
    accel_noise_density: float = 1.7e-3
    gyro_random_walk: float = 2.0e-5
    accel_random_walk: float = 3.0e-4
    gyro_turn_on_bias: float = 0.005
    accel_turn_on_bias: float = 0.05
    gyro_range: float = np.radians(2000.0)
    accel_range: float = 16 * GRAVITY
    mag_earth: tuple[float, float, float] = (0.0, 37.8, -25.4)
    """Earth's field in the world (ENU) frame, uT (Shenzhen-like: 45.5 uT, inclination -34 deg)."""
    mag_noise: float = 0.3
    hard_iron: float = 8.0
    """Std of the hard-iron offset (uT) drawn per device."""
    soft_iron: float = 0.05
    """Std of the soft-iron matrix off-identity terms."""
    steel_strength: float = 15.0


class ImuSimulator:
    """Samples an IMU rigidly mounted on a moving body (``kinematics(t)`` gives its truth).

    ``kinematics(t) -> (R_world_body (N,3,3), v (N,3), a_world (N,3), w_body (N,3), p_world (N,3))``.
    The IMU sits at ``T_body_imu``; lever-arm terms (w x (w x r) + dw x r) are included.
    """

    def __init__(
        self, model: ImuModel, kinematics, T_body_imu: np.ndarray, seed: int = 0, steel_distance=None
    ) -> None:
        self.model = model
        self.kinematics = kinematics
        self.T_body_imu = np.asarray(T_body_imu, float)
        self.rng = np.random.default_rng(seed)
        m = model
        self.b_g = self.rng.normal(0.0, m.gyro_turn_on_bias, 3)
        self.b_a = self.rng.normal(0.0, m.accel_turn_on_bias, 3)
        self.hard = self.rng.normal(0.0, m.hard_iron, 3)
        self.soft = np.eye(3) + self.rng.normal(0.0, m.soft_iron, (3, 3))
        self.soft = (self.soft + self.soft.T) / 2
        self.steel_distance = steel_distance
        self.k_next = 0
        """Index of the next sample (time ``k * dt``: exact, however the samples are requested)."""
        self.bias_log: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._noise_buf = np.zeros((0, 15))

    def _noise(self, n: int) -> np.ndarray:
        """The next ``n`` rows of standard normal draws (gyro and accel random walk, gyro, accel and
        magnetometer white noise: 5 x 3 columns). Drawn in fixed blocks, so sample k gets the same noise
        however the samples are requested (one call for 1 s or 200 calls of 5 ms: a stream's reader
        thread polls at whatever moments the machine's load allows)."""
        while len(self._noise_buf) < n:
            self._noise_buf = np.vstack([self._noise_buf, self.rng.standard_normal((_NOISE_BLOCK, 15))])
        out, self._noise_buf = self._noise_buf[:n], self._noise_buf[n:]
        return out

    @property
    def dt(self) -> float:
        return 1.0 / self.model.rate

    @property
    def t_next(self) -> float:
        """Time of the next sample [s]."""
        return self.k_next * self.dt

    @t_next.setter
    def t_next(self, t: float) -> None:
        self.k_next = int(np.ceil(t / self.dt - 1e-9))

    def samples_until(self, t_end: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        """All samples with time in [t_next, t_end]: times (N,), accel (N,3), gyro (N,3), mag (N,3)
        and truth {"R", "b_g", "b_a", "saturated"}."""
        k_end = int(np.floor(t_end / self.dt + 1e-9))
        n = k_end - self.k_next + 1
        if n <= 0:
            z = np.zeros((0, 3))
            return np.zeros(0), z, z, z, {"b_g": z, "b_a": z, "saturated": np.zeros(0, bool)}
        t = np.arange(self.k_next, k_end + 1) * self.dt
        self.k_next = k_end + 1
        R_wb, _, a_w, w_b, p_w = self.kinematics(t)
        R_bi, r = self.T_body_imu[:3, :3], self.T_body_imu[:3, 3]
        # angular acceleration of the body by finite difference of w (smooth: splines)
        _, _, _, w_b2, _ = self.kinematics(t + 1e-4)
        dw = (w_b2 - w_b) / 1e-4
        a_lever_b = np.cross(w_b, np.cross(w_b, r)) + np.cross(dw, r)
        a_imu_w = a_w + np.einsum("nij,nj->ni", R_wb, a_lever_b)
        R_wi = R_wb @ R_bi
        f_true = np.einsum("nji,nj->ni", R_wi, a_imu_w + np.array([0.0, 0.0, GRAVITY]))
        w_true = w_b @ R_bi  # R_bi^T w_b
        m, dt = self.model, self.dt
        z = self._noise(n)
        # the random walks summed sample after sample from the last bias (bit-identical for any chunking)
        bg = np.cumsum(np.vstack([self.b_g, z[:, 0:3] * (m.gyro_random_walk * np.sqrt(dt))]), axis=0)[1:]
        ba = np.cumsum(np.vstack([self.b_a, z[:, 3:6] * (m.accel_random_walk * np.sqrt(dt))]), axis=0)[1:]
        self.b_g, self.b_a = bg[-1].copy(), ba[-1].copy()
        gyro = w_true + bg + z[:, 6:9] * (m.gyro_noise_density / np.sqrt(dt))
        accel = f_true + ba + z[:, 9:12] * (m.accel_noise_density / np.sqrt(dt))
        sat = (np.abs(gyro) > m.gyro_range).any(1) | (np.abs(accel) > m.accel_range).any(1)
        gyro = np.clip(gyro, -m.gyro_range, m.gyro_range)
        accel = np.clip(accel, -m.accel_range, m.accel_range)
        p_imu = p_w + np.einsum("nij,j->ni", R_wb, r)
        field_w = np.tile(np.asarray(m.mag_earth, float), (n, 1))
        if self.steel_distance is not None:
            d = np.maximum(self.steel_distance(p_imu), 0.3)
            # anomaly along a fixed direction (induced magnetisation of vertical steel: mostly z)
            field_w += (m.steel_strength / d**3)[:, None] * np.array([0.3, -0.2, 1.0])
        mag = np.einsum("ij,nj->ni", self.soft, np.einsum("nji,nj->ni", R_wi, field_w)) + self.hard
        mag += z[:, 12:15] * m.mag_noise
        return t, accel, gyro, mag, {"R": R_wi, "b_g": bg, "b_a": ba, "saturated": sat}
