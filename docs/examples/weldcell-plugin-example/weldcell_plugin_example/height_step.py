"""``seam.height-step``: a seam wherever the surface height steps, e.g. the top-plate edge of a lap joint.

The cloud is in the robot base frame with +z up. A *foot* point lies on the lower surface with a point
at least ``min_step`` higher within ``radius`` (a KD-tree query); foot points are grouped into seams
(connected within ``2 * radius``), ordered along their principal axis and binned every ``spacing``.
Per bin the seam point is the inner corner: the foot point closest to the upper surface, moved under
that surface's edge. The approach direction bisects the corner (down and toward the wall).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import Field
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from weldcell.plugins.scan_plan.seams import SeamPolyline
from weldcell.sdk.cloud import PointCloud, check_cloud
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length


class HeightStepSettings(Settings):
    """Settings of the height-step seam finder."""

    min_step: Length = Field(0.002, gt=0, description="smallest height step that is a joint [m]")
    radius: Length = Field(0.003, gt=0, description="neighbourhood radius of the step test [m]")
    spacing: Length = Field(0.002, gt=0, description="distance between seam points [m]")
    min_seam_length: Length = Field(0.02, gt=0, description="shorter seams are dropped [m]")


@dataclass
class HeightStepResult:
    """The seams found (same type as ``seam.edge-intensity``'s) and which points were foot points."""

    seams: list[SeamPolyline]
    foot: np.ndarray


class HeightStepSeams:
    """The stage object: ``HeightStepSeams(settings)(cloud) -> HeightStepResult``."""

    def __init__(self, settings: HeightStepSettings) -> None:
        self.s = settings

    def __call__(self, cloud: PointCloud) -> HeightStepResult:
        s = self.s
        P = check_cloud(cloud, "cloud for height-step seams", min_points=10).points
        tree = cKDTree(P)
        nbrs = tree.query_ball_point(P, s.radius, workers=2)
        z_lo = np.array([P[n, 2].min() for n in nbrs])
        z_hi = np.array([P[n, 2].max() for n in nbrs])
        foot = (z_hi - P[:, 2] >= s.min_step) & (P[:, 2] - z_lo < s.min_step / 4)
        high = P[:, 2] - z_lo >= s.min_step  # on top of a step
        if foot.sum() < 2 or not high.any():
            return HeightStepResult([], foot)
        F, H = P[foot], P[high, :2]
        d_high, i_high = cKDTree(H).query(F[:, :2], workers=2)
        pairs = cKDTree(F).query_pairs(2 * s.radius, output_type="ndarray")
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(F), len(F)))
        _, label = connected_components(graph, directed=False)
        seams = []
        for lab in np.unique(label):
            idx = np.flatnonzero(label == lab)
            centred = F[idx] - F[idx].mean(axis=0)
            axis = np.linalg.svd(centred, full_matrices=False)[2][0]
            t = centred @ axis
            bins = np.floor((t - t.min()) / s.spacing).astype(int)
            pts, toward = [], []
            for b in np.unique(bins):
                k = idx[bins == b][np.argmin(d_high[idx[bins == b]])]  # the foot point nearest the wall
                edge_xy = H[i_high[k]]
                pts.append([*edge_xy, F[k, 2]])
                toward.append(edge_xy - F[k, :2])
            pts, toward = np.asarray(pts), np.asarray(toward)
            keep = np.r_[True, np.linalg.norm(np.diff(pts, axis=0), axis=1) > s.spacing / 4]  # no repeats
            pts, toward = pts[keep], toward[keep]
            if len(pts) < 2:
                continue
            side = np.cross([0.0, 0.0, 1.0], np.gradient(pts, axis=0) * [1.0, 1.0, 0.0])  # horizontal normal
            side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-12)
            side *= np.sign(np.sum(side[:, :2] * toward)) or 1.0  # point it toward the wall
            app = (side + [0.0, 0.0, -1.0]) / np.linalg.norm(side + [0.0, 0.0, -1.0], axis=1, keepdims=True)
            length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
            if length >= s.min_seam_length:
                seams.append(SeamPolyline(len(seams), "lap", pts, app, False, length))
        return HeightStepResult(seams, foot)
