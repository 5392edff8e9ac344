"""SRM finger contact model: penetration, friction, end of seam, tag kinematics."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.plugins.tactile.paths import Polyline, planned_path_with_error, straight_seam
from weldcell.plugins.tactile.render import InFingerCamera
from weldcell.plugins.tactile.srm_model import (
    SRMParams,
    Workpiece,
    contact,
    tag_pose,
    tip_deflection_from_tag,
)
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import frame_from_axes

SEAM = straight_seam(0.1, origin=(0.0, 0.0), heading=0.0)  # along +x; wall on the left (+y), free side right


def _tool(x: float, y: float, heading: float = 0.0) -> np.ndarray:
    return frame_from_axes([np.cos(heading), np.sin(heading), 0.0], [0.0, 0.0, -1.0], [x, y, 0.002])


@pytest.mark.parametrize("heading", [0.0, 0.4])
def test_tip_ends_on_the_wall_and_deflection_equals_penetration(heading: float) -> None:
    wp = Workpiece(SEAM, free_side="right")
    p = SRMParams(friction=0.0)
    for y in (-0.0015, -0.001, 0.0):
        c = contact(_tool(0.05, y, heading), wp, p)
        assert c.in_contact
        assert c.penetration == pytest.approx(p.tip_radius + y)
        assert c.tip_position[1] == pytest.approx(-p.tip_radius, abs=1e-12)  # tip centre on the wall offset
        assert np.linalg.norm(c.deflection_tool) == pytest.approx(c.penetration)
        assert c.normal_force == pytest.approx(p.stiffness[0] * c.penetration)
    assert not contact(_tool(0.05, -0.0025), wp, p).in_contact


def test_friction_bends_the_tip_backwards() -> None:
    wp = Workpiece(SEAM, free_side="right")
    p = SRMParams(friction=0.2)
    c = contact(_tool(0.05, -0.001), wp, p, sliding_velocity=np.array([0.005, 0.0, 0.0]))
    assert c.tip_position[0] < 0.05  # dragged against travel
    assert c.tip_position[1] == pytest.approx(-p.tip_radius)  # still on the wall
    assert (0.05 - c.tip_position[0]) == pytest.approx(p.friction * 0.001, rel=1e-6)


def test_contact_fades_round_the_end_of_the_seam() -> None:
    wp = Workpiece(SEAM, free_side="right")
    p = SRMParams()
    pens = [
        contact(_tool(x, -0.001), wp, p).penetration for x in (0.099, 0.1005, 0.101, 0.1015, 0.1018, 0.103)
    ]
    assert pens[0] == pytest.approx(0.001)
    assert all(a >= b for a, b in zip(pens, pens[1:], strict=False))  # monotone fade, no jump back
    assert pens[-1] == 0.0 and not contact(_tool(0.103, -0.001), wp, p).in_contact
    assert contact(_tool(0.1015, -0.001), wp, p).at_seam_end


def test_overload_and_wall_height() -> None:
    wp = Workpiece(SEAM, free_side="right")
    assert contact(_tool(0.05, 0.006), wp, SRMParams()).overload
    high = _tool(0.05, -0.001)
    high[2, 3] = 0.05
    assert not contact(high, wp, SRMParams()).in_contact


def test_tag_model_round_trip() -> None:
    p = SRMParams()
    cam = InFingerCamera()
    u = np.array([0.001, -0.002, 0.0005])
    T = tag_pose(u, p, cam.T_cam_tag_rest)
    tag_move = T[:3, 3] - cam.T_cam_tag_rest[:3, 3]
    np.testing.assert_allclose(tip_deflection_from_tag(tag_move, p), u, atol=1e-12)


def test_bad_inputs() -> None:
    with pytest.raises(DataError):
        SRMParams(tip_radius=0.0)
    with pytest.raises(DataError):
        Workpiece(SEAM[:1])
    with pytest.raises(DataError):
        Workpiece(SEAM, wall_normals=np.zeros((3, 3)))
    with pytest.raises(DataError):
        Polyline(np.array([[0.0, 0.0], [np.nan, 1.0]]))


def test_planned_path_error_is_what_was_asked() -> None:
    plan = planned_path_with_error(SEAM, offset=0.002, drift=0.0, wobble=0.0, noise=0.0, side="right")
    assert np.allclose(Polyline(SEAM).distances(plan), 0.002)
    assert np.all(plan[:, 1] < 0)  # on the right of +x travel
