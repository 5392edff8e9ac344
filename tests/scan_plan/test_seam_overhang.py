"""Normals without a viewpoint on a part whose face overhangs the table it rests on (issue 16, h16e):
the acute wedge between table and face is where sign propagation along normals flips a whole face; the
support plane's contact geometry (:func:`~weldcell.plugins.scan_plan.seams.support.contact_roots`)
orients it."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from weldcell.plugins.scan_plan.cloud_numerics import noise_level, pca_normals
from weldcell.plugins.scan_plan.seams import scan_side_normals, support_plane
from weldcell.plugins.scan_plan.seams.orientation import propagate_signs, sensor_side

STEP = 0.001


def _strip(a, b, length, step=STEP):
    """Points of the rectangle spanned by the cross-section segment a -> b (y, z) and x in [0, length]."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = np.arange(0.0, 1.0 + 1e-9, step / np.linalg.norm(b - a))
    x = np.arange(0.0, length + 1e-9, step)
    T, X = np.meshgrid(t, x, indexing="ij")
    yz = a + T.ravel()[:, None] * (b - a)
    return np.column_stack([X.ravel(), yz])


def _overhang_scene(seed=0):
    """A prism (cross-section (0, 0), (6, 0), (29, 40), (0, 40) mm; 120 mm long) resting on its 6 mm foot on
    a table z = 0 (like a plate's edge): its face from (6, 0) to (29, 40) overhangs the table (outward
    normal (0, 0.87, -0.5), a 60 deg wedge with the table), its top faces +z, its back -y. Only the
    surfaces a sensor sees (the table under the overhang included), in a turned frame. Returns points,
    true outward normals."""
    rng = np.random.default_rng(seed)
    L = 0.12
    parts = [
        (_strip((-0.08, 0.0), (0.0, 0.0), L), (0, 0, 1)),  # table behind the part
        (_strip((0.007, 0.0), (0.12, 0.0), L), (0, 0, 1)),  # table in front, under the overhang too
        (_strip((0.006, 0.0), (0.006 + 0.04 / np.sqrt(3.0), 0.04), L), (0, np.sqrt(0.75), -0.5)),  # overhang
        (_strip((0.0, 0.04), (0.028, 0.04), L), (0, 0, 1)),  # top
        (_strip((0.0, 0.001), (0.0, 0.039), L), (0, -1, 0)),  # back
    ]
    P = np.vstack([p for p, _ in parts])
    N = np.vstack([np.tile(n, (len(p), 1)) for p, n in parts]).astype(float)
    P = P + rng.normal(0.0, 5e-5, P.shape)
    R = Rotation.random(random_state=rng).as_matrix()
    return P @ R.T + rng.uniform(-0.5, 0.5, 3), N @ R.T


def test_an_overhanging_face_is_oriented_from_its_contact_with_the_table():
    P, N_true = _overhang_scene()
    N = pca_normals(P, k=10)
    idx = cKDTree(P).query(P, k=10)[1]
    plane = support_plane(P, N, noise_level(P, 3 * STEP), STEP, margin=0.008)
    assert plane is not None and float(plane.normal @ N_true[0]) > 0.99  # the table, facing the part
    over = (N_true @ N_true[0]) < -0.5  # the overhanging face's points
    oriented = scan_side_normals(P, N, idx, plane)
    agree = np.einsum("ij,ij->i", oriented, N_true) > 0
    assert agree[over].mean() > 0.95
    assert agree.mean() > 0.95
    # the sign propagation alone (no contact roots) runs through the wedge and flips the face
    alone = propagate_signs(N, idx, sensor_side(P, N, plane))
    assert (np.einsum("ij,ij->i", alone, N_true) > 0)[over].mean() < 0.5
