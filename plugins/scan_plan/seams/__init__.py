"""Weld-seam extraction from a workpiece point cloud (paper 000, section II-E, eqs. 11-17), plus the
joint classification and polyline chaining a weld path needs.

Paper part (per point, fully vectorised over fixed-width neighbour arrays from one KD-tree query):

* eq. 11 -- adaptive neighbourhood ``N_r(p)``: the points within radius ``r``, grown to the ``m``
  nearest where fewer than ``m`` lie inside ``r`` (the effective radius ``r_p`` is recorded);
* eq. 12 -- edge intensity ``I_p = |p - centroid(N_r(p))| / r_p``: the normalised displacement of a
  point from the centroid of its neighbours (low on smooth surface, a ridge along edges);
* eq. 13 -- 3-D gradient of the intensity, ``I_k = max_i (I_i - I_p) * delta_k / d^2`` (the steepest
  neighbour slope projected on axis k, see :func:`intensity_gradient` for why not ``d / delta_k``);
* eqs. 14-15, 17 -- structure tensor ``H = sum_i G(p, q_i) g_i g_i^T`` over ``N_r(p)`` with the
  Gaussian of eq. 17 (sigma = standard deviation of the neighbour distances);
* eq. 16 -- the eigenvalue-free edge test ``Tr(H)^3 / Det(H) >= t``.

Beyond the paper (the paper stops at a set of edge points):

* each edge point is classified from the oriented normals of its two sides (a 2-means split of the
  neighbour normals): ``concave`` (fillet / lap / corner roots), ``groove`` (V-groove bottoms: concave
  with a narrow included angle), ``convex`` (plate outlines, web tops), ``boundary`` (one-sided
  neighbourhood: scan borders, free plate edges) and ``weak`` (sides nearly parallel: noise);
* weldable points are clustered (KD-tree radius graph, approach directions must agree), each cluster
  is ordered along a minimum-spanning-tree diameter (works for curved and closed seams) from which the
  side rows and spurs it folds back along are cut (a monotonicity check of the geodesic distance from
  its start, :func:`_unfold_path`), binned along that arclength (bins that run back are dropped),
  snapped onto the intersection line of the two fitted side planes, smoothed and resampled at a fixed
  spacing into a :class:`SeamPolyline`.

The package's modules are the method's steps, in the order data flows through them:

==================  ===========================================================================
``edges``           eqs. 11-17: adaptive neighbourhood, edge intensity, gradient, structure tensor
``support``         the plane the part rests on or is held against (table, fixture); contact lines
``orientation``     normals oriented towards the sensor side found from the scan (no viewpoint)
``candidates``      oriented normals and the joint class of each edge point
``sides``           the two sides of a crease (2-means of normals) and their side planes
``chaining``        clusters of weldable points ordered into pieces; bridging across gaps
``tracing``         growing open pieces along their joint beyond their ends
``refinement``      nodes snapped onto the side planes, quadric walls, end trims, orientation
``ordering``        smoothing of positions and approach, approach orthogonal to travel
``pipeline``        :func:`extract_seams` and :func:`chain_seams`: the steps end to end
``settings``        :class:`SeamSettings` (one object for the stage) and :class:`ChainSettings`
``model``           labels, the method's fixed constants, :class:`SeamPolyline`, :class:`SeamExtraction`
==================  ===========================================================================

The quadric wall fits are :mod:`weldcell.plugins.scan_plan.wall_quadrics`; the point-cloud numerics
(neighbour tables, 3x3 eigen-solver) :mod:`weldcell.plugins.scan_plan.cloud_numerics`. Everything
importable from the former single module ``seams.py`` is importable from this package.
"""

from __future__ import annotations

from .candidates import (  # noqa: F401
    Classifying,
    classify_edges,
    point_normals,
)
from .chaining import (  # noqa: F401
    Bridging,
    _bin_means,
    _cluster_pieces,
    _end_directions,
    _farthest,
    _fold,
    _gap_nodes,
    _Piece,
    _trace,
    _tree_diameters,
    _unfold_path,
    bridge_pieces,
)
from .edges import (  # noqa: F401
    EdgeScores,
    Neighbourhood,
    _floored_ratio,
    _usable_table,
    adaptive_neighbourhood,
    edge_intensity,
    edge_ratio,
    edge_scores,
    intensity_gradient,
    noise_floor,
    structure_tensor,
    tensor_trace,
    tensor_weights,
)
from .model import (  # noqa: F401
    BEHIND_TOL,
    BOUNDARY,
    CONCAVE,
    CONVEX,
    CONVEX_DROPPED,
    CORE_FRACTION,
    GROOVE,
    LABEL_NAMES,
    MIN_INCLUDED_ANGLE,
    NONE,
    SMALL_BATCH,
    THIRD_SURFACE,
    TOE_INCLUDED,
    TOE_RADIUS,
    TOE_SHIFT,
    WALL_MAX_POINTS,
    WALL_MIN_CREASE,
    WEAK,
    WELDABLE,
    SeamExtraction,
    SeamPolyline,
    _as_points,
    _positive,
    _unit,
)
from .ordering import (  # noqa: F401
    _local_quadratic,
    _orthogonal_to_travel,
    _smooth_approach,
    _smooth_positions,
    _straight,
)
from .orientation import (  # noqa: F401
    propagate_signs,
    scan_side_normals,
    sensor_side,
    viewing_axis,
)
from .pipeline import (  # noqa: F401
    _clusters,
    _cut_overshoot,
    _fitted_pieces,
    _polyline,
    chain_seams,
    extract_seams,
)
from .refinement import (  # noqa: F401
    SideLimits,
    _curved_wall_nodes,
    _cut_end_corners,
    _mean_where,
    _orient,
    _refine_nodes,
    _refine_on_sides,
    _resample,
    _trim_turning_ends,
)
from .settings import (  # noqa: F401
    ChainSettings,
    SeamSettings,
)
from .sides import (  # noqa: F401
    _dot3,
    _fit_planes_from,
    _fit_two_planes,
    _kept,
    _sides_at,
    _two_sides,
    _wsum3,
    fit_two_planes,
    two_sides,
)
from .support import (  # noqa: F401
    SupportPlane,
    drop_contact,
    on_support,
    support_plane,
)
from .tracing import (  # noqa: F401
    Growing,
    _blocking_nodes,
    _cloud_ends,
    _concat,
    _crease_direction,
    _first_ahead,
    _grow_end,
    _sub,
    _trace_joint,
    _Tracer,
    _with_fit,
    grow_pieces,
)
