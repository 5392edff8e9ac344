"""The fast reductions of weldcell.sdk.arrays give numpy's values."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.sdk.arrays import col_max, col_min, row_dot, row_sums


@pytest.fixture(scope="module")
def rng():
    return np.random.default_rng(11)


def test_row_sums_match_numpy_for_floats_and_masks(rng):
    a = rng.normal(size=(500, 25))
    np.testing.assert_allclose(row_sums(a), a.sum(1), rtol=0, atol=1e-12)
    b = a > 0
    assert row_sums(b).dtype == np.int64
    np.testing.assert_array_equal(row_sums(b), b.sum(1))


def test_row_sums_of_wide_masks_do_not_overflow():
    b = np.ones((3, 600), dtype=bool)  # 600 > 255: a uint8 sum would wrap
    np.testing.assert_array_equal(row_sums(b), [600, 600, 600])


def test_column_extrema_and_row_dots(rng):
    P = rng.normal(size=(1000, 3))
    np.testing.assert_array_equal(col_min(P), P.min(axis=0))
    np.testing.assert_array_equal(col_max(P), P.max(axis=0))
    keys = rng.integers(-50, 50, size=(100, 3))
    assert col_min(keys).dtype == keys.dtype and (col_min(keys) == keys.min(axis=0)).all()
    Q = rng.normal(size=(1000, 3))
    np.testing.assert_allclose(row_dot(P, Q), np.einsum("ij,ij->i", P, Q), rtol=0, atol=1e-14)
