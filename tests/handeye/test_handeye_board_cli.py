"""Issue 13 item 4: board photos from the command line — the board (chessboard, ChArUco, ArUco grid),
the intrinsics (OpenCV YAML / JSON file, or calibrated from the same photos) and --settings keys."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from weldcell.plugins.handeye.result import HandEyeSample
from weldcell.plugins.handeye.samples_io import write_samples
from weldcell.sdk.geometry import T_from_rpy, invert, pose_error

K_TRUE = np.array([[600.0, 0, 322.0], [0, 605.0, 238.0], [0, 0, 1]])
X_TRUE = T_from_rpy([0.02, -0.03, 1.55], [0.04, -0.06, 0.09])  # T_flange_camera
SQUARE = 0.03  # m; 9 x 6 squares = 8 x 5 inner corners (one even: no 180 deg ambiguity)



def _render(T_cam_board: np.ndarray, size=(640, 480)) -> np.ndarray:
    """A chessboard photo: the board texture (9 x 6 squares of 30 mm, white margin) warped into a
    pinhole camera with ``K_TRUE`` by the plane homography K [r1 r2 t]."""
    import cv2

    px = 2e-4  # m per texture pixel: a square is exactly 150 pixels
    nx, ny, margin = 9, 6, 0.03
    q, m = round(SQUARE / px), round(margin / px)
    tex = np.full((ny * q + 2 * m, nx * q + 2 * m), 255, np.uint8)
    for i in range(nx):
        for j in range(ny):
            if (i + j) % 2 == 0:
                tex[m + j * q : m + (j + 1) * q, m + i * q : m + (i + 1) * q] = 0
    # texture pixel -> board metres (origin at the first inner corner)
    S = np.array([[px, 0, px / 2 - margin - SQUARE], [0, px, px / 2 - margin - SQUARE], [0, 0, 1]])
    Hm = K_TRUE @ np.column_stack([T_cam_board[:3, 0], T_cam_board[:3, 1], T_cam_board[:3, 3]]) @ S
    img = cv2.warpPerspective(tex, Hm, size, flags=cv2.INTER_LINEAR, borderValue=200)
    return cv2.GaussianBlur(img, (3, 3), 0.6)


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    """Ten rendered photos of a fixed chessboard from a camera on the flange (eye-in-hand), with the
    robot poses, as samples.json."""
    import cv2

    folder = tmp_path_factory.mktemp("board")
    T_base_board = T_from_rpy([0, 0, 0.3], [0.7, 0.1, 0.02])
    rng = np.random.default_rng(2)
    samples = []
    for i in range(10):
        # the camera looks at the board's printed side (along its +z) from 0.45-0.6 m, tilted up to ~25 deg
        look = T_from_rpy([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), rng.uniform(-0.5, 0.5)])
        T_board_cam = look.copy()
        T_board_cam[:3, 3] = np.array([0.105, 0.06, 0]) - look[:3, 2] * rng.uniform(0.45, 0.6)
        G = T_base_board @ T_board_cam @ invert(X_TRUE)
        name = f"{i + 1:02d}.png"
        cv2.imwrite(str(folder / name), _render(invert(T_board_cam)))
        samples.append(HandEyeSample(T_base_flange=G, image=str(folder / name)))
    write_samples(folder / "samples.json", samples, "eye-in-hand")
    return folder


def _T(path: Path) -> np.ndarray:
    return np.array(json.loads(path.read_text())["T"])


def test_chessboard_photos_from_the_command_line(cli, photos, tmp_path):
    """--board chessboard with the square size; intrinsics calibrated from the same photos, or read
    from OpenCV's YAML (cv2.FileStorage) or a plain JSON; without either, one clear usage error."""
    import cv2

    code, out = cli(
        photos, "-o", tmp_path / "c.json", "--board", "chessboard:8x5:30", "--calibrate-intrinsics"
    )
    assert code == 0, out
    assert "method park" in out  # photos: a board method by default
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["metrics"]["intrinsics"]["source"] == "calibrated from the board photos"
    assert abs(doc["metrics"]["intrinsics"]["K"][0][0] - 600) < 6
    dt, dr = pose_error(_T(tmp_path / "c.json"), X_TRUE)
    assert dt < 2e-3 and np.degrees(dr) < 0.15, (dt, np.degrees(dr))  # measured 1.0 mm, 0.05 deg

    fs = cv2.FileStorage(str(tmp_path / "cam.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K_TRUE)
    fs.write("distortion_coefficients", np.zeros((1, 5)))
    fs.release()
    (tmp_path / "cam.json").write_text(json.dumps({"fx": 600.0, "fy": 605.0, "cx": 322.0, "cy": 238.0}))
    for f in ("cam.yml", "cam.json"):
        code, out = cli(
            photos, "-o", tmp_path / "k.json", "--board", "chessboard:8x5:30", "--intrinsics", tmp_path / f
        )
        assert code == 0, out
        dt, dr = pose_error(_T(tmp_path / "k.json"), X_TRUE)
        assert dt < 1e-3 and np.degrees(dr) < 0.1, (f, dt, np.degrees(dr))  # measured 0.27 mm, 0.03 deg
    code, out = cli(photos, "-o", tmp_path / "n.json", "--board", "chessboard:8x5:30")
    assert code == 2 and "board images need camera intrinsics" in out and "--calibrate-intrinsics" in out
    code, out = cli(photos, "-o", tmp_path / "n.json", "--board", "chessboard:8x5", "--calibrate-intrinsics")
    assert code == 2 and "chessboard needs 1 positive lengths" in out


def test_settings_file_board_keys_and_unknown_keys(cli, photos, tmp_path):
    """--settings may carry the board and the intrinsics; a key the command does not use is an error,
    and board keys for a flange method are refused rather than dropped."""
    (tmp_path / "s.toml").write_text(
        'calibrate_intrinsics = true\n[board]\nkind = "chessboard"\n'
        "squares_x = 8\nsquares_y = 5\nsquare = 0.03\n"
    )
    code, out = cli(photos, "-o", tmp_path / "s.json", "--settings", tmp_path / "s.toml", "--method", "tsai")
    assert code == 0, out
    assert pose_error(_T(tmp_path / "s.json"), X_TRUE)[0] < 3e-3
    (tmp_path / "u.toml").write_text('intrinsic = "cam.yml"\n')
    code, out = cli(photos, "-o", tmp_path / "u.json", "--settings", tmp_path / "u.toml")
    assert code == 2 and "intrinsic" in out and "unknown" in out.lower()
    code, out = cli(photos, "-o", tmp_path / "f.json", "--method", "flange", "--board", "chessboard:8x5:30")
    assert code == 2 and "used only by the board methods" in out


@pytest.mark.data
def test_intrinsics_yaml_and_charuco_option_on_real_photos(aruco_data):
    """OpenCV's own tutorial files: the YAML written by its calibration sample, and the ChArUco board
    given as a command-line spec, find the board in the real photo."""
    from weldcell.plugins.handeye.board import BoardSpec, board_pose, read_intrinsics

    K, dist = read_intrinsics(aruco_data / "modules/aruco/samples/tutorial_camera_charuco.yml")
    assert abs(K[0, 0] - 452.51) < 0.01 and dist.shape == (5,)
    spec = BoardSpec.parse("charuco:5x7:40:20:DICT_6X6_250")
    assert (spec.square, spec.marker, spec.dictionary) == (0.04, 0.02, "DICT_6X6_250")
    bp = board_pose(
        aruco_data / "modules/aruco/tutorials/charuco_detection/images/choriginal.jpg", spec, K, dist
    )
    assert bp.n_points >= 20 and bp.reprojection_rms < 1.0
    assert 0.1 < np.linalg.norm(bp.T_cam_board[:3, 3]) < 1.5  # a desk board, tens of cm away
