"""Low-latency smoothing of marker displacement at camera rate.

The paper does not say how the ArUco displacement is smoothed; raw PnP translations jitter by a few
hundredths of a millimetre. We use the One-Euro filter (Casiez, Roussel, Vogel, CHI 2012): a first-order
low-pass whose cut-off rises with the signal's speed, so a resting finger is smoothed strongly while a
fast deformation passes with little lag. It handles a variable frame interval (dropped frames).
"""

from __future__ import annotations

import math

import numpy as np
from weldcell.sdk.errors import UsageError


def _alpha(cutoff_hz: float, dt: float) -> float:
    tau = 1.0 / (2.0 * math.pi * cutoff_hz)
    return 1.0 / (1.0 + tau / dt)


class OneEuroFilter:
    """Vector One-Euro filter. ``min_cutoff`` (Hz) sets smoothing at rest, ``beta`` (s/m) the speed gain."""

    def __init__(self, min_cutoff: float = 3.0, beta: float = 200.0, d_cutoff: float = 5.0) -> None:
        if min_cutoff <= 0 or d_cutoff <= 0 or beta < 0:
            raise UsageError(
                "OneEuroFilter: min_cutoff and d_cutoff must be > 0 and beta >= 0",
                "use e.g. min_cutoff=3 Hz, beta=200 s/m, d_cutoff=5 Hz",
            )
        self.min_cutoff, self.beta, self.d_cutoff = min_cutoff, beta, d_cutoff
        self.reset()

    def reset(self) -> None:
        """Forget the history (after a long marker loss)."""
        self._x: np.ndarray | None = None
        self._dx: np.ndarray | None = None
        self._t: float | None = None

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if self._x is None or self._t is None:
            self._x, self._dx, self._t = x.copy(), np.zeros_like(x), t
            return x.copy()
        dt = t - self._t
        if dt <= 0:
            return self._x.copy()
        dx = (x - self._x) / dt
        a_d = _alpha(self.d_cutoff, dt)
        self._dx = a_d * dx + (1.0 - a_d) * self._dx
        cutoff = self.min_cutoff + self.beta * float(np.linalg.norm(self._dx))
        a = _alpha(cutoff, dt)
        self._x = a * x + (1.0 - a) * self._x
        self._t = t
        return self._x.copy()


class PassThrough:
    """No filtering (``filter="none"``)."""

    def reset(self) -> None:
        pass

    def __call__(self, x: np.ndarray, t: float) -> np.ndarray:
        return np.asarray(x, dtype=float).copy()
