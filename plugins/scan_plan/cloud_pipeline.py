"""Denoise → seams → 6-DOF torch paths on one cloud in the robot base frame.

The part of the scan-and-plan method that the ``scan-and-plan`` job (after its scan and reconstruction)
and ``weldcell seam`` (on a recorded cloud) share, so both run the same stages in the same order: the job
passes its run context's stages and steps, the command the stages it resolved from its options.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from typing import Any

from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.stages import denoised_scan
from weldcell.sdk.weldpath import WeldPath

STEPS = {
    "denoise": "denoise (bilateral filter)",
    "seam": "seams (edge intensity)",
    "path": "weld path (torch frames + slerp)",
}
"""The job's step name of each stage role."""


@dataclass
class SeamRun:
    """What the stages computed: the weld path (None when no seam was found), the cloud the seams were
    found on, the seam stage's result, and each stage's time (s)."""

    path: WeldPath | None
    cloud: PointCloud
    extraction: Any
    timings: dict[str, float] = field(default_factory=dict)


def plan_on_cloud(
    cloud: PointCloud,
    stage: Callable[[str], Callable[..., Any]],
    *,
    frame: str = "base",
    denoise: bool = True,
    step: Callable[[str], AbstractContextManager[Any]] | None = None,
    on_denoised: Callable[[PointCloud], Any] | None = None,
) -> SeamRun:
    """Denoise (optional) → seams → torch paths (only when a seam was found).

    ``stage(role)`` gives the stage object of a role (``denoise``, ``seam``, ``path``); ``step(name)``,
    when given, is a context manager around each stage (the job's ``ctx.step``, named by :data:`STEPS`);
    ``on_denoised(cloud)`` is called inside the denoise step (the job writes the cloud there).
    The seam stage gets the scan's viewpoints even from a denoise stage that built its output without
    them (:func:`weldcell.sdk.stages.denoised_scan`).
    """
    timings: dict[str, float] = {}

    def around(role: str) -> AbstractContextManager[Any]:
        return step(STEPS[role]) if step is not None else nullcontext()

    clean = cloud
    if denoise:
        with around("denoise"):
            fn = stage("denoise")
            t0 = time.perf_counter()
            clean = denoised_scan(cloud, fn(cloud))
            timings["denoise"] = time.perf_counter() - t0
            if on_denoised is not None:
                on_denoised(clean)
    with around("seam"):
        fn = stage("seam")
        t0 = time.perf_counter()
        extraction = fn(clean)
        timings["seams"] = time.perf_counter() - t0
    if not extraction.seams:
        return SeamRun(None, clean, extraction, timings)
    with around("path"):
        fn = stage("path")
        t0 = time.perf_counter()
        path = fn(extraction.seams, frame=frame)
        timings["path"] = time.perf_counter() - t0
    return SeamRun(path, clean, extraction, timings)
