"""Seam-stage data: the per-point class labels, the method's fixed constants (each with the reason it
has its value), :class:`SeamPolyline` and :class:`SeamExtraction`, and the input checks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from weldcell.sdk.errors import DataError

#: per-point class labels of :attr:`SeamExtraction.labels`
NONE, CONCAVE, GROOVE, CONVEX, BOUNDARY, WEAK = 0, 1, 2, 3, 4, 5
LABEL_NAMES = {
    NONE: "none",
    CONCAVE: "concave",
    GROOVE: "groove",
    CONVEX: "convex",
    BOUNDARY: "boundary",
    WEAK: "weak",
}
WELDABLE = {"concave": CONCAVE, "groove": GROOVE}
#: smallest included angle of a weldable crease: sides that face each other more closely are the two faces
#: of a thin sheet or a scan border whose normals flipped, not a groove a torch (or a camera) can see into
MIN_INCLUDED_ANGLE = np.deg2rad(25.0)
#: side-plane fits of the refinement ignore points more than this x the fit radius behind the other
#: side's plane or off their own (a third surface, e.g. the top of a lap joint's upper plate beyond its
#: 6 mm edge face)
BEHIND_TOL = 0.15
#: a fit that left out more than this fraction of its points saw a third surface: it is fitted again
#: from the points within CORE_FRACTION x its radius, and the node takes the approach of the smaller
#: (position) radius
THIRD_SURFACE = 0.1
CORE_FRACTION = 0.5
#: ... and when at least this share of those core points lies more than BEHIND_TOL x the radius in front
#: of its side's plane (a step: a thin lap plate's top beside its edge face; synthetic 2.5 mm lap: 15 %),
#: its fits start from each side's majority layer (``sides._step_layer``). Noise alone puts a negligible
#: share there (the band is ~3 noise sigmas at the 6 mm side radius of a 0.3 mm-noise cloud)
STEP_SHARE = 0.05
#: acute creases (included angle below TOE_INCLUDED) whose position at the approach and the side radius
#: differ by more than TOE_SHIFT (m) take their position from planes within TOE_RADIUS x the side radius
#: (55 deg: the Y-pipe's 45 deg toe, not a 60 deg V-groove, whose root faces also make the two positions
#: differ; there the 4 mm planes only add ripple to the seam line, 0.67 -> 1.25 deg in the demo job)
TOE_INCLUDED = np.deg2rad(55.0)
TOE_SHIFT = 3e-4
TOE_RADIUS = 2.0 / 3.0
#: a node with more than this share of its side-radius points behind one side's plane and not in front
#: of the other (``refinement._convex_share``) is a convex edge, not a joint (the Y-pipe's branch rim:
#: 0.43 as the share of all left-out points, before 2026-11-25; a synthetic block edge 0.43-0.82; lap
#: joints 0 -- also 2-3 mm thin ones, whose plate top lies in front of the lower plate's plane)
CONVEX_DROPPED = 0.3
#: below this many rows (a trace step) LAPACK's eigh is faster than the vectorised closed form
SMALL_BATCH = 16
#: at most this many points per node in the curved-wall fits (memory: nodes x points x 6 floats)
WALL_MAX_POINTS = 8000
#: the side planes must differ by this much for the crease line to be defined (obtuse flanks: 145 deg)
WALL_MIN_CREASE = np.deg2rad(10.0)


@dataclass
class SeamPolyline:
    """One ordered weld seam: ``points`` (K, 3) along travel, ``normals`` (K, 3) unit approach
    directions (pointing into the joint, i.e. from the torch towards the work)."""

    id: int
    joint_class: str
    points: np.ndarray
    normals: np.ndarray
    closed: bool
    length: float

    @property
    def approach(self) -> np.ndarray:
        """Alias of :attr:`normals`: unit approach directions (K, 3)."""
        return self.normals


@dataclass
class SeamExtraction:
    """Result of :func:`extract_seams`. Per-point arrays have one row per input point."""

    edge_mask: np.ndarray  # (N,) bool, eq. 16 edge points
    score: np.ndarray  # (N,) Tr(H)^3 / Det(H), eq. 16
    intensity: np.ndarray  # (N,) edge intensity, eq. 12
    labels: np.ndarray  # (N,) int8, see LABEL_NAMES (NONE for non-edge points)
    seams: list[SeamPolyline]
    radius: float  # the radius r used (m)
    params: dict = field(default_factory=dict)

    def label_names(self) -> np.ndarray:
        """Per-point class names (N,)."""
        return np.array([LABEL_NAMES[int(v)] for v in range(6)])[self.labels]


def _as_points(points: np.ndarray, m: int) -> np.ndarray:
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3:
        raise DataError(
            f"points must be an (N, 3) array, got shape {P.shape}", "pass x, y, z columns in metres"
        )
    if len(P) == 0:
        raise DataError(
            "the point cloud is empty", "check that the scan saw the workpiece and that cropping kept it"
        )
    if not np.all(np.isfinite(P)):
        bad = int((~np.all(np.isfinite(P), axis=1)).sum())
        raise DataError(
            f"points has {bad} rows with NaN or infinite coordinates",
            "drop invalid points first (weldcell.sdk.cloud.drop_invalid)",
        )
    if len(P) < m + 1:
        raise DataError(
            f"the cloud has {len(P)} points but the neighbourhood needs m={m} neighbours (eq. 11)",
            "pass a denser cloud or a smaller m",
        )
    return P


def _positive(value: float | None, name: str) -> float | None:
    if value is None:
        return None
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise DataError(f"{name} must be a positive number, got {value}", f"pass {name} > 0")
    return v


def _unit(v: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), eps)
