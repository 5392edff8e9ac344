"""The front end and the estimator on real RGB-D data: three Kinect v1 frames with reference poses
(tests/mapping/data/slambook2_rgbd, MIT licence, see its README)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.hal.readings import Intrinsics
from weldcell.plugins.mapping.frontend import OrbFrontEnd
from weldcell.plugins.mapping.settings import MapJobSettings
from weldcell.plugins.mapping.tum import load_tum, run_visual

DATA = Path(__file__).parent / "data" / "slambook2_rgbd"
KINECT = Intrinsics(640, 480, 518.0, 519.0, 325.5, 253.5)
SETTINGS = MapJobSettings.model_validate({"frontend": {"depth_noise": 1.4e-3}})  # Kinect v1


def test_real_frames_load_with_their_depth_scale():
    seq = load_tum(DATA, intrinsics=KINECT)
    assert len(seq.times) == 3 and seq.intrinsics.fx == 518.0
    rgb, depth = seq.frame(0)
    assert rgb.shape == (480, 640, 3) and depth.dtype == np.float32
    z = depth[depth > 0]
    assert 0.5 < np.median(z) < 5.0  # metres: the 5000-per-metre scale was applied


def test_relative_poses_on_real_frames_agree_with_the_reference():
    """RANSAC PnP between consecutive real frames (0.23-0.73 m, 4-7° apart): within 40 mm and 0.5° of the
    reference poses, and the reported sigma is not several times smaller than that error."""
    seq = load_tum(DATA, intrinsics=KINECT)
    fe = OrbFrontEnd(SETTINGS.frontend)
    feats = [fe.extract(*seq.frame(i), seq.intrinsics) for i in range(3)]
    for i in range(2):
        r = fe.relative_pose(feats[i], feats[i + 1], seq.intrinsics)
        assert r.ok and r.inliers >= 50
        T_ref = np.linalg.inv(seq.gt_poses[i]) @ seq.gt_poses[i + 1]
        E = np.linalg.inv(T_ref) @ r.T_ref_cur
        err_t = np.linalg.norm(E[:3, 3])
        assert err_t < 0.04
        assert np.degrees(Rotation.from_matrix(E[:3, :3]).magnitude()) < 0.5
        assert err_t / np.sqrt(3) < 4 * max(r.sigma_t, 0.005)


def test_estimator_runs_on_real_frames():
    r = run_visual(load_tum(DATA, intrinsics=KINECT), SETTINGS)
    assert r["keyframes"] == 3 and r["lost"] == 0
    assert r["ate_m"] < 0.03
