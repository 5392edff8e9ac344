"""Algorithm 1's two call forms: ``iterative_pool``'s keywords and ``run_pool`` with one ``PoolOptions``."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.plugins.handeye.iterative import PoolOptions, iterative_pool, run_pool
from weldcell.plugins.handeye.simulation import simulate_cell
from weldcell.plugins.handeye.verification import ConsensusVerifier, radius_cost
from weldcell.sdk.errors import DataError


def test_options_object_and_keywords_give_the_same_pool():
    cell = simulate_cell(rng=7)
    c = cell.noisy_p_cam(0.001, np.random.default_rng(7))
    c[[4, 20]] += [[0.02, 0.0, 0.0], [0.0, 0.0, -0.02]]
    kw = dict(verifier_sees_count=True, search="wide", budget=12, seed=5, refit=3.0, max_verifications=300)
    a = iterative_pool(c, cell.p_base, ConsensusVerifier(c, cell.p_base), radius_cost(0.3), **kw)
    b = run_pool(c, cell.p_base, ConsensusVerifier(c, cell.p_base), radius_cost(0.3), PoolOptions(**kw))
    assert a.pool == b.pool and a.n_used == b.n_used and a.n_verified == b.n_verified
    assert np.array_equal(a.H, b.H) and np.array_equal(a.H_refit, b.H_refit)
    assert np.array_equal(a.history, b.history) and a.events == b.events and a.timed_out == b.timed_out
    assert not {4, 20} & set(a.pool)
    with pytest.raises(DataError, match="pool_size"):
        run_pool(c[:5], cell.p_base[:5], ConsensusVerifier(c, cell.p_base), options=PoolOptions(pool_size=6))
