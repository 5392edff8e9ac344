"""Point clouds: validation, transforms, Open3D round trips, unit checks and PLY/PCD files."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.sdk.cloud import (
    PointCloud,
    check_cloud,
    check_units,
    drop_invalid,
    guess_units,
    read_cloud,
    write_cloud,
)
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy


@pytest.fixture
def plate():
    """A 20 cm x 10 cm plate sampled on a 1 cm grid, with normals and colours."""
    x, y = np.meshgrid(np.linspace(0, 0.2, 21), np.linspace(0, 0.1, 11))
    pts = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 0.05)])
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    colors = np.tile([0.2, 0.4, 0.6], (len(pts), 1))
    return PointCloud(pts, normals, colors, frame="camera")


def test_shapes_are_checked():
    c = PointCloud(np.arange(9.0))
    assert c.points.shape == (3, 3) and len(c) == 3 and c.frame == "base"
    with pytest.raises(DataError, match="3 points but 2 normals"):
        PointCloud(np.zeros((3, 3)), normals=np.zeros((2, 3)))
    with pytest.raises(DataError, match="colors"):
        PointCloud(np.zeros((3, 3)), colors=np.zeros((4, 3)))


def test_select_keeps_attributes_aligned(plate):
    mask = plate.points[:, 0] > 0.1
    sub = plate.select(mask)
    assert len(sub) == mask.sum() and len(sub.normals) == len(sub) and len(sub.colors) == len(sub)
    sub.meta["x"] = 1
    assert "x" not in plate.meta  # meta is copied, not shared


def test_transformed_moves_points_and_rotates_normals(plate):
    T = T_from_rpy([np.pi / 2, 0, 0], [1.0, 0.0, 0.0])  # 90 deg about x, then 1 m along x
    moved = plate.transformed(T, frame="base")
    assert moved.frame == "base" and plate.frame == "camera"
    np.testing.assert_allclose(moved.points[0], [1.0, -0.05, 0.0], atol=1e-12)
    np.testing.assert_allclose(moved.normals[0], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(moved.colors, plate.colors)
    np.testing.assert_allclose(plate.points[0], [0.0, 0.0, 0.05])  # the original is untouched


def test_open3d_round_trip(plate):
    back = PointCloud.from_open3d(plate.to_open3d(), frame="camera")
    np.testing.assert_allclose(back.points, plate.points)
    np.testing.assert_allclose(back.normals, plate.normals)
    np.testing.assert_allclose(back.colors, plate.colors)
    bare = PointCloud.from_open3d(PointCloud(plate.points).to_open3d())
    assert bare.normals is None and bare.colors is None


def test_check_cloud_refuses_empty_and_nan_clouds(plate):
    assert check_cloud(plate) is plate
    with pytest.raises(DataError) as e:
        check_cloud(PointCloud(np.zeros((0, 3))), what="scan 3")
    assert e.value.message == "scan 3 has 0 points; at least 1 are needed" and "camera" in e.value.fix
    with pytest.raises(DataError, match="has 231 points; at least 1000 are needed"):
        check_cloud(plate, min_points=1000)
    bad = plate.points.copy()
    bad[[2, 5]] = np.nan
    with pytest.raises(DataError) as e:
        check_cloud(PointCloud(bad))
    assert "2 of 231 points with NaN" in e.value.message and "drop_invalid" in e.value.fix


def test_drop_invalid_removes_nan_inf_and_zero_points(plate):
    pts = plate.points.copy()
    pts[0] = np.nan
    pts[1] = [np.inf, 0, 0]
    pts[2] = 0.0
    clean = drop_invalid(PointCloud(pts, colors=plate.colors))
    assert len(clean) == len(plate) - 3 and len(clean.colors) == len(clean)
    check_cloud(clean)


def test_guess_and_check_units(plate):
    assert guess_units(plate.points) == "m"
    assert guess_units(plate.points * 1000) == "mm"
    assert guess_units(np.array([[0, 0, 0], [10.0, 0, 0]])) is None  # 10 units: cannot tell
    assert guess_units(np.zeros((1, 3))) is None
    check_units(plate, "m")
    with pytest.raises(DataError) as e:
        check_units(PointCloud(plate.points * 1000), "m", what="part.ply")
    assert e.value.message == "part.ply spans 200 units; that looks like mm, not m"
    assert e.value.fix.startswith("pass --units mm")


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_write_and_read_round_trip(plate, tmp_path, suffix):
    path = write_cloud(tmp_path / f"plate{suffix}", plate)
    assert path.is_file()
    assert [p.name for p in tmp_path.iterdir()] == [f"plate{suffix}"]  # no temporary file left
    back = read_cloud(path, frame="camera")
    np.testing.assert_allclose(back.points, plate.points, atol=1e-6)
    assert back.normals is not None and back.frame == "camera"
    assert back.meta["source"] == str(path)


def test_read_in_millimetres_converts_to_metres(plate, tmp_path):
    path = write_cloud(tmp_path / "mm.ply", PointCloud(plate.points * 1000), binary=False)
    with pytest.raises(DataError, match="looks like mm, not m"):
        read_cloud(path)
    back = read_cloud(path, units="mm")
    np.testing.assert_allclose(back.points, plate.points, atol=1e-6)
    raw = read_cloud(path, check_scale=False)
    assert np.ptp(raw.points[:, 0]) == pytest.approx(200.0)


def test_read_errors_say_what_to_do(tmp_path):
    with pytest.raises(DataError, match="point cloud file not found"):
        read_cloud(tmp_path / "absent.ply")
    (tmp_path / "cloud.xyz").write_text("0 0 0\n")
    with pytest.raises(DataError) as e:
        read_cloud(tmp_path / "cloud.xyz")
    assert "unsupported point cloud format '.xyz'" in e.value.message and ".ply or .pcd" in e.value.fix
    with pytest.raises(DataError) as e:
        read_cloud(tmp_path / "cloud.xyz", units="feet")
    assert "unknown units 'feet'" in e.value.message and "mm" in e.value.fix
    empty = tmp_path / "empty.ply"
    empty.write_text(
        "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n"
    )
    with pytest.raises(DataError, match="0 points"):
        read_cloud(empty)
