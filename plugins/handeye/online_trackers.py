"""The online estimators of the ``calibrate`` job, fed one flange centre at a time.

Eye-on-base, :class:`PoolTracker`: Algorithm 1 (paper 003) online on (centre in the camera, the
flange's feature in the base). Eye-in-hand, :class:`FeatureTracker`: ``X c_i = inv(T_base_flange_i) q``
refit on every centre. Both say when the estimate is good enough (``converged``) and where the next
pose's centre should appear (``predicted``), which crops the next scan.
"""

from __future__ import annotations

import numpy as np
from weldcell.plugins.handeye.featurefit import fit_with_unknown_point, translation_sigma
from weldcell.plugins.handeye.stages import predicted_p_cam
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import invert, pose_error
from weldcell.sdk.pointfit import scaled_svd_fit


class PoolTracker:
    """Eye-on-base: Algorithm 1 online (:class:`IncrementalPool`) on (centre in the camera, the
    flange's feature in the base)."""

    cost_name = "Algorithm 1 cost"

    def __init__(self, pool, feature: np.ndarray) -> None:
        self.pool, self.feature = pool, feature
        self.c: list[np.ndarray] = []
        self.d: list[np.ndarray] = []

    def add(self, c: np.ndarray, T_base_flange: np.ndarray, normal: np.ndarray) -> None:
        self.c.append(c)
        self.d.append((T_base_flange @ np.r_[self.feature, 1.0])[:3])
        self.pool.add(c, self.d[-1])

    @property
    def H(self) -> np.ndarray | None:
        return self.pool.H

    @property
    def cost(self) -> float:
        return self.pool.cost

    @property
    def converged(self) -> bool:
        return self.pool.converged

    def predicted(self, T_goal: np.ndarray) -> np.ndarray | None:
        return None if self.H is None else predicted_p_cam(self.H, T_goal, self.feature)

    def row(self, truth: np.ndarray) -> dict:
        row = {} if self.H is None else {"pool_error": pose_error(self.H, truth)}
        if len(self.c) >= 4:
            row["all_data_error"] = pose_error(scaled_svd_fit(np.array(self.c), np.array(self.d)).T, truth)
        return row

    def metrics(self, index: list[int]) -> dict:
        return {
            "pool": [index[j] for j in self.pool.pool],
            "pool_cost_m": self.pool.cost,
            "pool_converged": self.pool.converged,
        }

    def figures(self, truth: np.ndarray, result, q_true) -> dict:
        if self.H is None:
            return {}
        dt, dr = pose_error(self.H, truth)
        return {
            "algorithm1_error_vs_truth": {"translation_mm": dt * 1e3, "rotation_deg": float(np.degrees(dr))}
        }


class FeatureTracker:
    """Eye-in-hand: ``X c_i = inv(T_base_flange_i) q`` refit on every centre so far
    (:func:`fit_with_unknown_point`); its cost is the fit's predicted 1-sigma translation error.
    Scans are cropped around where the plate should appear: by the prior (nominal mount and
    ``feature_prior``) until the fit predicts better than :attr:`TRUST` (m), then by the fit."""

    cost_name = "predicted error (1 sigma)"
    TRUST = 0.005

    def __init__(self, flange, seed: int, X_prior: np.ndarray, q_prior) -> None:
        self.flange, self.seed = flange, seed
        self.prior = (np.asarray(X_prior, float), np.asarray(q_prior, float))
        self.c: list[np.ndarray] = []
        self.B: list[np.ndarray] = []
        self.n: list[np.ndarray] = []
        self.fit = None
        self.cost = float("inf")

    def add(self, c: np.ndarray, T_base_flange: np.ndarray, normal: np.ndarray) -> None:
        self.c.append(c)
        self.B.append(invert(T_base_flange))
        self.n.append(normal)
        C, B, fs = np.array(self.c), np.array(self.B), self.flange.s
        try:
            fit = fit_with_unknown_point(
                C,
                B,
                len(C) >= 8,
                fs.n_sigma,
                fs.min_threshold,
                rng=self.seed,
                normals=np.array(self.n),
                normal_weight=fs.normal_weight,
            )
        except DataError:  # too few centres or too little rotation so far
            return
        self.fit, self.cost = fit, translation_sigma(C, B, fit)

    @property
    def converged(self) -> bool:
        return self.fit is not None and self.cost <= self.flange.e_required

    def predicted(self, T_goal: np.ndarray) -> np.ndarray:
        X, q = (self.fit.T, self.fit.q) if self.cost < self.TRUST else self.prior
        return (invert(X) @ invert(T_goal) @ np.r_[q, 1.0])[:3]

    def row(self, truth: np.ndarray) -> dict:
        return {} if self.fit is None else {"all_data_error": pose_error(self.fit.T, truth)}

    def metrics(self, index: list[int]) -> dict:
        return {"predicted_error_m": self.cost, "converged": self.converged}

    def figures(self, truth: np.ndarray, result, q_true) -> dict:
        q = result.extra.get("feature_base")
        if q is None or q_true is None:
            return {}
        return {"feature_error_mm": float(np.linalg.norm(np.asarray(q) - q_true) * 1e3)}
