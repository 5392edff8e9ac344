"""Exact nearest-neighbour search on a fixed point set, for ICP and normal estimation.

:class:`PointTree` answers the queries the registration makes (k nearest points, optionally within a
distance bound) with the result conventions of ``scipy.spatial.cKDTree`` (distances ``inf`` and index
``n`` where no neighbour lies within the bound). The back-end is ``pykdtree`` (an OpenMP KD-tree,
1.3-1.6x faster than ``cKDTree`` on these low-k queries on 2 cores); where it is not installed the
same queries go to ``cKDTree`` with identical results, so nothing but the speed depends on it.

pykdtree's OpenMP runtime (libgomp bundled in its wheel) by default keeps its threads spinning for a
while after each parallel query; on a 2-core machine they then steal the core from the numpy step that
follows. The runtime reads ``GOMP_SPINCOUNT`` once, when it is loaded: it is loaded here with
``GOMP_SPINCOUNT=0`` (threads sleep at once) unless the user set it or ``OMP_WAIT_POLICY``, and the
environment is restored right after, so no other library sees the change. See
docs/methods/reconstruction.md, section 5.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

_backend: Any = None  # pykdtree's KDTree class, False when unavailable, None before the first use


def _pykdtree() -> Any:
    global _backend
    if _backend is None:
        added = not any(k in os.environ for k in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY"))
        if added:
            os.environ["GOMP_SPINCOUNT"] = "0"
        try:
            from pykdtree.kdtree import KDTree
        except ImportError:
            _backend = False
        else:
            _backend = KDTree
        finally:
            if added:
                os.environ.pop("GOMP_SPINCOUNT", None)
    return _backend


def backend_name() -> str:
    """``"pykdtree"`` or ``"scipy"``: which library answers :class:`PointTree` queries."""
    return "pykdtree" if _pykdtree() else "scipy"


class PointTree:
    """KD-tree over an (N, 3) float64 point set with ``cKDTree``-compatible ``query`` results.

    ``backend`` = "auto" (pykdtree when installed), "pykdtree" or "scipy".
    """

    def __init__(self, points: np.ndarray, backend: str = "auto"):
        self.data = np.ascontiguousarray(points, dtype=np.float64)
        self.n = len(self.data)
        kd = _pykdtree() if backend in ("auto", "pykdtree") else False
        if backend == "pykdtree" and not kd:
            raise ImportError("pykdtree is not installed: pip install pykdtree")
        if kd and self.n:
            self._pyk, self._ck = kd(self.data, leafsize=16), None
        else:  # sliding-midpoint splits: ~30 % faster to build than median splits, queries as fast
            self._pyk, self._ck = None, cKDTree(self.data, leafsize=32, balanced_tree=False)
        self.backend = "pykdtree" if self._pyk is not None else "scipy"

    def query(
        self, q: np.ndarray, k: int = 1, distance_upper_bound: float = np.inf, workers: int = -1
    ) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices) of the ``k`` nearest points of each row of ``q``, as ``cKDTree.query``.

        Shapes (M,) for k = 1, else (M, k); index ``n`` and distance ``inf`` where fewer than ``k``
        points lie within ``distance_upper_bound``. ``workers`` applies to the scipy back-end only.
        """
        q = np.ascontiguousarray(q, dtype=np.float64)
        if self._ck is not None:
            return self._ck.query(q, k=k, distance_upper_bound=distance_upper_bound, workers=workers)
        bound = None if not np.isfinite(distance_upper_bound) else float(distance_upper_bound)
        d, i = self._pyk.query(q, k=int(k), distance_upper_bound=bound)
        i = i.astype(np.int64)
        if k > self.n:  # pykdtree pads with its own sentinels: use cKDTree's (n, inf)
            pad = i >= self.n
            i[pad], d[pad] = self.n, np.inf
        return d, i
