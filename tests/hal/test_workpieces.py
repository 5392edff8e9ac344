"""Workpieces of the simulated cell: seams on the surface, concave fillets, dense sampling, placement,
clear errors on bad parameters."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
from weldcell.hal.sim.workpieces import (
    WORKPIECES,
    SeamTruth,
    Workpiece,
    cylinder_on_plate,
    fillet_t,
    make_workpiece,
    rad,
    v_groove_butt,
    workpiece_parameters,
    y_pipe,
)
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy, transform_points, transform_vectors

KINDS = list(WORKPIECES)
CONCAVE = ["fillet-t", "lap", "cylinder-on-plate", "y-pipe"]


@pytest.fixture(scope="module")
def built() -> dict[str, Workpiece]:
    return {k: make_workpiece(k) for k in KINDS}


def _scene(mesh: o3d.geometry.TriangleMesh) -> o3d.t.geometry.RaycastingScene:
    s = o3d.t.geometry.RaycastingScene()
    s.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return s


def _dist(scene, pts: np.ndarray) -> np.ndarray:
    return scene.compute_distance(o3d.core.Tensor(np.asarray(pts, dtype=np.float32))).numpy()


def _occ(scene, pts: np.ndarray) -> np.ndarray:
    return scene.compute_occupancy(o3d.core.Tensor(np.asarray(pts, dtype=np.float32)), nsamples=5).numpy()


def _interior(seam: SeamTruth, margin: int = 4) -> slice:
    """Seam points away from the open ends (where offsets leave the part through its end faces)."""
    return slice(None) if seam.closed else slice(margin, len(seam) - margin)


def test_registry_names() -> None:
    assert KINDS == ["v-groove-butt", "fillet-t", "lap", "corner", "cylinder-on-plate", "y-pipe"]


@pytest.mark.parametrize("kind", KINDS)
def test_seams_lie_on_the_mesh_surface(built, kind) -> None:
    wp = built[kind]
    scene = _scene(wp.mesh)
    assert wp.seams
    for seam in wp.seams:
        d = _dist(scene, seam.points)
        if kind == "v-groove-butt":
            # the seam is the centre of the root opening: root_gap/2 from each root face
            assert d.max() <= wp.params["root_gap"] / 2 + 1e-5
        else:
            assert d.max() < 0.5e-3, f"{kind}/{seam.id}: {d.max() * 1e3:.3f} mm off the surface"


def test_v_groove_without_gap_has_its_seam_on_the_root_faces() -> None:
    wp = v_groove_butt(root_gap=0.0)
    assert _dist(_scene(wp.mesh), wp.seam("groove").points).max() < 0.5e-3


@pytest.mark.parametrize("kind", KINDS)
def test_seam_sampling_is_dense_ordered_and_unit(built, kind) -> None:
    for seam in built[kind].seams:
        assert seam.segment_lengths().max() <= 1e-3
        assert np.allclose(np.linalg.norm(seam.approach, axis=1), 1.0)
        assert np.allclose(np.linalg.norm(seam.travel, axis=1), 1.0)
        steps = np.diff(np.vstack([seam.points, seam.points[:1]]) if seam.closed else seam.points, axis=0)
        # points are ordered along travel
        assert np.all(np.sum(steps * seam.travel[: len(steps)], axis=1) > 0)
        # the torch frames are right-handed with z = approach
        T = seam.torch_frames()
        assert np.allclose(np.linalg.det(T[:, :3, :3]), 1.0)
        assert np.allclose(T[:, :3, 2], seam.approach)


@pytest.mark.parametrize("kind", KINDS)
def test_approach_comes_from_free_space(built, kind) -> None:
    wp = built[kind]
    scene = _scene(wp.mesh)
    for seam in wp.seams:
        i = _interior(seam)
        eps = 1e-3
        outside = seam.points[i] - eps * seam.approach[i]
        assert _occ(scene, outside).max() == 0, f"{kind}/{seam.id}: -approach offset is inside the part"
        # free: not touching a face (a 90° corner leaves eps·sin45° of clearance)
        assert _dist(scene, outside).min() > 0.3 * eps


@pytest.mark.parametrize("kind", CONCAVE)
def test_fillet_like_seams_are_concave(built, kind) -> None:
    """Along +approach, the torch runs into the solid right at the seam: the corner is concave."""
    wp = built[kind]
    scene = _scene(wp.mesh)
    for seam in wp.seams:
        i = _interior(seam)
        inside = seam.points[i] + 0.5e-3 * seam.approach[i]
        assert _occ(scene, inside).min() == 1, f"{kind}/{seam.id}: +approach offset is not in the part"


def test_fillet_approach_bisects_web_and_base() -> None:
    wp = fillet_t(web_height=0.08, thickness=0.012)
    s1, s2 = wp.seam("fillet-1"), wp.seam("fillet-2")
    # equal 45° to the base normal (+z) and to the web face normal (+y for fillet-1, -y for fillet-2)
    for seam, web_n in ((s1, np.array([0, 1.0, 0])), (s2, np.array([0, -1.0, 0]))):
        assert np.allclose(seam.approach @ np.array([0, 0, 1.0]), -math.sqrt(0.5))
        assert np.allclose(seam.approach @ web_n, -math.sqrt(0.5))
        assert np.allclose(seam.points[:, 2], 0.012)
        assert np.allclose(np.abs(seam.points[:, 1]), 0.006)


def test_watertight_single_part_meshes(built) -> None:
    for kind in ("fillet-t", "lap", "cylinder-on-plate", "y-pipe"):
        assert built[kind].mesh.is_watertight(), kind


def test_cylinder_seam_is_a_closed_circle_with_a_start_and_direction() -> None:
    wp = cylinder_on_plate(radius=0.04, thickness=0.012)
    seam = wp.seam("saddle")
    assert seam.closed and seam.joint == "saddle"
    assert np.allclose(np.linalg.norm(seam.points[:, :2], axis=1), 0.04)
    assert np.allclose(seam.points[:, 2], 0.012)
    assert np.allclose(seam.points[0], [0.04, 0, 0.012])
    assert np.allclose(seam.travel[0], [0, 1, 0])  # counter-clockwise from above
    assert seam.length == pytest.approx(2 * math.pi * 0.04, rel=1e-3)
    assert np.linalg.norm(seam.points[-1] - seam.points[0]) <= 1e-3


def test_y_pipe_seam_is_the_analytic_intersection_of_both_cylinders() -> None:
    R, r, beta = 0.05, 0.03, rad(60)
    wp = y_pipe(radius=R, branch_radius=r, branch_angle=beta, length=0.45)
    p = wp.seam("junction").points
    axis0 = np.array([0.0, 0.0, R])
    b = np.array([math.cos(beta), 0.0, math.sin(beta)])
    rel = p - axis0
    assert np.allclose(np.hypot(rel[:, 1], rel[:, 2]), R, atol=1e-9)  # on the main pipe
    radial = rel - np.outer(rel @ b, b)
    assert np.allclose(np.linalg.norm(radial, axis=1), r, atol=1e-9)  # on the branch
    assert np.all(rel @ b > 0)  # the upper junction, not the branch's extension below the axis


def test_y_pipe_surface_has_no_interior_parts() -> None:
    """The branch stops at the junction and the main pipe has a hole there: no surface lies inside
    the other pipe, so a camera sees a real concave junction."""
    R, r, beta, L = 0.04, 0.03, rad(45), 0.4
    wp = y_pipe(radius=R, branch_radius=r, branch_angle=beta, length=L)
    pts = wp.sample_surface(200_000, rng=3, frame="workpiece").points
    rel = pts - np.array([0.0, 0.0, R])
    b = np.array([math.cos(beta), 0.0, math.sin(beta)])
    s = rel @ b
    in_branch = (np.linalg.norm(rel - np.outer(s, b), axis=1) < r - 1e-4) & (s > 0) & (s < L / 2 - 1e-4)
    in_main = (np.hypot(rel[:, 1], rel[:, 2]) < R - 1e-4) & (np.abs(pts[:, 0]) < L / 2 - 1e-4)
    assert not np.any(in_branch | in_main)


def test_placement_moves_mesh_and_seams_consistently(built) -> None:
    T = T_from_rpy([0.3, -0.2, 1.1], [0.5, -0.2, 0.3])
    for kind in ("lap", "y-pipe"):
        wp = built[kind]
        placed = wp.placed(T)
        assert np.allclose(wp.T_world_workpiece, np.eye(4))  # the original is untouched
        world = placed.seams_in_world()
        for s0, s1 in zip(wp.seams, world, strict=True):
            assert np.allclose(s1.points, transform_points(T, s0.points))
            assert np.allclose(s1.approach, transform_vectors(T, s0.approach))
            assert np.allclose(s1.travel, transform_vectors(T, s0.travel))
            # the placed seam still lies on the placed mesh
            d0 = _dist(_scene(wp.mesh), s0.points)
            d1 = _dist(_scene(placed.mesh_in_world()), s1.points)
            assert np.allclose(d0, d1, atol=2e-6)
        cloud = placed.sample_surface(2000, rng=0)
        local = wp.sample_surface(2000, rng=0, frame="workpiece")
        assert cloud.frame == "world" and local.frame == "workpiece"
        assert np.allclose(cloud.points, transform_points(T, local.points))
        assert np.median(_dist(_scene(placed.mesh_in_world()), cloud.points)) < 1e-6


def test_make_workpiece_passes_parameters() -> None:
    wp = make_workpiece("fillet_t", web_height=0.05)
    assert wp.kind == "fillet-t" and wp.params["web_height"] == 0.05
    assert np.asarray(wp.mesh.vertices)[:, 2].max() == pytest.approx(0.06)
    assert np.asarray(wp.mesh.vertices)[:, 2].min() == pytest.approx(0.0)
    assert workpiece_parameters("lap")["overlap"] == 0.04


@pytest.mark.parametrize(
    ("kind", "params", "needle"),
    [
        ("v-groove-butt", {"thickness": -0.01}, "thickness"),
        ("v-groove-butt", {"root_gap": 0.2}, "does not fit"),
        ("v-groove-butt", {"root_face": 0.02}, "root_face"),
        ("fillet-t", {"web_thickness": 0.3}, "web_thickness"),
        ("lap", {"overlap": 0.2}, "overlap"),
        ("corner", {"length": 0.0}, "length"),
        ("cylinder-on-plate", {"radius": 0.2}, "does not fit"),
        ("y-pipe", {"branch_radius": 0.05}, "branch_radius"),
        ("y-pipe", {"branch_angle": rad(5)}, "branch_angle"),
        ("y-pipe", {"branch_length": 0.05}, "branch_length"),
        ("fillet-t", {"seam_spacing": 0.002}, "seam_spacing"),
    ],
)
def test_bad_parameters_raise_data_error(kind, params, needle) -> None:
    with pytest.raises(DataError) as e:
        make_workpiece(kind, **params)
    assert needle in e.value.message
    assert e.value.fix


def test_unknown_kind_and_parameter_list_the_valid_ones() -> None:
    with pytest.raises(DataError) as e:
        make_workpiece("butterfly")
    assert "v-groove-butt" in e.value.fix and "y-pipe" in e.value.fix
    with pytest.raises(DataError) as e:
        make_workpiece("lap", thicknes=0.01)
    assert "thicknes" in e.value.message and "thickness" in e.value.fix and "overlap" in e.value.fix


def test_seam_truth_validates_shapes() -> None:
    with pytest.raises(DataError):
        SeamTruth("s", "fillet", np.zeros((3, 3)), np.zeros((3, 3)), np.ones((3, 3)))
    with pytest.raises(DataError):
        SeamTruth("s", "weird", np.zeros((3, 3)), np.ones((3, 3)), np.ones((3, 3)))
    with pytest.raises(DataError):
        v_groove_butt().placed(np.ones((4, 4)))
