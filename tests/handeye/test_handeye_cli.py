"""`weldcell calibrate hand-eye`: simulated scans, point pairs, the real ancorasir layouts, bad inputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from weldcell.hal.kinematics import get_model
from weldcell.hal.sim.devices import SimDepthCamera, SimRobot
from weldcell.hal.sim.flange import flange_for
from weldcell.hal.sim.world import SimWorld
from weldcell.plugins.handeye.result import HandEyeSample
from weldcell.plugins.handeye.samples_io import write_samples
from weldcell.plugins.handeye.simulation import simulate_cell
from weldcell.sdk.cloud import PointCloud, write_cloud
from weldcell.sdk.geometry import T_from_rpy, frame_from_axes, invert, pose_error

T_WORLD_CAMERA = T_from_rpy(np.radians([-89.5, 0.4, 90.3]), [1.452, 0.004, 0.547])



@pytest.fixture(scope="module")
def scans(tmp_path_factory) -> Path:
    """A samples.json with 8 raw scans (flange + last link) rendered by the simulated PhoXi M."""
    folder = tmp_path_factory.mktemp("scans")
    world = SimWorld([], seed=0)
    model = get_model("ur10e")
    robot = SimRobot(model, world, flange=flange_for("ur10e"))
    cam = SimDepthCamera(world, "phoxi-m", T_WORLD_CAMERA, decimation=2, seed=5)
    for d in (robot, cam):
        d.configure()
        d.activate()
    rng = np.random.default_rng(0)
    samples = []
    for i, xyz in enumerate(
        [
            [0.68, -0.15, 0.45],
            [0.82, 0.15, 0.45],
            [0.82, -0.15, 0.65],
            [0.68, 0.15, 0.65],
            [0.75, 0.0, 0.55],
            [0.70, 0.08, 0.50],
            [0.80, -0.05, 0.60],
            [0.72, -0.1, 0.62],
        ]
    ):
        T = frame_from_axes([0, 0, 1.0], [1.0, 0, 0], xyz) @ T_from_rpy(rng.uniform(-0.25, 0.25, 3))
        robot.move_joint(model.ik(T, robot.q))
        write_cloud(folder / f"{i:02d}.ply", PointCloud(cam.capture().to_cloud().points, frame="camera"))
        samples.append(
            HandEyeSample(T_base_flange=robot.state().T_base_flange, cloud=str(folder / f"{i:02d}.ply"))
        )
    write_samples(folder / "samples.json", samples)
    return folder


def _T(path: Path) -> np.ndarray:
    doc = json.loads(path.read_text())
    assert doc["schema"] == "weldcell/hand-eye@1"
    return np.array(doc["T"])


def test_raw_simulated_scans(cli, scans, tmp_path):
    """Segmentation (link separated), circle and robust fit from raw scans. Measured ~0.05 mm."""
    code, out = cli(scans, "-o", tmp_path / "he.json", "--report", tmp_path / "rep")
    assert code == 0, out
    dt, dr = pose_error(_T(tmp_path / "he.json"), T_WORLD_CAMERA)
    assert dt < 0.3e-3 and np.degrees(dr) < 0.05, (dt, np.degrees(dr))
    assert "T_base_camera" in out and "8 inliers" in out and "confidence" in out
    assert (tmp_path / "rep" / "residuals.png").is_file() and (tmp_path / "rep" / "summary.txt").is_file()


def test_flange_pose_as_target_for_classical_solvers(cli, scans, tmp_path):
    code, out = cli(scans, "-o", tmp_path / "he.json", "--method", "li")
    assert code == 0, out
    dt, dr = pose_error(_T(tmp_path / "he.json"), T_WORLD_CAMERA)
    assert dt < 10e-3 and np.degrees(dr) < 1.0, (dt, np.degrees(dr))


def test_scan_without_a_flange_is_skipped_and_named(cli, scans, tmp_path):
    doc = json.loads((scans / "samples.json").read_text())
    rng = np.random.default_rng(1)
    write_cloud(
        tmp_path / "empty.ply", PointCloud(rng.uniform([-0.2, -0.2, 0.6], [0.2, 0.2, 0.61], (5000, 3)))
    )
    doc["samples"][2]["cloud"] = str(tmp_path / "empty.ply")
    for s in doc["samples"]:
        s["cloud"] = str(scans / s["cloud"]) if not s["cloud"].startswith("/") else s["cloud"]
    (tmp_path / "samples.json").write_text(json.dumps(doc))
    code, out = cli(tmp_path, "-o", tmp_path / "he.json")
    assert code == 0, out
    assert "scan 2 (empty.ply)" in out and "7 inliers" in out
    doc["samples"] = doc["samples"][:4]
    doc["samples"][0]["cloud"] = str(tmp_path / "empty.ply")
    (tmp_path / "samples.json").write_text(json.dumps(doc))
    code, out = cli(tmp_path, "-o", tmp_path / "he.json")
    assert code == 2 and "no flange found in 2 of 4 scans (scan 0 (empty.ply)" in out and "fix:" in out


def _pairs(tmp_path: Path, n=20, sigma=0.0003, units="m", edit=None) -> Path:
    cell = simulate_cell(n_poses=n, rng=3)
    p = cell.noisy_p_cam(sigma, np.random.default_rng(4))
    if n > 5:
        p[5] += [0.01, -0.008, 0.0]  # a false segmentation
    samples = [HandEyeSample(T_base_flange=T, p_cam=c) for T, c in zip(cell.T_base_flange, p, strict=True)]
    write_samples(tmp_path / "samples.json", samples)
    doc = json.loads((tmp_path / "samples.json").read_text())
    if units == "mm":
        for s in doc["samples"]:
            s["p_cam"] = [v * 1e3 for v in s["p_cam"]]
            for row in s["T_base_flange"][:3]:
                row[3] *= 1e3
        doc["units"] = "mm"
    if edit:
        edit(doc)
    (tmp_path / "samples.json").write_text(json.dumps(doc))
    return tmp_path


def test_point_pairs_with_an_outlier_reported_with_its_reason(cli, tmp_path):
    folder = _pairs(tmp_path, units="mm")
    code, out = cli(folder, "-o", tmp_path / "he.json")
    assert code == 0, out
    assert "outlier sample 5: residual" in out and "> threshold" in out
    from weldcell.plugins.handeye.simulation import PAPER_T_BASE_CAMERA

    dt, dr = pose_error(_T(tmp_path / "he.json"), PAPER_T_BASE_CAMERA)
    assert dt < 1e-3 and np.degrees(dr) < 0.05, (dt, np.degrees(dr))  # sigma 0.3 mm, 19 inliers
    code, out = cli(folder, "-o", tmp_path / "it.json", "--method", "flange-iterative")
    assert code == 0 and "Algorithm 1" in out
    dt, _ = pose_error(_T(tmp_path / "it.json"), PAPER_T_BASE_CAMERA)
    assert dt < 2e-3


def test_too_few_samples(cli, tmp_path):
    code, out = cli(_pairs(tmp_path, n=3), "-o", tmp_path / "he.json")
    assert code == 2 and "3 samples; the flange fit needs at least 4" in out and "fix:" in out
    assert not (tmp_path / "he.json").exists()


def test_eye_in_hand_fixed_feature_from_the_file_or_the_option(cli, tmp_path):
    """A camera on the flange looking at a plate 0.4 m from the base origin: samples.json's
    feature_base "estimate" (what the online job writes) finds it; --feature-base origin, which says
    the feature is the base mounting flange, cannot fit; a malformed option is one usage error."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    X = T_from_rpy([0.01, -0.02, 0.03], [0.002, -0.06, 0.04])  # T_flange_camera
    q = np.array([0.4, 0.1, 0.01])  # the plate in the base frame
    samples = []
    for _ in range(12):
        R = Rotation.from_rotvec(rng.uniform(-0.4, 0.4, 3)).as_matrix() @ np.diag([1.0, -1.0, -1.0])
        G = np.eye(4)
        G[:3, :3], G[:3, 3] = R, q + R @ [0, 0.06, -0.55] + rng.uniform(-0.05, 0.05, 3)
        c = (invert(G @ X) @ np.r_[q, 1.0])[:3] + rng.normal(0, 1e-4, 3)
        samples.append(HandEyeSample(T_base_flange=G, p_cam=c, meta={"normal": [0.0, 0.0, -1.0]}))
    write_samples(tmp_path / "samples.json", samples, "eye-in-hand", feature_base="estimate")
    doc = json.loads((tmp_path / "samples.json").read_text())
    assert doc["feature_base"] == "estimate" and doc["samples"][0]["normal"] == [0.0, 0.0, -1.0]
    code, out = cli(tmp_path, "-o", tmp_path / "he.json")
    assert code == 0, out
    dt, dr = pose_error(_T(tmp_path / "he.json"), X)
    assert dt < 1e-3 and np.degrees(dr) < 0.1, (dt, np.degrees(dr))
    fb = json.loads((tmp_path / "he.json").read_text())["extra"]["feature_base"]
    assert np.linalg.norm(np.asarray(fb) - q) < 1e-3
    code, out = cli(tmp_path, "-o", tmp_path / "origin.json", "--feature-base", "origin")
    assert code == 0 and "far above a scanner's noise" in out and "feature_base" in out
    assert pose_error(_T(tmp_path / "origin.json"), X)[0] > 0.05
    code, out = cli(tmp_path, "-o", tmp_path / "bad.json", "--feature-base", "1,2")
    assert code == 2 and "--feature-base '1,2' is not origin, estimate or x,y,z" in out


def test_mixed_units(cli, tmp_path):
    def mm_sample(doc):
        doc["samples"][4]["p_cam"] = [v * 1e3 for v in doc["samples"][4]["p_cam"]]

    code, out = cli(_pairs(tmp_path, edit=mm_sample), "-o", tmp_path / "he.json")
    assert code == 2 and "mixed mm and m" in out and "samples [4]" in out
    code, out = cli(
        _pairs(tmp_path, units="mm", edit=lambda d: d.update(units="m")), "-o", tmp_path / "he.json"
    )
    assert code == 2 and "that is millimetres" in out and "--units mm" in out
    code, out = cli(tmp_path, "-o", tmp_path / "he.json", "--units", "mm")
    assert code == 0, out


def test_rotation_poor_poses_for_classical_methods(cli, tmp_path):
    cell = simulate_cell(n_poses=10, max_angle=0.0, rng=3)
    C = np.einsum("ij,njk->nik", invert(cell.T_base_camera), cell.T_base_flange)
    write_samples(
        tmp_path / "samples.json",
        [HandEyeSample(T_base_flange=T, T_cam_target=c) for T, c in zip(cell.T_base_flange, C, strict=True)],
    )
    code, out = cli(tmp_path, "-o", tmp_path / "he.json", "--method", "park")
    assert code == 2 and "orientations differ by at most 0.00 deg" in out and "rotate the flange" in out


def test_not_a_data_folder(cli, tmp_path):
    code, out = cli(tmp_path, "-o", tmp_path / "he.json")
    assert code == 2 and "no hand-eye data found" in out and "--layout" in out


# -- the real ancorasir data (Franka + PhoXi) -------------------------------------------------------
@pytest.mark.data
def test_ancorasir_sample_folder_from_raw_scans(cli, flange_data, tmp_path):
    folder = flange_data / "calib_toolbox/data/2019-06-14-sample"
    code, out = cli(folder, "-o", tmp_path / "he.json")
    assert code == 2 and "coplanar" in out and "--allow-coplanar" in out
    code, out = cli(folder, "-o", tmp_path / "he.json", "--allow-coplanar", "--remeasure")
    assert code == 0, out
    doc = json.loads((tmp_path / "he.json").read_text())
    assert doc["metrics"]["rms_inliers_m"] < 0.6e-3 and "coplanar" in " ".join(doc["warnings"])
    assert "measured from 6 scans" in out and "mixed units: p_cam in mm" in out


@pytest.mark.data
def test_ancorasir_point_pairs_and_kinect(cli, flange_data, tmp_path):
    code, out = cli(flange_data / "paper_dda5a35/data/franka", "-o", tmp_path / "he.json")
    assert code == 0, out
    assert "43 inliers, 5 outliers" in out and "sample 44: residual 37." in out
    H = np.load(flange_data / "paper_dda5a35/data/franka/H.npy")
    H[:3, 3] *= 1e-3
    dt, dr = pose_error(_T(tmp_path / "he.json"), H)
    assert dt < 2e-3 and np.degrees(dr) < 0.3
    code, out = cli(
        flange_data / "paper_dda5a35/Kinect_Result", "-o", tmp_path / "k.json", "--feature", "estimate"
    )
    assert code == 0, out
    assert json.loads((tmp_path / "k.json").read_text())["metrics"]["mean_all_m"] < 2.5e-3
