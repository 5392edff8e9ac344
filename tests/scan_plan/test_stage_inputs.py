"""What one scan-and-plan stage hands the next is typed: viewpoints and the neighbour table travel in
fields of :class:`~weldcell.sdk.cloud.PointCloud`, not in ``meta``, so a third-party stage cannot lose
them by accident, a moved cloud moves its viewpoints, and a table never serves other points."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from weldcell.plugins.scan_plan import seams as seams_pkg
from weldcell.plugins.scan_plan.cloud_numerics import knn_table
from weldcell.plugins.scan_plan.cloud_pipeline import plan_on_cloud
from weldcell.plugins.scan_plan.scans_io import read_input_cloud
from weldcell.plugins.scan_plan.stages import (
    BilateralDenoiser,
    BilateralSettings,
    EdgeSeamExtractor,
    EdgeSeamSettings,
    oriented_normals,
)
from weldcell.sdk.cloud import PointCloud, read_cloud, write_cloud
from weldcell.sdk.errors import DataError, PluginError
from weldcell.sdk.geometry import T_from_rpy

from .synthetic import corner_workpiece

EYES = np.array([[0.05, -0.30, 0.45], [0.35, 0.20, 0.50]])


@pytest.fixture(scope="module")
def scan() -> PointCloud:
    """An L-shaped corner (two plates) seen from two cameras, in the base frame."""
    P, _ = corner_workpiece(noise=0.0002, seed=3)
    return PointCloud(P, frame="base", viewpoints=EYES)


class PlainDenoiser:
    """A third-party denoise stage written as plugin authors do: a fresh cloud from the input's fields
    (points thinned, PCA normals, the frame) -- nothing else of the input is passed on."""

    def __call__(self, cloud: PointCloud) -> PointCloud:
        pc = cloud.to_open3d().voxel_down_sample(0.002)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(12))
        return PointCloud(np.asarray(pc.points), normals=np.asarray(pc.normals), frame=cloud.frame)


class Recorder:
    """A seam stage that records the cloud it was given and finds nothing."""

    def __init__(self) -> None:
        self.seen: PointCloud | None = None

    def __call__(self, cloud: PointCloud):
        self.seen = cloud

        class NoSeams:
            seams: list = []

        return NoSeams()


def test_a_third_party_denoiser_that_builds_a_fresh_cloud_does_not_lose_the_viewpoints(scan):
    seam = Recorder()
    run = plan_on_cloud(scan, {"denoise": PlainDenoiser(), "seam": seam}.__getitem__)
    assert run.path is None and seam.seen is run.cloud
    np.testing.assert_array_equal(seam.seen.viewpoints, EYES)
    # so the first-party seam stage orients the third party's normals toward the cameras
    N = oriented_normals(seam.seen)
    assert N is not None
    facing = [np.einsum("ij,ij->i", N, e - seam.seen.points) for e in EYES]
    assert np.mean(np.max(facing, axis=0) > 0) > 0.99


def test_a_denoiser_that_moves_the_cloud_to_another_frame_is_refused(scan):
    def moving(cloud):
        return PointCloud(cloud.points, frame="camera")

    with pytest.raises(PluginError, match="keeps the frame"):
        plan_on_cloud(scan, {"denoise": moving, "seam": Recorder()}.__getitem__)
    with pytest.raises(PluginError, match="not a PointCloud"):
        plan_on_cloud(scan, {"denoise": lambda c: c.points, "seam": Recorder()}.__getitem__)


def test_the_first_party_denoiser_keeps_the_scan_and_leaves_its_neighbour_table(scan):
    clean = BilateralDenoiser(BilateralSettings())(scan)
    np.testing.assert_array_equal(clean.viewpoints, EYES)
    assert clean.frame == "base" and clean.neighbours is not None and clean.neighbours.matches(clean.points)


def test_transformed_clouds_move_their_viewpoints_and_keep_their_orientation(scan):
    clean = BilateralDenoiser(BilateralSettings())(scan)
    T = T_from_rpy([0.4, -1.1, 2.0], [0.3, -0.2, 0.1])
    moved = clean.transformed(T, frame="world")
    np.testing.assert_allclose(moved.viewpoints, EYES @ T[:3, :3].T + T[:3, 3], atol=1e-12)
    # the normals face the cameras as before the move: with two cameras the visibility test decides, and
    # its pixel grid follows the points as the camera sees them, not the cloud's frame
    np.testing.assert_allclose(
        oriented_normals(moved), oriented_normals(clean) @ T[:3, :3].T, atol=1e-9
    )
    one = clean.with_viewpoints(EYES[:1])
    before = oriented_normals(one) @ T[:3, :3].T
    np.testing.assert_allclose(oriented_normals(one.transformed(T)), before, atol=1e-9)
    # had the viewpoints stayed put (what copying meta did), many normals would face away from the camera
    lost = oriented_normals(one.transformed(T).with_viewpoints(EYES[:1]))
    assert np.mean(np.einsum("ij,ij->i", before, lost) > 0) < 0.9
    np.testing.assert_array_equal(clean.select(clean.points[:, 2] > 0.01).viewpoints, EYES)
    np.testing.assert_array_equal(clean.with_points(clean.points[:10]).viewpoints, EYES)


def test_a_stale_neighbour_table_is_never_used(scan, monkeypatch):
    clean = BilateralDenoiser(BilateralSettings())(scan)
    table = clean.neighbours
    given = []
    real = seams_pkg.extract_seams

    def spy(points, normals=None, settings=None, **kw):
        given.append(kw.get("neighbours"))
        return real(points, normals, settings, **kw)

    monkeypatch.setattr(seams_pkg, "extract_seams", spy)
    stage = EdgeSeamExtractor(EdgeSeamSettings())
    stage(clean)
    assert given[-1] is table  # the fresh table is reused
    # any new cloud starts without it: a crop, a move, another stage's output
    assert clean.select(np.arange(len(clean) - 1)).neighbours is None
    assert clean.transformed(np.eye(4)).neighbours is None
    assert clean.with_points(clean.points.copy()).neighbours is None
    # points changed in place after the table was made: the table is dropped, the stage searches itself
    stale = clean.with_neighbours(table)
    stale.points[0] += 1e-4
    assert stale.neighbours is None
    stage(stale)
    assert given[-1] is None
    with pytest.raises(DataError, match="other points"):
        clean.with_neighbours(knn_table(clean.points[::-1].copy(), 8))
    with pytest.raises(DataError, match="NeighbourTable"):
        clean.with_neighbours({"idx": table.idx})


def test_viewpoints_are_checked_and_the_former_meta_key_still_works(scan):
    with pytest.raises(DataError, match="viewpoints"):
        PointCloud(scan.points, viewpoints=[[0.0, 0.0, np.nan]])
    with pytest.raises(DataError, match="viewpoints"):
        PointCloud(scan.points, viewpoints=[1.0, 2.0])
    assert PointCloud(scan.points, viewpoints=[]).viewpoints is None
    with pytest.warns(DeprecationWarning, match="viewpoints="):
        old = PointCloud(scan.points, meta={"viewpoints": EYES.tolist(), "source": "x"})
    np.testing.assert_array_equal(old.viewpoints, EYES)
    assert old.meta == {"source": "x"}


def test_viewpoints_written_into_meta_after_the_cloud_was_built_still_reach_the_seam_stage(scan, monkeypatch):
    late = PointCloud(scan.points, normals=None, frame="base")
    late.meta["viewpoints"] = EYES.tolist()  # code written before the viewpoints were typed
    seen = {}

    def spy(points, normals=None, settings=None, **kw):
        seen["viewpoints"] = kw.get("viewpoints")
        raise RuntimeError("stop")

    monkeypatch.setattr(seams_pkg, "extract_seams", spy)
    warns = pytest.warns(DeprecationWarning, match="cloud.viewpoints")
    with warns, pytest.raises(RuntimeError, match="stop"):
        EdgeSeamExtractor(EdgeSeamSettings())(late)
    np.testing.assert_array_equal(seen["viewpoints"], EYES)


@pytest.mark.parametrize("name", ["model.ply", "model.pcd"])
@pytest.mark.parametrize("binary", [True, False])
def test_cloud_files_keep_the_viewpoints_and_stay_readable(tmp_path, scan, name, binary):
    f = write_cloud(tmp_path / name, scan.select(np.arange(200)), binary=binary)
    back = read_cloud(f)
    np.testing.assert_allclose(back.viewpoints, EYES, rtol=0, atol=0)  # exact: written with repr()
    np.testing.assert_allclose(back.points, scan.points[:200], atol=1e-6)
    assert len(o3d.io.read_point_cloud(str(f)).points) == 200  # any reader skips the comments
    mm = f.with_name("mm" + f.suffix)
    write_cloud(mm, PointCloud(scan.points[:200] * 1000, viewpoints=EYES * 1000), binary=binary)
    np.testing.assert_allclose(read_cloud(mm, units="mm").viewpoints, EYES, atol=1e-12)
    seam_input, _ = read_input_cloud(mm, "mm", "base")  # what `weldcell seam --units mm` reads
    np.testing.assert_allclose(seam_input.viewpoints, EYES, atol=1e-12)
    assert read_cloud(write_cloud(tmp_path / ("none" + f.suffix), PointCloud(scan.points))).viewpoints is None


def test_a_damaged_viewpoint_comment_is_one_clear_error(tmp_path, scan):
    f = write_cloud(tmp_path / "v.ply", scan.select(np.arange(50)), binary=False)
    f.write_text(f.read_text().replace("weldcell viewpoint 0.05", "weldcell viewpoint zero"))
    with pytest.raises(DataError, match="weldcell viewpoint x y z"):
        read_cloud(f)
