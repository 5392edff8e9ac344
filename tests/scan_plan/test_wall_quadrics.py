"""Curved-wall seam nodes (plugins/scan_plan/wall_quadrics.py and its use in the seam stage)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan.seams import (
    _curved_wall_nodes,
    _refine_on_sides,
    _smooth_approach,
    extract_seams,
)
from weldcell.sdk.errors import DataError

RADIUS = 0.02  # a 20 mm post standing on a plate: its wall curves along the root


def _post_on_plate(spacing: float = 6e-4, noise: float = 0.0, seed: int = 0):
    """Points and outward normals of a plate (z = 0) and a vertical post of ``RADIUS`` on it, within
    40 mm of the root circle; the root circle (K, 3) and its approach (bisector of +z and the post's
    outward normal, pointing into the corner)."""
    rng = np.random.default_rng(seed)
    r = np.arange(RADIUS + spacing / 2, RADIUS + 0.04, spacing)
    plate = []
    for ri in r:
        phi = np.arange(0, 2 * np.pi, spacing / ri) + rng.uniform(0, spacing / ri)
        plate.append(np.column_stack([ri * np.cos(phi), ri * np.sin(phi), np.zeros_like(phi)]))
    plate = np.vstack(plate)
    phi = np.arange(0, 2 * np.pi, spacing / RADIUS)
    z = np.arange(spacing / 2, 0.04, spacing)
    pp, zz = np.meshgrid(phi, z)
    post = np.column_stack([RADIUS * np.cos(pp.ravel()), RADIUS * np.sin(pp.ravel()), zz.ravel()])
    P = np.vstack([plate, post])
    N = np.vstack([np.tile([0.0, 0.0, 1.0], (len(plate), 1)), post * [1.0, 1.0, 0.0] / RADIUS])
    if noise:
        P = P + rng.normal(0.0, noise, P.shape)
    t = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    root = np.column_stack([RADIUS * np.cos(t), RADIUS * np.sin(t), np.zeros_like(t)])
    approach = -(np.column_stack([np.cos(t), np.sin(t), np.ones_like(t)])) / np.sqrt(2.0)
    return P, N, root, approach


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def test_wall_quadrics_put_the_node_on_the_root_where_planes_sit_inside_the_curved_wall():
    """Planes fitted to a wall that curves along the seam sink below the root, so their intersection
    lies too deep; the walls' tangent planes meet on it."""
    P, N, root, approach = _post_on_plate()
    tree = cKDTree(P)
    start = root + 3e-4 * approach  # a node off the root, as the chaining leaves it
    X_plane, _, ok_plane, _, _ = _refine_on_sides(P, N, tree, start, 0.006, np.deg2rad(35.0))
    assert ok_plane.all()
    plane_err = np.linalg.norm(X_plane - root, axis=1)
    assert plane_err.min() > 1.5e-4  # the planes' bias (0.25 mm) this test guards against
    X, A, ok = _curved_wall_nodes(P, N, tree, start, 0.008, 0.032, 0.006)
    assert ok.all()
    assert np.max(np.linalg.norm(X - root, axis=1)) < 5e-5  # 0.03 mm: sigma shrinks on the 20 mm post
    assert np.max(_angle_deg(A, approach)) < 0.1


def test_wall_quadrics_average_sensor_noise():
    """0.1 mm of noise on every point: the nodes stay within 0.08 mm (rms) of the root and the approach
    within 0.5 deg (thousands of points per wall)."""
    P, N, root, approach = _post_on_plate(noise=1e-4, seed=3)
    X, A, ok = _curved_wall_nodes(P, N, cKDTree(P), root, 0.008, 0.032, 0.006)
    assert ok.mean() > 0.95
    assert np.sqrt(np.mean(np.sum((X[ok] - root[ok]) ** 2, axis=1))) < 8e-5
    assert np.sqrt(np.mean(_angle_deg(A[ok], approach[ok]) ** 2)) < 0.5


def test_a_wall_with_too_few_points_keeps_the_input_node():
    """A node whose neighbourhood holds one wall only is not moved and is reported as not fitted."""
    P, N, root, _ = _post_on_plate()
    plate = P[:, 2] == 0.0
    far = np.array([[0.06, 0.0, 0.0]])  # on the plate, 40 mm from the post
    X, _, ok = _curved_wall_nodes(P[plate], N[plate], cKDTree(P[plate]), far, 0.008, 0.032, 0.006)
    assert not ok.any()
    assert np.array_equal(X, far)


def test_approach_smoothing_follows_a_direction_that_turns_along_a_closed_seam():
    """A closed seam whose approach tilts back and forth by 20 deg: a moving average under-shoots the
    turns; the local quadratic fit of the curved-seam smoothing follows them."""
    s = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    tilt = np.radians(20.0) * np.sin(2 * s)
    A = np.column_stack([np.sin(tilt), np.zeros_like(s), -np.cos(tilt)])
    ok = np.ones(len(s), dtype=bool)
    curved = _smooth_approach(A, ok, 15, closed=True, curved=True)
    boxed = _smooth_approach(A, ok, 15, closed=True, curved=False)
    assert np.max(_angle_deg(curved, A)) < 0.1
    assert np.max(_angle_deg(boxed, A)) > 0.5  # what the straight-seam smoothing would do here


def test_negative_wall_radius_is_refused():
    P, N, _, _ = _post_on_plate(spacing=2e-3)
    with pytest.raises(DataError, match="wall_radius"):
        extract_seams(P, N, wall_radius=-0.01)
