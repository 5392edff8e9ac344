"""The simulated worker of ``localize-and-weld``: places the weldment with a random error and as-built
members that differ from CAD, and hands the world its mesh (simulated cell only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from weldcell.hal.sim import world_of
from weldcell.plugins.localize.job_settings import SimWorkerSettings
from weldcell.plugins.localize.template import Template


@dataclass
class TruePlacement:
    """Where the simulated worker really put the weldment: the rigid error and the as-built members."""

    pose: np.ndarray
    M: np.ndarray
    outlines: list
    welds: list

    def to_json(self) -> dict:
        return {"x": self.pose[0], "y": self.pose[1], "theta": self.pose[2], "M": self.M.tolist()}


def place_in_sim(ctx, template: Template, w: SimWorkerSettings) -> TruePlacement:
    """The simulated worker places the weldment (seeded by the cell's seed, so a resume places it again
    identically) and the world gets it as a mesh."""
    from shapely import distance, points
    from shapely.geometry import Polygon
    from weldcell.hal.sim.weldment import perturb_members, placement_error, weldment_workpiece
    from weldcell.plugins.localize.pose import pose_matrix
    from weldcell.plugins.localize.refine import fuse_across, member_axis

    rng = np.random.default_rng([ctx.profile.cell.seed, 1002])
    dx, dy, dth = (
        w.placement
        if w.placement is not None
        else placement_error(w.placement_offset, w.placement_angle, rng)
    )
    built, var = perturb_members([m.outline for m in template.members], w.member_variation, rng)
    M = pose_matrix((dx, dy, dth), template.centroid)
    outlines = [P @ M[:2, :2].T + M[:2, 3] for P in built]
    polys = [Polygon(m.outline) for m in template.members]
    welds = []
    for wd in template.welds:
        near = [i for i, p in enumerate(polys) if distance(p, points(wd.points[:, :2])).min() <= 3e-3]
        xy = wd.points[:, :2]
        if near:  # a seam lies against the side faces of the members it joins: it follows each across its
            # axis (refine.fuse_across, as synth.true_welds), not the mean of their displacements
            axes = [member_axis(template.members[i].outline) for i in near]
            disp = [var[i].displace(xy) - xy for i in near]
            xy = xy + fuse_across(disp, [np.array([-u[1], u[0]]) for u in axes])
        welds.append(np.column_stack([xy @ M[:2, :2].T + M[:2, 3], wd.points[:, 2]]))
    world = world_of(ctx)
    T_world_base = world.T_world("robot.base")
    wp = weldment_workpiece(
        outlines,
        [m.top for m in template.members],
        welds,
        [wd.id for wd in template.welds],
        table_z=template.table_z,
    )
    world.workpieces.append(wp.placed(T_world_base))
    return TruePlacement(np.array([dx, dy, dth]), M, outlines, welds)
