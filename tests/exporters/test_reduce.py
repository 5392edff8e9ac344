"""Path reduction: the fewest poses whose interpolated path stays within the tolerance of the planned one."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from weldcell.plugins.exporters import programs
from weldcell.plugins.exporters.reduce import reduce_poses
from weldcell.sdk.errors import DataError

from .conftest import path_gap, torch_poses, weld_path


@pytest.mark.parametrize(("tol_mm", "tol_deg"), [(0.1, 0.5), (0.05, 0.2), (1.0, 2.0)])
def test_reduced_path_stays_within_the_tolerance(tol_mm, tol_deg):
    seam = weld_path(0.45, 0.1).seams[1]  # a wavy closed circle: position and orientation both turn
    red = reduce_poses(seam.poses, tol_mm / 1000, math.radians(tol_deg))
    assert 2 < len(red.poses) < len(seam.poses)
    assert red.indices[0] == 0 and red.indices[-1] == len(seam.poses) - 1
    np.testing.assert_allclose(red.poses, seam.poses[red.indices])
    d, a = path_gap(seam.poses, red.poses)  # independent dense check, both ways
    assert d <= tol_mm / 1000 + 2e-5  # + the dense sampling step
    assert a <= math.radians(tol_deg) + 1e-3
    assert red.max_position_error <= tol_mm / 1000 and red.max_angle_error <= math.radians(tol_deg)
    assert red.max_position_error > 0.5 * tol_mm / 1000 or red.max_angle_error > 0.5 * math.radians(tol_deg)


def test_few_poses_near_the_chord_bound():
    """A 50 mm circle held to 0.1 mm needs at least 2 pi / (2 acos(1 - tol / r)) chords; the split keeps
    at most about twice that."""
    a = np.linspace(0, 2 * np.pi, 1001)
    pts = np.column_stack([0.05 * np.cos(a), 0.05 * np.sin(a), np.zeros_like(a)])
    poses = torch_poses(pts, [0.0, 0.0, -1.0])
    red = reduce_poses(poses, 1e-4, math.radians(5))
    n_min = 2 * np.pi / (2 * math.acos(1 - 1e-4 / 0.05))
    assert n_min <= len(red.poses) - 1 <= 2 * n_min + 2


def test_a_straight_seam_keeps_its_two_ends():
    """The demo's 493 mm seam held 739 robtargets; a straight seam needs its two ends."""
    pts = np.column_stack([np.linspace(0.2, 0.693, 739), np.full(739, 0.1), np.full(739, 0.05)])
    red = reduce_poses(torch_poses(pts, [0.0, 0.5, -1.0]))
    assert len(red.poses) == 2 and red.max_position_error < 1e-9


def test_a_pure_reorientation_is_kept():
    """Poses at one point turning the torch about z, then about x: the angle alone decides where to split."""
    from scipy.spatial.transform import Rotation

    turns = [Rotation.from_rotvec([0, 0, 0.5 * s]) for s in np.linspace(0, 1, 15)]
    turns += [Rotation.from_rotvec([0.5 * s, 0, 0]) * turns[-1] for s in np.linspace(0, 1, 16)[1:]]
    poses = np.tile(np.eye(4), (len(turns), 1, 1))
    poses[:, :3, :3] = [r.as_matrix() for r in turns]
    red = reduce_poses(poses, 1e-4, math.radians(0.5))
    assert list(red.indices) == [0, 14, 29] and red.max_angle_error < 1e-6


def test_bad_tolerances_are_refused():
    poses = weld_path(0.45, 0.1).seams[0].poses
    for tol in (0.0, -1.0, math.nan):
        with pytest.raises(DataError, match="tolerances must be positive"):
            reduce_poses(poses, tol)


def test_the_program_reports_the_achieved_deviation(ur_doc):
    loose = programs.URScriptSettings(tolerance="0.5 mm", angle_tolerance="2 deg")
    tight = programs.export_urscript(ur_doc)
    coarse = programs.export_urscript(ur_doc, loose)
    assert len(coarse.plan.motions) < len(tight.plan.motions)
    for result, tol in ((tight, 1e-4), (coarse, 5e-4)):
        assert 0 < result.plan.max_position_error <= tol
        line = next(x for x in result.text.splitlines() if "path reduction" in x)
        mm, deg = (float(v) for v in re.findall(r"deviation ([\d.]+) mm, ([\d.]+) deg", line)[0])
        assert mm == pytest.approx(result.plan.max_position_error * 1000, abs=1e-3)
        assert deg == pytest.approx(math.degrees(result.plan.max_angle_error), abs=1e-3)
