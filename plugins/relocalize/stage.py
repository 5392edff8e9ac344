"""The ``relocalizer`` stage (kind ``relocalizer``, :class:`weldcell.sdk.stages.RelocalizerStage`): what a job
(the cell-4 ``map`` job's second visit) uses to relocalize against a prior map without importing this
plugin's modules."""

from __future__ import annotations

import math

import numpy as np

from .relocalize import PriorMap, Priors, RelocalizationResult, RelocalizeSettings, prepare, relocalize

__all__ = ["RelocalizeSettings", "Relocalizer"]


class Relocalizer:
    """``prepare(points)`` once per loaded prior map, then ``(prior, current, **priors)`` per attempt."""

    def __init__(self, settings: RelocalizeSettings | None = None) -> None:
        self.settings = settings or RelocalizeSettings()

    def prepare(self, points: np.ndarray) -> PriorMap:
        return prepare(np.asarray(points, float), self.settings).warm(self.settings)

    def __call__(
        self,
        prior: PriorMap | np.ndarray,
        current: np.ndarray,
        yaw: float | None = None,
        yaw_sigma: float = math.radians(5.0),
        position: np.ndarray | None = None,
        position_sigma: float = 2.0,
        keyframe_positions: np.ndarray | None = None,
        current_keyframes: np.ndarray | None = None,
    ) -> RelocalizationResult:
        """``keyframe_positions``: the prior map's key frames; with ``current_keyframes`` (the current map's)
        they are sampled within twice the current travelled distance (§II-E)."""
        from .inputs import sample_keyframes

        if position is None and keyframe_positions is not None and len(keyframe_positions):
            keyframe_positions = sample_keyframes(
                np.asarray(keyframe_positions, float), current_keyframes, 2.0
            )
        pr = Priors(
            yaw,
            yaw_sigma,
            None if position is None else np.asarray(position, float),
            position_sigma,
            keyframe_positions,
        )
        return relocalize(prior, current, pr, self.settings)
