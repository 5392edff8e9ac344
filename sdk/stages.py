"""The stage kinds of the first-party jobs and the call each stage object answers.

A :class:`~weldcell.sdk.descriptors.StageSpec` has a ``kind``; a job asks for a stage by kind
(its :class:`~weldcell.sdk.descriptors.StageRole`), builds it with ``factory(settings)`` and calls
it as below. A plugin that registers a stage of one of these kinds can replace the built-in one
in any profile (``[stages.<role>] plugin = "..."``). The protocols are structural: no base class
to inherit, only the call to answer.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from weldcell.sdk.cloud import PointCloud
from weldcell.sdk.errors import PluginError
from weldcell.sdk.scan import PosedScan
from weldcell.sdk.weldpath import WeldPath


class ReconstructStage(Protocol):
    """kind ``reconstruct``: merge posed views into one model in the robot base frame.

    Returns an object with ``cloud`` (PointCloud, base frame, ``viewpoints`` = the views' camera
    positions in the base frame when known), ``fitness_before``, ``fitness`` and ``accepted`` (one
    entry per view).
    """

    def __call__(
        self,
        scans: Sequence[PosedScan],
        T_flange_camera: np.ndarray,
        progress: Callable[[int, int, str], None] | None = None,
    ) -> Any: ...


class DenoiseStage(Protocol):
    """kind ``denoise``: a cleaner (and usually thinner) cloud of the same scan, in the same frame.

    Build the output with ``cloud.with_points(points, normals=...)``: it keeps the frame, the
    ``viewpoints`` and ``meta``. A stage may attach the neighbour table of its output points
    (``out.with_neighbours(table)``, a :class:`~weldcell.sdk.cloud.NeighbourTable`) for the seam stage
    to reuse. Jobs pass the output through :func:`denoised_scan`, so viewpoints a stage left out are
    carried over and a changed frame is refused.
    """

    def __call__(self, cloud: PointCloud) -> PointCloud: ...


def denoised_scan(scan: PointCloud, out: PointCloud) -> PointCloud:
    """A denoise stage's output ``out`` with what it must keep of its input ``scan``: the frame (a
    stage that moved the cloud is refused with :class:`PluginError`), the viewpoints (carried over
    when the stage built its output without them: they are where the sensor was, whichever points
    remain) and the scan's ``structure`` (how it was sampled, measured on the cloud as captured)."""
    if not isinstance(out, PointCloud):
        raise PluginError(
            f"the denoise stage returned a {type(out).__name__}, not a PointCloud",
            "a denoise stage returns cloud.with_points(points, normals=...) (see the plugin-author guide)",
        )
    if out.frame != scan.frame:
        raise PluginError(
            f"the denoise stage returned a cloud in frame '{out.frame}' for one in '{scan.frame}'",
            "a denoise stage keeps the frame: build its output with cloud.with_points(points, normals=...)",
        )
    if out.sensor_viewpoints() is None and scan.sensor_viewpoints() is not None:
        out = out.with_viewpoints(scan.sensor_viewpoints())
    if out.structure is None and scan.structure is not None:
        out = out.with_structure(scan.structure)
    return out


class SeamStage(Protocol):
    """kind ``seam``: find weld seams on a cloud; what it may use besides the points travels in typed
    fields of the cloud: ``normals``, ``viewpoints`` (sensor positions, same frame; None when unknown)
    and ``neighbours`` (a :class:`~weldcell.sdk.cloud.NeighbourTable` of exactly these points, or None).
    Returns an object with ``seams``: a list of polylines, each with ``id``, ``joint_class``, ``points``
    (K, 3) ordered along travel, ``normals`` (K, 3) approach directions into the joint, ``closed`` and
    ``length``."""

    def __call__(self, cloud: PointCloud) -> Any: ...


class PathStage(Protocol):
    """kind ``path``: torch poses along seams (z toward the work, x along travel)."""

    def __call__(self, seams: Sequence[Any], frame: str = "base") -> WeldPath: ...


class HandEyeStage(Protocol):
    """kind ``handeye``: measure the calibration feature in a scan and solve the hand-eye transform.

    ``measure(points, predicted=None, seed=0)`` returns a measurement with the feature position in
    the camera frame; ``solve(samples, config, ...)`` returns a
    :class:`weldcell.sdk.handeye_files.HandEyeResult` (``weldcell/hand-eye@1``).
    """

    def measure(self, points: np.ndarray, predicted: np.ndarray | None = None, seed: int = 0) -> Any: ...

    def solve(self, samples: Sequence[Any], config: str, **kwargs: Any) -> Any: ...


class TactileServoStage(Protocol):
    """kind ``tactile-servo``: a servo for a planned path; ``step(t, T_base_tool, delta)`` returns the
    next velocity command (see :mod:`weldcell.plugins.tactile.servo`)."""

    def __call__(self, planned_points: np.ndarray, gate: Callable[..., None] | None = None) -> Any: ...


class EdgesStage(Protocol):
    """kind ``edges``: edge points of a laser scan. ``(scan, template) -> EdgePoints`` with ``xy`` (M, 2) in
    the base frame (see :mod:`weldcell.plugins.localize.edges`)."""

    def __call__(self, scan: Any, template: Any) -> Any: ...


class LocalizeStage(Protocol):
    """kind ``localize``: fit a CAD template to edge points. ``(template, edges) -> Localization`` with
    ``status``, ``M`` (4x4, P_found = M @ P_planned) and ``to_json()`` (``weldcell/localization@1``)."""

    def __call__(self, template: Any, edges: Any) -> Any: ...


@dataclass(frozen=True)
class Detection2D:
    """One object found in an image: box ``xyxy`` (pixels: left, top, right, bottom), class name and
    index, and a score in [0, 1]."""

    xyxy: tuple[float, float, float, float]
    label: str
    class_id: int
    score: float


class DetectorStage(Protocol):
    """kind ``detector``: objects (weld regions) in one colour image. ``(rgb (H, W, 3) uint8, meta)
    -> list[Detection2D]`` (empty when nothing is found); ``meta`` may carry what a simulated detector
    needs (the frame's ground-truth pose), real detectors ignore it."""

    def __call__(self, rgb: np.ndarray, meta: dict | None = None) -> list[Detection2D]: ...


class MapTransferStage(Protocol):
    """kind ``map-transfer``: local maps in the ``weldcell/map-segments@1`` folder and their transport.
    ``writer(root, source, cut)`` -> an object with ``add(id, points, colors, T_world_segment, distance,
    keyframes, extra)``, ``add_existing(src_root, entry)`` and ``finish()``; ``serve(root)`` -> a started
    server (``address``, ``stop()``); ``fetch(address, out)`` -> a report (``segments``, ``complete``,
    ``first_segment_s``); ``manifest(root)``, ``world_cloud(root)``, ``segment(root, entry)`` read a folder
    (see :mod:`weldcell.plugins.map_transfer.stage`)."""

    def writer(self, root: Any, source: str = "", cut: dict | None = None) -> Any: ...

    def serve(self, root: Any) -> Any: ...

    def fetch(self, address: str, out: Any) -> Any: ...

    def manifest(self, root: Any) -> dict: ...

    def world_cloud(self, root: Any) -> Any: ...

    def segment(self, root: Any, entry: dict) -> Any: ...


class RelocalizerStage(Protocol):
    """kind ``relocalizer``: ``prepare(points)`` -> a prior map prepared once per load; ``(prior, current,
    yaw=None, yaw_sigma=.., position=None, position_sigma=.., keyframe_positions=None)`` -> a result with
    ``status`` ("ok"|"failed"), ``T_prior_current`` (4x4), ``overlap``, ``confidence``, ``reason`` and
    ``to_json()`` (``weldcell/relocalization@1``; see :mod:`weldcell.plugins.relocalize.relocalize`)."""

    def prepare(self, points: np.ndarray) -> Any: ...

    def __call__(self, prior: Any, current: np.ndarray, **priors: Any) -> Any: ...


STAGE_KINDS: dict[str, type] = {
    "reconstruct": ReconstructStage,
    "denoise": DenoiseStage,
    "seam": SeamStage,
    "path": PathStage,
    "handeye": HandEyeStage,
    "tactile-servo": TactileServoStage,
    "edges": EdgesStage,
    "localize": LocalizeStage,
    "detector": DetectorStage,
    "map-transfer": MapTransferStage,
    "relocalizer": RelocalizerStage,
}
"""Stage kind -> the protocol its stage objects answer."""
