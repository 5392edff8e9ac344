"""Repeatable Open3D calls: the same captures give the same calibration on every run.

Open3D runs its point-to-point ICP (correspondence sums) and ``segment_plane`` (parallel RANSAC
iterations drawing from one shared random engine) on oneTBB worker threads; how the work is split
between threads depends on the machine's load, so the floating-point sums and the RANSAC draws come
out in a different order from run to run (e.g. 7 different ICP transforms in 30 identical calls on a
loaded 2-core host). Inside :func:`open3d_serial` Open3D uses one thread, which makes those calls
bit-repeatable. Used by the hand-eye plugin (clouds of 1-20k points) and the seam stage's support-plane
RANSAC; the cost is small at those sizes (measured beside each use).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

_lock = threading.Lock()
_depth = 0
_previous = 0


@contextmanager
def open3d_serial() -> Iterator[None]:
    """Run the block with Open3D limited to one CPU thread (nestable; the previous limit is restored)."""
    import open3d as o3d

    global _depth, _previous
    with _lock:
        if _depth == 0:
            _previous = int(o3d.utility.get_max_threads())
            o3d.utility.set_max_threads(1)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                o3d.utility.set_max_threads(_previous)
