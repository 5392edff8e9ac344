"""Torch frames, offset and interpolation (paper 000, eqs. 18-19) and the weld-path JSON format."""

from __future__ import annotations

import json

import numpy as np
import pytest
from weldcell.plugins.scan_plan.seams import SeamPolyline, extract_seams
from weldcell.plugins.scan_plan.torch_path import plan_torch_path, slerp_quaternions, torch_frames, weld_path
from weldcell.sdk.errors import DataError
from weldcell.sdk.weldpath import WeldPath

from .test_seams import cylinder_on_plate, t_fillet


def line_seam(n=21, closed=False):
    y = np.linspace(0.0, 0.1, n)
    pts = np.c_[0.005 + 0 * y, y, 0.008 + 0 * y]
    appr = np.tile(np.array([-1.0, 0, -1]) / np.sqrt(2), (n, 1))
    return SeamPolyline(0, "concave", pts, appr, closed, 0.1)


def circle_seam(n=60, R=0.02):
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    pts = np.c_[R * np.cos(th), R * np.sin(th), 0.008 + 0 * th]
    appr = np.c_[np.cos(th), np.sin(th), -np.ones(n)] / np.sqrt(2)
    return SeamPolyline(1, "concave", pts, appr, True, 2 * np.pi * R)


def test_frames_are_right_handed_with_z_into_joint_and_x_along_travel():
    seam = line_seam()
    path = plan_torch_path(seam, standoff=0.015, rho=0)
    R = path.poses[:, :3, :3]
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(np.einsum("kij,kil->kjl", R, R), np.eye(3), atol=1e-9)
    assert np.allclose(np.cross(R[:, :, 2], R[:, :, 0]), R[:, :, 1])  # y = z x x
    assert np.allclose(R[:, :, 2], seam.normals)  # z = approach, into the joint
    assert np.allclose(R[:, :, 0], [0, 1, 0])  # x = travel (+y)


def test_standoff_is_respected_along_the_torch_axis():
    seam = line_seam()
    for work, travel in ((0.0, 0.0), (np.deg2rad(10), np.deg2rad(-15))):
        path = plan_torch_path(seam, standoff=0.012, work_angle=work, travel_angle=travel, rho=0)
        d = np.linalg.norm(path.points - seam.points, axis=1)
        assert np.allclose(d, 0.012)
        assert np.allclose(path.points + 0.012 * path.poses[:, :3, 2], seam.points)  # axis hits the seam
    # zero angles: the paper's p_w = p_e + d n with n the outward normal (= -approach)
    path = plan_torch_path(seam, standoff=0.012, rho=0)
    assert np.allclose(path.points, seam.points - 0.012 * seam.normals)


def test_work_and_travel_angles_tilt_about_x_and_y():
    seam = line_seam()
    base = plan_torch_path(seam, standoff=0.01, rho=0).poses[:, :3, :3]
    push = plan_torch_path(seam, standoff=0.01, travel_angle=np.deg2rad(20), rho=0).poses[:, :3, :3]
    work = plan_torch_path(seam, standoff=0.01, work_angle=np.deg2rad(15), rho=0).poses[:, :3, :3]
    z0, x0 = base[0][:, 2], base[0][:, 0]
    assert np.degrees(np.arccos(push[0][:, 2] @ z0)) == pytest.approx(20)
    assert push[0][:, 2] @ x0 > 0  # push: the torch axis leans towards travel
    assert np.allclose(push[0][:, 1], base[0][:, 1])  # rotation about y keeps y
    assert np.degrees(np.arccos(work[0][:, 2] @ z0)) == pytest.approx(15)
    assert np.allclose(work[0][:, 0], x0)  # rotation about the travel axis keeps x


def test_interpolation_adds_rho_points_with_unit_quaternions():
    seam = line_seam(n=11)
    rho = 4
    path = plan_torch_path(seam, standoff=0.01, rho=rho, travel_average=3)
    assert len(path.poses) == 11 + 10 * rho
    q = np.array(path.to_pose7())[:, 3:]
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    P = path.points
    frac = np.arange(1, rho + 1)[:, None] / (rho + 1)
    assert np.allclose(P[1 : rho + 1], P[0] + frac * (P[rho + 1] - P[0]))
    ring = plan_torch_path(circle_seam(n=60), standoff=0.01, rho=2)
    assert len(ring.poses) == 60 * 3  # closed: also between the last and the first frame
    z = ring.poses[:, :3, 2]
    assert np.all(np.einsum("ij,ij->i", z[1:], z[:-1]) > np.cos(np.deg2rad(10)))  # smooth rotation


def test_slerp_is_eq_19_and_keeps_unit_norm():
    from scipy.spatial.transform import Rotation, Slerp

    r = Rotation.from_rotvec([[0, 0, 0], [0.3, -1.2, 0.7]])
    q = r.as_quat()
    a = np.linspace(0, 1, 7)
    ours = slerp_quaternions(q[:1], q[1:], a[None, :])[0]
    ref = Slerp([0, 1], r)(a).as_quat()
    ref *= np.sign(np.sum(ref * ours, axis=1))[:, None]
    assert np.allclose(ours, ref, atol=1e-9)
    assert np.allclose(np.linalg.norm(ours, axis=1), 1)


def test_travel_direction_follows_a_closed_seam():
    seam = circle_seam()
    path = plan_torch_path(seam, standoff=0.01, rho=0, travel_average=3)
    x = path.poses[:, :3, 0]
    tangent = np.c_[
        -np.sin(np.arctan2(seam.points[:, 1], seam.points[:, 0])),
        np.cos(np.arctan2(seam.points[:, 1], seam.points[:, 0])),
        0 * seam.points[:, 0],
    ]
    proj = tangent - np.einsum("ij,ij->i", tangent, seam.normals)[:, None] * seam.normals
    proj /= np.linalg.norm(proj, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", x, proj) > np.cos(np.deg2rad(3)))


def test_paths_on_extracted_seams_end_to_end(tmp_path):
    P, N, roots, _ = t_fillet(seed=5)
    res = extract_seams(P, N)
    paths = [plan_torch_path(s, standoff=0.015, travel_angle=np.deg2rad(10)) for s in res.seams]
    doc = weld_path(res.seams, paths, frame="base", metrics={"n_seams": len(res.seams)}).to_json()
    assert doc["schema"] == "weldcell/weld-path@1" and doc["units"] == "m"
    f = tmp_path / "path.json"
    f.write_text(json.dumps(doc))
    back = WeldPath.from_json(f)
    assert back.frame == "base" and back.metrics["n_seams"] == len(res.seams)
    for s, p, b in zip(res.seams, paths, back.seams, strict=True):
        assert np.allclose(b.points, s.points, atol=1e-6) and np.allclose(b.poses, p.poses, atol=1e-6)
        assert np.allclose(b.extra["approach"], s.normals, atol=1e-5)
        assert b.closed == s.closed and b.joint == s.joint_class
        # every torch axis points down into the joint and meets the seam within 1 mm of the root
        z = p.poses[:, :3, 2]
        assert np.all(z[:, 2] < -0.5)
        root = min(roots, key=lambda r: abs(r[0, 0] - np.median(s.points[:, 0])))
        assert np.abs(p.targets[:, 0] - root[0, 0]).max() < 1e-3
        assert np.abs(p.targets[:, 2] - root[0, 2]).max() < 1e-3
    ring = extract_seams(*cylinder_on_plate(seed=5)[:2]).seams
    assert len(ring) == 1 and plan_torch_path(ring[0], standoff=0.01).closed


def test_reading_a_weld_path_rejects_bad_documents(tmp_path):
    seam = line_seam()
    good = weld_path([seam], [plan_torch_path(seam, standoff=0.01)]).to_json()
    assert WeldPath.from_json(good).seams[0].poses.shape[1:] == (4, 4)
    bad_cases = [
        ({**good, "schema": "weldcell/weld-path@0"}, "schema"),
        ({**good, "units": "mm"}, "units"),
        ({**good, "seams": [{"id": 0}]}, "missing points, poses"),
        ({**good, "seams": [{**good["seams"][0], "poses": [[0, 0, 0, 0, 0, 0, 2.0]]}]}, "non-unit"),
        ({**good, "seams": [{**good["seams"][0], "poses": [[0, 0, 0]]}]}, "poses"),
        ([1, 2], "JSON object"),
    ]
    for doc, match in bad_cases:
        with pytest.raises(DataError, match=match):
            WeldPath.from_json(doc)
    with pytest.raises(DataError, match="not found"):
        WeldPath.from_json(tmp_path / "missing.json")
    with pytest.raises(DataError, match="seams but"):
        weld_path([seam], [])


def test_bad_seams_and_settings_raise_data_error():
    one = SeamPolyline(0, "concave", np.zeros((1, 3)), np.zeros((1, 3)), False, 0.0)
    with pytest.raises(DataError, match="at least 2"):
        plan_torch_path(one, standoff=0.01)
    with pytest.raises(DataError, match="standoff"):
        plan_torch_path(line_seam(), standoff=-1)
    along = line_seam()
    along.normals[:] = [0, 1, 0]  # approach parallel to travel
    with pytest.raises(DataError, match="parallel"):
        plan_torch_path(along, standoff=0.01)


@pytest.mark.parametrize("work_deg, travel_deg", [(20.0, -7.0), (45.0, 15.0), (-30.0, 10.0), (0.0, 0.0)])
def test_work_and_travel_angles_are_exactly_the_settings(work_deg, travel_deg):
    """AWS definitions: the travel angle is the torch axis' lean along the travel direction, the work
    angle its angle about the travel axis; each must equal its setting whatever the other one is."""
    s = np.linspace(0, 0.2, 20)
    points = np.stack([s, 0.01 * np.sin(10 * s), np.zeros_like(s)], axis=1)
    approach = np.tile([0.0, 0.0, -1.0], (20, 1))
    travel = np.gradient(points, axis=0)
    T = torch_frames(
        points,
        approach,
        travel,
        standoff=0.015,
        work_angle=np.radians(work_deg),
        travel_angle=np.radians(travel_deg),
    )
    for Ti, xi, ai in zip(T, travel, approach, strict=True):
        t = xi - (xi @ ai) * ai
        t /= np.linalg.norm(t)
        z = Ti[:3, 2]
        lean = np.degrees(np.arcsin(z @ t))  # along travel
        across = z - (z @ t) * t  # the torch axis projected onto the plane across the seam
        y = np.cross(ai, t)
        work = np.degrees(np.arctan2(-(across @ y), across @ ai))
        assert lean == pytest.approx(travel_deg, abs=1e-6)
        assert work == pytest.approx(work_deg, abs=1e-6)
