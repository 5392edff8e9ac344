"""PointTree answers like scipy's cKDTree whichever back-end serves it."""

from __future__ import annotations

import os

import numpy as np
import pytest
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan import nearest
from weldcell.plugins.scan_plan.nearest import PointTree


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.default_rng(3)
    P = rng.uniform(-0.1, 0.1, (3000, 3))
    Q = P[:500] + rng.normal(0, 0.004, (500, 3))
    return P, Q


@pytest.mark.parametrize("backend", ["auto", "scipy"])
@pytest.mark.parametrize("k, bound", [(1, np.inf), (1, 0.003), (2, 0.005), (20, np.inf)])
def test_queries_match_ckdtree(clouds, backend, k, bound):
    P, Q = clouds
    d_ref, i_ref = cKDTree(P).query(Q, k=k, distance_upper_bound=bound)
    d, i = PointTree(P, backend=backend).query(Q, k=k, distance_upper_bound=bound)
    assert i.dtype == np.int64 and i.shape == i_ref.shape
    np.testing.assert_array_equal(i, i_ref)
    np.testing.assert_allclose(d, d_ref, rtol=0, atol=1e-15)
    if np.isfinite(bound):
        assert (i == len(P)).any() and np.isinf(d[i == len(P)]).all()  # misses are (inf, n) as in scipy


def test_more_neighbours_than_points_pad_like_scipy():
    P = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.03, 0, 0]])
    d, i = PointTree(P).query(np.array([[0.02, 0, 0]]), k=5)
    np.testing.assert_array_equal(i[0, 3:], [3, 3])
    assert np.isinf(d[0, 3:]).all() and np.isfinite(d[0, :3]).all()


def test_loading_the_back_end_leaves_the_environment_alone():
    before = dict(os.environ)
    nearest.backend_name()
    PointTree(np.zeros((4, 3)) + np.arange(4)[:, None])
    assert dict(os.environ) == before


def test_forcing_a_missing_back_end_says_what_to_install(monkeypatch):
    monkeypatch.setattr(nearest, "_backend", False)
    assert nearest.backend_name() == "scipy"
    assert PointTree(np.eye(3)).backend == "scipy"
    with pytest.raises(ImportError, match="pip install pykdtree"):
        PointTree(np.eye(3), backend="pykdtree")
