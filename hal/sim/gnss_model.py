"""A GNSS receiver model: u-blox M8T standalone (metre-level, slowly wandering error), optional RTK,
fix loss under roofs and degraded accuracy next to tall steel (multipath).

Standalone: the M8T's datasheet gives 2.5 m CEP horizontal (GPS+GLONASS); CEP 2.5 m is a 1-sigma of
about 2.1 m per horizontal axis. The error is not white: it is a first-order Gauss-Markov process
(correlation time ``tau`` = 60 s, typical of ionospheric/ephemeris errors), plus 0.3 m white noise;
vertical sigma is 1.7 x horizontal. RTK ("rtk-fixed"): 1 cm + 1 ppm horizontal, 2 cm vertical.
Under a roof the receiver has no fix (``fix_type`` "none", NaN coordinates); when the sky comes back
it needs ``reacquire`` seconds (hot start, < 1 s for the M8T) before the next fix. Within
``multipath_radius`` of steel the sigma doubles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EARTH_RADIUS = 6378137.0


@dataclass
class GnssModel:
    rate: float = 5.0
    mode: str = "standalone"
    """'standalone' (M8T alone) or 'rtk' (with a base station's corrections)."""
    sigma_h: float = 2.1
    sigma_white: float = 0.3
    tau: float = 60.0
    rtk_sigma_h: float = 0.01
    rtk_sigma_v: float = 0.02
    reacquire: float = 1.0
    multipath_radius: float = 1.5
    origin: tuple[float, float, float] = (22.5966, 113.9976, 30.0)


def enu_to_geodetic(enu: np.ndarray, origin: tuple[float, float, float]) -> tuple[float, float, float]:
    """Local tangent-plane ENU (m) to latitude/longitude (deg) and altitude (m), small-area approximation."""
    lat0, lon0, alt0 = origin
    lat = lat0 + np.degrees(enu[1] / EARTH_RADIUS)
    lon = lon0 + np.degrees(enu[0] / (EARTH_RADIUS * np.cos(np.radians(lat0))))
    return float(lat), float(lon), float(alt0 + enu[2])


class GnssSimulator:
    """Produces fixes at ``model.rate`` for an antenna whose true ENU position is ``position(t)``."""

    def __init__(
        self, model: GnssModel, position, sky_blocked=None, steel_distance=None, seed: int = 0
    ) -> None:
        self.model = model
        self.position = position
        self.sky_blocked = sky_blocked
        self.steel_distance = steel_distance
        self.rng = np.random.default_rng(seed)
        m = model
        self.bias = (
            np.zeros(3)
            if m.mode == "rtk"
            else self.rng.normal(0, 1, 3) * [m.sigma_h, m.sigma_h, 1.7 * m.sigma_h]
        )
        self.t_next = 0.0
        self.sky_since: float | None = -np.inf  # powered up with a fix

    def samples_until(self, t_end: float) -> list[dict]:
        """Fixes with time in [t_next, t_end]: dicts with t, enu (or None), fix_type, sigma_h/v, truth."""
        out = []
        dt = 1.0 / self.model.rate
        while self.t_next <= t_end + 1e-9:
            out.append(self._one(self.t_next, dt))
            self.t_next += dt
        return out

    def _one(self, t: float, dt: float) -> dict:
        m = self.model
        p = np.asarray(self.position(t), float)
        blocked = bool(self.sky_blocked(p[None])[0]) if self.sky_blocked else False
        if blocked:
            self.sky_since = None
            return {"t": t, "enu": None, "fix_type": "none", "sigma_h": np.inf, "sigma_v": np.inf, "truth": p}
        if self.sky_since is None:
            self.sky_since = t
        if t - self.sky_since < m.reacquire:
            return {"t": t, "enu": None, "fix_type": "none", "sigma_h": np.inf, "sigma_v": np.inf, "truth": p}
        scale = 1.0
        if self.steel_distance is not None and self.steel_distance(p[None])[0] < m.multipath_radius:
            scale = 2.0
        if m.mode == "rtk":
            sh, sv = m.rtk_sigma_h * scale, m.rtk_sigma_v * scale
            err = self.rng.normal(0, 1, 3) * [sh, sh, sv]
            kind = "rtk-fixed"
        else:
            a = np.exp(-dt / m.tau)
            sig = np.array([m.sigma_h, m.sigma_h, 1.7 * m.sigma_h])
            self.bias = a * self.bias + np.sqrt(1 - a * a) * sig * self.rng.normal(0, 1, 3)
            err = self.bias * scale + self.rng.normal(0, m.sigma_white, 3)
            sh, sv = np.hypot(m.sigma_h, m.sigma_white) * scale, 1.7 * m.sigma_h * scale
            kind = "3d"
        return {
            "t": t,
            "enu": p + err,
            "fix_type": kind,
            "sigma_h": float(sh),
            "sigma_v": float(sv),
            "truth": p,
        }
