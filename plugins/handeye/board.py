"""Calibration-board pose from a photo (ChArUco, ArUco grid or plain chessboard): detection + solvePnP;
camera intrinsics from a file (OpenCV YAML/XML/JSON, or plain JSON) or calibrated from the same photos.
OpenCV is imported inside these functions only."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from weldcell.sdk.errors import DataError, MissingExtraError


def _cv2():
    try:
        import cv2
    except ImportError:
        raise MissingExtraError("board detection", "cv2", "vision") from None
    return cv2


BOARD_KINDS = ("charuco", "aruco-grid", "chessboard")


@dataclass
class BoardSpec:
    """A board: ``kind`` "charuco" (squares_x x squares_y chessboard, square and marker side in m),
    "aruco-grid" (squares_x x squares_y markers of ``marker`` m separated by ``separation`` m) or
    "chessboard" (squares_x x squares_y INNER corners, OpenCV's pattern size, ``square`` m apart)."""

    kind: str = "charuco"
    squares_x: int = 5
    squares_y: int = 7
    square: float = 0.04
    marker: float = 0.02
    separation: float = 0.01
    dictionary: str = "DICT_6X6_250"

    @classmethod
    def parse(cls, text: str) -> BoardSpec:
        """A board from the command line, lengths in mm: ``chessboard:9x6:25`` (inner corners, square),
        ``charuco:5x7:40:20[:DICT_6X6_250]`` (squares, square, marker),
        ``aruco-grid:5x7:40:10[:DICT]`` (markers, marker, separation)."""
        parts = [p.strip() for p in str(text).split(":")]
        fix = "e.g. chessboard:9x6:25, charuco:5x7:40:20:DICT_6X6_250 or aruco-grid:5x7:40:10 (lengths in mm)"
        try:
            kind = parts[0]
            nx, ny = (int(v) for v in parts[1].lower().split("x"))
            nums = [float(v) * 1e-3 for v in parts[2:] if not v.upper().startswith("DICT_")]
            dicts = [v for v in parts[2:] if v.upper().startswith("DICT_")]
        except (IndexError, ValueError):
            raise DataError(f"board '{text}' is not KIND:NXxNY:LENGTHS", fix) from None
        need = {"chessboard": 1, "charuco": 2, "aruco-grid": 2}
        if kind not in need or len(nums) != need[kind] or min(nx, ny) < 2 or min(nums) <= 0:
            raise DataError(f"board '{text}': {kind} needs {need.get(kind, '?')} positive lengths", fix)
        kw: dict = {"kind": kind, "squares_x": nx, "squares_y": ny}
        if dicts:
            kw["dictionary"] = dicts[0].upper()
        if kind == "chessboard":
            kw["square"] = nums[0]
        elif kind == "charuco":
            kw["square"], kw["marker"] = nums
        else:
            kw["marker"], kw["separation"] = nums
        return cls(**kw)

    @classmethod
    def from_dict(cls, d: dict, where: str = "board") -> BoardSpec:
        """A board from a settings table (lengths in m); DataError naming an unknown key."""
        from weldcell.sdk.datafile import check_keys

        check_keys(d, [f for f in cls.__dataclass_fields__], where)
        if d.get("kind", "charuco") not in BOARD_KINDS:
            raise DataError(
                f"{where}: unknown board kind {d.get('kind')!r}", f"use one of {', '.join(BOARD_KINDS)}"
            )
        return cls(**d)

    def object_points(self) -> np.ndarray:
        """Chessboard inner corners in the board frame (m), row-major as OpenCV detects them."""
        g = np.mgrid[0 : self.squares_x, 0 : self.squares_y].T.reshape(-1, 2) * self.square
        return np.column_stack([g, np.zeros(len(g))])

    def build(self):
        cv2 = _cv2()
        if self.kind == "chessboard":
            return None, None
        if not hasattr(cv2.aruco, self.dictionary):
            raise DataError(
                f"unknown ArUco dictionary '{self.dictionary}'", "use e.g. DICT_6X6_250, DICT_5X5_100"
            )
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        if self.kind == "charuco":
            return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square, self.marker, d), d
        if self.kind == "aruco-grid":
            return cv2.aruco.GridBoard((self.squares_x, self.squares_y), self.marker, self.separation, d), d
        raise DataError(f"unknown board kind '{self.kind}'", f"use one of {', '.join(BOARD_KINDS)}")


@dataclass
class BoardPose:
    """``T_cam_board`` (board frame into the camera), points used and RMS reprojection error (px)."""

    T_cam_board: np.ndarray
    n_points: int
    reprojection_rms: float
    marker_ids: list[int]


_K_KEYS = ("camera_matrix", "cameraMatrix", "K", "intrinsic_matrix", "M")
_D_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "dist", "D", "distortion")


def read_intrinsics(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Camera matrix and distortion from a file: OpenCV's ``cv2.FileStorage`` YAML/XML/JSON
    (``camera_matrix`` + ``distortion_coefficients``, as written by OpenCV's calibration samples), or a
    plain JSON object with the matrix as rows (``camera_matrix``/``K``) or ``fx, fy, cx, cy``, and
    ``distortion_coefficients``/``dist``/``D`` (default none). DataError naming what is missing."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"intrinsics file not found: {path}", "check the path")
    K = dist = None
    if path.suffix.lower() == ".json":
        K, dist = _intrinsics_json(path)
    if K is None:
        K, dist = _intrinsics_filestorage(path)
    if K is None or K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise DataError(
            f"{path}: no 3x3 camera matrix (keys tried: {', '.join(_K_KEYS)}, or fx/fy/cx/cy)",
            "write camera_matrix and distortion_coefficients as OpenCV's calibration does",
        )
    dist = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    if dist.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
        raise DataError(
            f"{path}: {dist.size} distortion coefficients", "give 4, 5, 8, 12 or 14 (OpenCV's model)"
        )
    return np.asarray(K, float), dist


def _intrinsics_filestorage(path: Path):
    cv2 = _cv2()
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as e:
        raise DataError(
            f"{path}: not an OpenCV YAML/XML/JSON file ({str(e).splitlines()[-1][:80]})",
            "write it with cv2.FileStorage or as plain JSON",
        ) from None
    try:
        K = next((m for k in _K_KEYS if (m := fs.getNode(k).mat()) is not None), None)
        dist = next((m for k in _D_KEYS if (m := fs.getNode(k).mat()) is not None), None)
    finally:
        fs.release()
    return K, dist


def _intrinsics_json(path: Path):
    from weldcell.sdk.datafile import read_json_file

    doc = read_json_file(path, "intrinsics file")
    if not isinstance(doc, dict):
        return None, None
    raw = next((doc[k] for k in _K_KEYS if k in doc), None)
    if isinstance(raw, dict) and "data" in raw:  # OpenCV's own JSON layout: FileStorage reads it
        return None, None
    if raw is None and all(k in doc for k in ("fx", "fy", "cx", "cy")):
        raw = [[doc["fx"], 0, doc["cx"]], [0, doc["fy"], doc["cy"]], [0, 0, 1]]
    if raw is None:
        return None, None
    try:
        K = np.asarray(raw, float).reshape(3, 3)
        d = next((doc[k] for k in _D_KEYS if k in doc), None)
        dist = None if d is None else np.asarray(d, float).ravel()
    except (TypeError, ValueError):
        raise DataError(
            f"{path}: the camera matrix or distortion is not numbers",
            "write camera_matrix as 3 rows of 3 numbers",
        ) from None
    return K, dist


def _gray(image):
    cv2 = _cv2()
    if isinstance(image, str | Path):
        img = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise DataError(f"cannot read image {image}", "check the path and format")
        return img
    img = np.asarray(image)
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img


def detect_board(image, spec: BoardSpec, min_points: int = 6) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Board points (object (N, 3) m, image (N, 2) px) and marker ids found in a photo; DataError when
    too few are seen."""
    cv2 = _cv2()
    img = _gray(image)
    name = Path(image).name if isinstance(image, str | Path) else "image"
    if spec.kind == "chessboard":
        ok, corners = cv2.findChessboardCornersSB(img, (spec.squares_x, spec.squares_y))
        if not ok:
            raise DataError(
                f"{name}: chessboard of {spec.squares_x}x{spec.squares_y} inner corners not found",
                "check the board size (inner corners, not squares), focus and lighting",
            )
        return spec.object_points(), corners.reshape(-1, 2).astype(float), []
    board, d = spec.build()
    m_ids = None
    if spec.kind == "charuco":
        ch_corners, ch_ids, m_corners, m_ids = cv2.aruco.CharucoDetector(board).detectBoard(img)
        if ch_ids is None or len(ch_ids) < min_points:
            raise DataError(
                f"{name}: ChArUco board: {0 if ch_ids is None else len(ch_ids)} corners found, "
                f"need {min_points}",
                "check the board parameters (squares, dictionary), focus and lighting",
            )
        obj, imgp = board.matchImagePoints(ch_corners, ch_ids)
    else:
        m_corners, m_ids, _ = cv2.aruco.ArucoDetector(d).detectMarkers(img)
        if m_ids is None or 4 * len(m_ids) < min_points:
            raise DataError(
                f"{name}: ArUco grid: too few markers found", "check the board parameters and image"
            )
        obj, imgp = board.matchImagePoints(m_corners, m_ids)
    ids = [] if m_ids is None else [int(i) for i in np.ravel(m_ids)]
    return obj.reshape(-1, 3).astype(float), imgp.reshape(-1, 2).astype(float), ids


@dataclass
class Intrinsics:
    """Camera matrix, distortion, and how they were obtained (file, or calibrated: RMS px, images)."""

    K: np.ndarray
    dist: np.ndarray
    source: str
    rms: float | None = None
    n_images: int = 0


def calibrate_intrinsics(images: list, spec: BoardSpec, min_images: int = 4) -> Intrinsics:
    """Zhang's calibration (cv2.calibrateCamera) from the board photos themselves, for when no
    intrinsics file exists; photos where the board is not found are skipped. DataError when fewer
    than ``min_images`` remain or the RMS reprojection error exceeds 2 px."""
    cv2 = _cv2()
    obj, imgp, size = [], [], None
    for im in images:
        try:
            o, p, _ = detect_board(im, spec)
        except DataError:
            continue
        if len(o) < 6:
            continue
        obj.append(o.astype(np.float32))
        imgp.append(p.astype(np.float32))
        size = _gray(im).shape[::-1]
    if len(obj) < min_images:
        raise DataError(
            f"the board was found in {len(obj)} of {len(images)} photos; calibrating the camera needs "
            f"{min_images}",
            "check --board, or give the intrinsics file (--intrinsics)",
        )
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, imgp, size, None, None)
    if rms > 2.0:
        raise DataError(
            f"camera calibration from the photos: RMS reprojection error {rms:.2f} px",
            "check --board (sizes, inner corners) or give the intrinsics file (--intrinsics)",
        )
    return Intrinsics(K, dist.ravel(), "calibrated from the board photos", float(rms), len(obj))


def board_pose(
    image, spec: BoardSpec, K: np.ndarray, dist: np.ndarray | None = None, min_points: int = 6
) -> BoardPose:
    """Detect the board in ``image`` (array or path) and estimate ``T_cam_board`` by solvePnP
    (iterative, from the matched board points). Raises DataError when too few points are seen."""
    cv2 = _cv2()
    obj, imgp, ids = detect_board(image, spec, min_points)
    dist = np.zeros(5) if dist is None else np.asarray(dist, float)
    ok, rvec, tvec = cv2.solvePnP(obj, imgp, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise DataError("solvePnP failed on the detected board points", "check the intrinsics")
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - imgp) ** 2, axis=1))))
    R, _ = cv2.Rodrigues(rvec)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, tvec.ravel()
    return BoardPose(T, len(obj), rms, ids)


def board_poses(samples: list, s: dict, metrics: dict) -> np.ndarray:
    """Board poses ``T_cam_target``: given, or from the photos (board spec + intrinsics, or intrinsics
    calibrated from the same photos with ``calibrate_intrinsics``). A photo without the board is a
    row of NaN named in ``metrics["board_not_found"]`` (the caller drops it with its robot pose).
    ``s``: calibrate()'s settings (``board``, ``intrinsics``, ``calibrate_intrinsics``)."""
    from weldcell.sdk.errors import UsageError
    from weldcell.sdk.handeye_files import sample_id

    imgs = [smp.image for smp in samples if smp.T_cam_target is None and smp.image is not None]
    intr = None
    if imgs:
        b = s["board"]
        spec = b if isinstance(b, BoardSpec) else BoardSpec.from_dict(dict(b or {}), "board settings")
        if s["intrinsics"] is not None:
            K, dist = s["intrinsics"]
            intr = Intrinsics(np.asarray(K, float), np.asarray(dist, float), "given")
        elif s["calibrate_intrinsics"]:
            intr = calibrate_intrinsics(imgs, spec)
        else:
            raise UsageError(
                "board images need camera intrinsics",
                "pass --intrinsics FILE (OpenCV YAML/XML/JSON) or --calibrate-intrinsics "
                "(in Python: intrinsics=(K, dist) or calibrate_intrinsics=True)",
            )
        metrics["intrinsics"] = {
            "source": intr.source,
            "K": intr.K.tolist(),
            "dist": intr.dist.tolist(),
            "rms_px": intr.rms,
            "images": intr.n_images,
        }
    out, rms = [], []
    for i, smp in enumerate(samples):
        if smp.T_cam_target is not None:
            out.append(np.asarray(smp.T_cam_target, float))
        elif smp.image is not None:
            try:
                bp = board_pose(smp.image, spec, intr.K, intr.dist)
            except DataError as e:  # that photo is left out (with its robot pose), and said so
                metrics.setdefault("board_not_found", []).append(f"{sample_id(smp, i)}: {e.message}")
                out.append(np.full((4, 4), np.nan))
                continue
            out.append(bp.T_cam_board)
            rms.append(bp.reprojection_rms)
        else:
            raise DataError(
                f"sample {i} has no board pose or image", "target-based methods need T_cam_target or image"
            )
    if rms:
        metrics["board_reprojection_rms_px"] = rms
    return np.array(out)
