"""The seam stage's settings: one object for :func:`~.pipeline.extract_seams` (:class:`SeamSettings`) and
the one it derives for the chaining step (:class:`ChainSettings`). Lengths in metres, angles in radians."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
from weldcell.sdk.errors import DataError

from .candidates import Classifying
from .model import WELDABLE, _positive


@dataclass(frozen=True)
class SeamSettings:
    """Settings of :func:`~.pipeline.extract_seams` (see its docstring for each field's role).

    Eqs. 11-17: ``m`` (minimum neighbourhood, eq. 11), ``t`` (threshold on ``Tr(H)^3/Det(H)``, eq. 16,
    >= 27), ``sigma`` (Gaussian of eq. 17; None = per point, as the paper), ``radius`` (r of eq. 11;
    None = ``radius_factor`` x median spacing), ``k_max`` (neighbour columns), ``floor`` (noise floor
    added to H, x median Tr(H)/3), ``min_intensity`` (edge points also need I >= this, eq. 12).
    Classes: ``up`` (None: normals without a given orientation face the sensor side found from the scan
    itself, :mod:`~.orientation`; a direction: the former heuristic, towards it where not steep),
    ``joints`` (classes that become seams), ``contact_seams`` (keep the part's contact lines with the
    plane it rests on or is held against, :mod:`~.support`; default: dropped), ``coarse_reach``
    (neighbourhoods reach at least this x the scan's coarser sampling spacing, e.g. between the lines
    of a laser line scan), ``min_crease_angle`` / ``groove_max_angle`` / ``class_radius_factor`` (side
    fits at this x r),
    ``max_incidence`` (both sides must face a recorded camera at less than this).
    Chaining: ``cluster_eps`` (None = 2 r), ``spacing`` (None = r), ``min_seam_length``,
    ``smooth_window`` (nodes), ``smooth_length``, ``refine``, ``fit_radius`` (None = max(class radius,
    8 mm)), ``max_gap``, ``max_grow``, ``wall_radius`` (None = 4 x fit radius; 0 keeps the side planes).
    """

    m: int = 12
    t: float = 40.0
    sigma: float | None = None
    radius: float | None = None
    radius_factor: float = 3.0
    k_max: int = 32
    floor: float = 1.0
    min_intensity: float = 0.15
    up: tuple[float, float, float] | None = None
    contact_seams: bool = False
    coarse_reach: float = 1.25
    joints: tuple[str, ...] = ("concave", "groove")
    min_crease_angle: float = float(np.deg2rad(35.0))
    groove_max_angle: float = float(np.deg2rad(75.0))
    class_radius_factor: float = 2.0
    cluster_eps: float | None = None
    spacing: float | None = None
    min_seam_length: float = 0.01
    smooth_window: int = 5
    refine: bool = True
    fit_radius: float | None = None
    max_gap: float = 0.03
    max_grow: float = 0.3
    smooth_length: float = 0.06
    max_incidence: float = float(np.deg2rad(75.0))
    wall_radius: float | None = None

    @classmethod
    def of(cls, settings: SeamSettings | None = None, **overrides: object) -> SeamSettings:
        """``settings`` (default: the defaults) with ``overrides`` replaced; unknown names are an error."""
        base = settings if settings is not None else cls()
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise DataError(
                f"unknown seam setting(s) {', '.join(unknown)}", f"use only {', '.join(sorted(names))}"
            )
        if "joints" in overrides:
            overrides["joints"] = tuple(overrides["joints"])  # type: ignore[arg-type]
        return replace(base, **overrides) if overrides else base

    def check(self) -> None:
        """One clear error for the first bad value."""
        if self.m < 3:
            raise DataError(f"m must be >= 3, got {self.m}", "use m of about 10-20 neighbours")
        if not np.isfinite(self.t) or self.t < 27.0:
            raise DataError(
                f"t must be >= 27 (the minimum of Tr^3/Det, eq. 16), got {self.t}", "use t of 30-100"
            )
        for name in self.joints:
            if name not in WELDABLE:
                raise DataError(f"unknown joint class {name!r}", f"choose from {sorted(WELDABLE)}")
        for name in ("radius", "sigma", "spacing", "fit_radius"):
            _positive(getattr(self, name), name)
        w = self.wall_radius
        if w is not None and (not np.isfinite(w) or w < 0):
            raise DataError(
                f"wall_radius must be >= 0 m, got {w}", "pass e.g. 0.024, 0 to keep the side planes"
            )
        if not np.isfinite(self.max_gap) or self.max_gap < 0:
            raise DataError(
                f"max_gap must be >= 0 m, got {self.max_gap}", "pass e.g. 0.03 (0 disables bridging)"
            )
        if not np.isfinite(self.max_grow) or self.max_grow < 0:
            raise DataError(
                f"max_grow must be >= 0 m, got {self.max_grow}", "pass e.g. 0.3 (0 disables tracing)"
            )
        _positive(self.smooth_length, "smooth_length")
        _positive(self.coarse_reach, "coarse_reach")
        if self.up is not None and (len(self.up) != 3 or not np.linalg.norm(self.up) > 0):
            raise DataError(f"up must be a non-zero 3-vector or None, got {self.up}", "pass up=None")

    def class_radius(self, r: float, r_fine: float) -> float:
        """Radius (m) of the side fits that classify edge points: ``class_radius_factor`` x the radius
        ``r_fine`` of the fine spacing, but at least the eq. 11 radius ``r`` (which reaches across an
        anisotropic scan's coarse spacing)."""
        return max(self.class_radius_factor * r_fine, r)

    def classifying(self) -> Classifying:
        """The edge classification's settings (:func:`~.candidates.classify_edges`) from this object."""
        return Classifying(
            min_crease_angle=self.min_crease_angle,
            groove_max_angle=self.groove_max_angle,
            max_incidence=self.max_incidence,
        )

    def chain(self, r: float, r_fine: float | None = None) -> ChainSettings:
        """The chaining settings for eq. 11 radius ``r`` (m) and ``r_fine`` (m, default r): the radius
        the fine spacing alone gives (smaller on an anisotropic scan)."""
        r_fine = r if r_fine is None else r_fine
        R = self.class_radius(r, r_fine)
        approach_radius = self.fit_radius or max(R, 0.008)
        return ChainSettings(
            eps=self.cluster_eps or 2.0 * r,
            spacing=self.spacing or r_fine,
            side_radius=max(R, 0.006),
            approach_radius=approach_radius,
            min_length=self.min_seam_length,
            smooth_window=self.smooth_window,
            min_crease_angle=self.min_crease_angle,
            groove_max_angle=self.groove_max_angle,
            joints=tuple(self.joints),
            refine=self.refine,
            max_gap=self.max_gap,
            max_grow=self.max_grow,
            smooth_length=self.smooth_length,
            wall_radius=4.0 * approach_radius if self.wall_radius is None else self.wall_radius,
        )


@dataclass(frozen=True)
class ChainSettings:
    """Settings of :func:`~.pipeline.chain_seams` (lengths in m, angles in rad).

    ``eps`` link distance of the clustering; ``spacing`` node / resampling step; ``side_radius`` radius
    of the side-plane fits that place the nodes, ``approach_radius`` of those that give the approach;
    ``min_length`` shortest seam kept; ``smooth_window`` (nodes) / ``smooth_length`` (m) smoothing;
    ``min_crease_angle`` / ``groove_max_angle`` joint classes; ``joints`` classes kept;
    ``max_approach_angle`` linked points' approach must agree within it; ``min_fit_fraction`` of the
    nodes must show two side planes; ``refine`` snaps nodes onto the side planes; ``max_gap`` /
    ``max_gap_angle`` bridging; ``max_grow`` / ``grow_min_crease_angle`` tracing beyond the ends;
    ``wall_radius`` quadric wall patches of curved seams (0 disables).
    """

    eps: float
    spacing: float
    side_radius: float
    min_length: float
    smooth_window: int
    min_crease_angle: float
    groove_max_angle: float = float(np.deg2rad(75.0))
    joints: tuple[str, ...] = ("concave", "groove")
    max_approach_angle: float = float(np.deg2rad(60.0))
    min_fit_fraction: float = 0.6
    refine: bool = True
    max_gap: float = 0.03
    max_gap_angle: float = float(np.deg2rad(20.0))
    smooth_length: float = 0.06
    approach_radius: float = 0.0
    max_grow: float = 0.3
    grow_min_crease_angle: float = float(np.deg2rad(20.0))
    wall_radius: float = 0.0
