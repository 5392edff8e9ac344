"""``weldcell seam`` and ``weldcell reconstruct`` on clouds with known ground truth, and their answers to
bad input: empty and NaN clouds, wrong units, a scan without a pose, a missing hand-eye."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from weldcell.hal.sim.workpieces import v_groove_butt
from weldcell.sdk.cli import main
from weldcell.sdk.cloud import PointCloud, read_cloud, write_cloud
from weldcell.sdk.descriptors import StageSpec
from weldcell.sdk.geometry import T_from_rpy
from weldcell.sdk.hookspecs import hookimpl
from weldcell.sdk.plugins import get_plugin_manager
from weldcell.sdk.weldpath import WeldPath

from .synthetic import corner_workpiece

SEAM_X = 0.45  # the groove's root line runs along y at x = 0.45 m, z = 1 mm (the root face)
SEAM_Z = 0.001


def groove_cloud(n: int = 150_000, seed: int = 0) -> PointCloud:
    """The top (camera-visible) surface of a 300 mm V-groove butt joint in the robot base frame with
    0.3 mm noise; the groove runs along y."""
    T = T_from_rpy((0, 0, np.pi / 2), (SEAM_X, 0, 0))
    wp = v_groove_butt(length=0.3, width=0.15, thickness=0.012).placed(T)
    c = wp.sample_surface(n, rng=seed)
    c = c.select(c.normals[:, 2] > 0.3)
    pts = c.points + np.random.default_rng(seed + 1).normal(0.0, 3e-4, c.points.shape)
    return PointCloud(pts, frame="base")


@pytest.fixture(scope="module")
def groove_m(tmp_path_factory) -> Path:
    """The groove cloud in metres, with 300 NaN points as a depth camera's export may hold."""
    c = groove_cloud()
    pts = np.vstack([c.points, np.full((300, 3), np.nan)])
    f = tmp_path_factory.mktemp("clouds") / "groove.ply"
    write_cloud(f, PointCloud(pts))
    return f


@pytest.fixture(scope="module")
def groove_mm(tmp_path_factory) -> Path:
    f = tmp_path_factory.mktemp("clouds") / "groove_mm.pcd"
    write_cloud(f, PointCloud(groove_cloud().points * 1000.0))
    return f


def cli(*args: str):
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_error(res, code: int, *words: str) -> None:
    assert res.exit_code == code, res.output
    text = " ".join(res.output.split())  # rich wraps long lines
    for w in words:
        assert w in text, text


def check_groove_path(path: WeldPath) -> None:
    assert 1 <= len(path.seams) <= 2  # the groove (a sampling hole may split it once)
    assert sum(s.length for s in path.seams) > 0.25  # most of the 300 mm seam
    for s in path.seams:
        assert s.joint == "groove"
        assert np.max(np.abs(s.points[:, 0] - SEAM_X)) < 0.003  # within 3 mm of the true root line
        assert np.max(np.abs(s.points[:, 2] - SEAM_Z)) < 0.003
        assert np.mean(s.poses[:, 2, 2]) < -0.9  # torch z (approach) points down into the groove


# -------------------------------------------------------------------------------------------- weldcell seam
def test_seam_finds_the_groove_drops_nan_points_and_writes_programs_and_picture(groove_m, tmp_path):
    out = tmp_path / "path.json"
    res = cli(
        "seam",
        groove_m,
        "-o",
        out,
        "--export",
        "urscript",
        "--export",
        "abb-rapid",
        "--export",
        "csv",
        "--standoff",
        "20 mm",
        "--report",
        tmp_path / "report",
    )
    assert res.exit_code == 0, res.output
    assert "dropped 300 invalid points" in res.output
    assert "seams found" in res.output
    doc = json.loads(out.read_text())
    assert doc["schema"] == "weldcell/weld-path@1" and doc["units"] == "m" and doc["frame"] == "base"
    path = WeldPath.from_json(out)
    check_groove_path(path)
    s = path.seams[0]
    # standoff 20 mm: each torch point lies 20 mm back along its approach axis from the seam
    tips = s.poses[:, :3, 3] + 0.020 * s.poses[:, :3, 2]
    assert np.median(np.abs(tips[:, 2] - SEAM_Z)) < 0.003
    assert doc["metrics"]["seams_found"] == len(path.seams) and doc["metrics"]["dropped_invalid"] == 300
    assert doc["metrics"]["stages"]["path"]["settings"]["standoff"] == pytest.approx(0.020)
    assert "movel" in out.with_suffix(".script").read_text()
    assert "MoveL" in out.with_suffix(".mod").read_text()
    assert len(out.with_suffix(".csv").read_text().splitlines()) > len(s.poses) // 2
    assert (tmp_path / "report" / "seams.png").read_bytes()[:4] == b"\x89PNG"
    assert "s0" in (tmp_path / "report" / "summary.txt").read_text()


def test_seam_reads_millimetres_with_units_mm(groove_mm, tmp_path):
    out = tmp_path / "mm.json"
    res = cli("seam", groove_mm, "-o", out, "--units", "mm")
    assert res.exit_code == 0, res.output
    check_groove_path(WeldPath.from_json(out))  # found in metres, at the same place


def test_seam_refuses_a_cloud_whose_scale_does_not_fit_the_units(groove_m, groove_mm, tmp_path):
    res = cli("seam", groove_mm, "-o", tmp_path / "x.json")  # millimetres read as metres
    assert_error(res, 2, "looks like mm, not m", "--units mm")
    res = cli("seam", groove_m, "-o", tmp_path / "x.json", "--units", "mm")  # metres read as millimetres
    assert_error(res, 2, "looks like m, not mm", "--units m")
    assert not (tmp_path / "x.json").exists()


def test_seam_refuses_empty_and_all_nan_clouds(tmp_path):
    empty = tmp_path / "empty.ply"
    empty.write_text(
        "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n"
    )
    assert_error(cli("seam", empty, "-o", tmp_path / "p.json"), 2, "has no points")
    nan = tmp_path / "nan.ply"
    write_cloud(nan, PointCloud(np.full((1000, 3), np.nan)))
    assert_error(cli("seam", nan, "-o", tmp_path / "p.json"), 2, "all 1000 points are NaN")
    assert_error(cli("seam", tmp_path / "missing.ply", "-o", tmp_path / "p.json"), 2, "not found")
    assert not (tmp_path / "p.json").exists()


def test_seam_reports_no_seam_and_bad_options_clearly(groove_m, tmp_path):
    res = cli("seam", groove_m, "-o", tmp_path / "p.json", "--set", "seam.min_seam_length='2 m'")
    assert_error(res, 2, "no weld seam was found", "lower --t")
    assert_error(cli("seam", groove_m, "-o", tmp_path / "p.json", "--t", "5"), 2, "seam.t", "27")
    assert_error(
        cli("seam", groove_m, "-o", tmp_path / "p.json", "--set", "seam.bogus=1"), 2, "bogus", "unknown key"
    )
    assert_error(
        cli("seam", groove_m, "-o", tmp_path / "p.json", "--export", "kuka"),
        4,
        "no exporter named 'kuka'",
        "export.urscript",
    )


class FixedLine:
    """A third-party seam stage: reports one straight seam at a configured height."""

    def __init__(self, settings):
        self.z = settings.z

    def __call__(self, cloud):
        from types import SimpleNamespace

        from weldcell.plugins.scan_plan.seams import SeamPolyline

        y = np.linspace(-0.1, 0.1, 21)
        pts = np.c_[np.full_like(y, SEAM_X), y, np.full_like(y, self.z)]
        approach = np.tile([0.0, 0.0, -1.0], (len(y), 1))
        return SimpleNamespace(seams=[SeamPolyline(7, "groove", pts, approach, False, 0.2)])


class FixedLinePlugin:
    @hookimpl
    def weldcell_register_stages(self, register):
        from pydantic import Field
        from weldcell.sdk.settings import Settings

        class FixedLineSettings(Settings):
            z: float = Field(0.0, description="height of the line [m]")

        register(
            StageSpec(
                name="seam.fixed-line",
                kind="seam",
                summary="test",
                settings=FixedLineSettings,
                factory=FixedLine,
            )
        )


def test_seam_uses_the_stage_plugin_and_settings_a_profile_picks(groove_m, tmp_path):
    profile = tmp_path / "cell.toml"
    profile.write_text("""schema = "weldcell/profile@1"
name = "custom"
[job]
name = "scan-and-plan"
[stages.seam]
plugin = "seam.fixed-line"
settings = { z = 0.05 }
[stages.path.settings]
standoff = "10 mm"
""")
    pm = get_plugin_manager()
    with pm.plugin(FixedLinePlugin(), "fixed-line-test"):
        res = cli("seam", groove_m, "-o", tmp_path / "p.json", "--profile", profile, "--no-denoise")
    assert res.exit_code == 0, res.output
    assert "seam.fixed-line" in res.output
    path = WeldPath.from_json(tmp_path / "p.json")
    assert [s.id for s in path.seams] == ["s7"]
    assert np.allclose(path.seams[0].points[:, 2], 0.05)
    assert np.allclose(path.seams[0].poses[:, 2, 3], 0.06, atol=0.003)  # 10 mm standoff above z = 50 mm


# -------------------------------------------------------------------------------------------- reconstruct
T_FLANGE_CAMERA = T_from_rpy((0.0, 0.0, 0.0), (0.0, -0.06, 0.04))


def posed_views(units: str = "m", perturb: float = 0.002) -> tuple[list[dict], list[np.ndarray], np.ndarray]:
    """Three overlapping views of the corner workpiece (camera frame) with flange poses looking down;
    views 1 and 2 carry a ``perturb`` metre error in their flange pose (what ICP must correct)."""
    P, _ = corner_workpiece(spacing=0.002, noise=0.0002, seed=3)
    scale = {"m": 1.0, "mm": 1000.0}[units]
    out, clouds = [], []
    rng = np.random.default_rng(5)
    for i, (x, y) in enumerate([(0.08, 0.08), (0.12, 0.10), (0.09, 0.13)]):
        T_bf = T_from_rpy((np.pi, 0.0, 0.0), (x, y, 0.45))
        T_bc = T_bf @ T_FLANGE_CAMERA
        view = P[np.linalg.norm(P[:, :2] - [x, y], axis=1) < 0.11]
        cam = (view - T_bc[:3, 3]) @ T_bc[:3, :3]  # base -> camera
        T_rec = T_bf.copy()
        if i > 0:
            d = rng.normal(size=3)
            T_rec[:3, 3] += perturb * d / np.linalg.norm(d)
        T_rec[:3, 3] *= scale
        clouds.append(cam * scale)
        out.append({"cloud": f"{i:03d}.ply", "T_base_flange": T_rec.tolist(), "stamp": float(i)})
    return out, clouds, P


def write_scans(folder: Path, units: str = "m", drop_pose: int | None = None, **doc) -> np.ndarray:
    folder.mkdir(parents=True, exist_ok=True)
    recs, clouds, truth = posed_views(units)
    for r, c in zip(recs, clouds, strict=True):
        write_cloud(folder / r["cloud"], PointCloud(c, frame="camera"))
    if drop_pose is not None:
        del recs[drop_pose]["T_base_flange"]
    (folder / "scans.json").write_text(
        json.dumps({"schema": "weldcell/posed-scans@1", "units": units, "scans": recs, **doc})
    )
    return truth


def test_reconstruct_merges_posed_scans_and_icp_improves_fitness(tmp_path):
    truth = write_scans(tmp_path / "scans")
    out = tmp_path / "model.ply"
    res = cli("reconstruct", tmp_path / "scans", "-o", out, "--mount", "0,-60mm,40 mm,0,0,0")
    assert res.exit_code == 0, res.output
    assert "fitness before" in res.output and res.output.count(".ply ") >= 3
    report = json.loads(out.with_suffix(".json").read_text())
    views = report["views"]
    assert len(views) == 3
    assert all(v["fitness"] >= v["fitness_before"] for v in views)
    assert views[1]["fitness"] > views[1]["fitness_before"] + 0.05  # the 2 mm pose error was corrected
    model = read_cloud(out)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(truth).query(model.points)
    assert np.percentile(d, 95) < 0.0015  # the merged model lies on the true surface
    # the model file says where the cameras were (the registered poses), and `weldcell seam` reads it back
    cams = [np.asarray(v["T_base_camera"])[:3, 3] for v in views]
    np.testing.assert_allclose(model.viewpoints, cams, atol=1e-12)
    seam = cli("seam", out, "-o", tmp_path / "path.json")
    assert "viewpoints      3 (stored in the file)" in seam.output, seam.output


def test_reconstruct_reads_millimetre_scans_and_a_hand_eye_file(tmp_path):
    write_scans(tmp_path / "scans", units="mm")
    he = tmp_path / "handeye.json"
    he.write_text(
        json.dumps(
            {
                "schema": "weldcell/hand-eye@1",
                "transform": "T_flange_camera",
                "T": T_FLANGE_CAMERA.tolist(),
                "units": "m",
            }
        )
    )
    out = tmp_path / "model.ply"
    res = cli("reconstruct", tmp_path / "scans", "-o", out, "--hand-eye", he)
    assert res.exit_code == 0, res.output
    model = read_cloud(out)
    assert np.all(np.ptp(model.points, axis=0)[:2] > 0.15)  # metres: the 200 mm plate
    assert np.ptp(model.points, axis=0).max() < 0.3


def test_reconstruct_refuses_a_scan_without_pose_and_a_missing_hand_eye(tmp_path):
    write_scans(tmp_path / "scans", drop_pose=1)
    res = cli("reconstruct", tmp_path / "scans", "-o", tmp_path / "m.ply", "--mount", "0,0,0,0,0,0")
    assert_error(res, 2, "scan 1 (001.ply) has no pose", "T_base_flange")
    write_scans(tmp_path / "ok")
    assert_error(cli("reconstruct", tmp_path / "ok", "-o", tmp_path / "m.ply"), 2, "no hand-eye", "--mount")
    eye_on_base = tmp_path / "eob.json"
    eye_on_base.write_text(json.dumps({"transform": "T_base_camera", "T": np.eye(4).tolist()}))
    assert_error(
        cli("reconstruct", tmp_path / "ok", "-o", tmp_path / "m.ply", "--hand-eye", eye_on_base),
        2,
        "T_base_camera",
        "eye-in-hand",
    )
    assert_error(
        cli("reconstruct", tmp_path, "-o", tmp_path / "m.ply"), 2, "neither scans.json", "posed-scans@1"
    )
    assert not (tmp_path / "m.ply").exists()
