"""Reader of an RGB-D sequence in the TUM RGB-D benchmark's folder format (Sturm et al., IROS 2012), to
run the mapping estimator on real recorded data and score it against the sequence's ground truth.

A folder holds ``rgb.txt`` and ``depth.txt`` (``timestamp path`` per line, ``#`` comments), the PNG
images they name (depth: 16-bit, ``depth_scale`` 5000 per metre) and ``groundtruth.txt``
(``timestamp tx ty tz qx qy qz qw``, the camera's optical frame in the motion-capture world). Colour
and depth are associated by nearest timestamps within ``max_dt`` (the benchmark's associate.py).
Intrinsics: the benchmark's published calibration per Freiburg sensor, chosen from the folder name
(``freiburg1/2/3``), else the default 525 px / centre.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.hal.readings import Intrinsics
from weldcell.sdk.errors import DataError

DEPTH_SCALE = 5000.0
CALIBRATION = {  # the benchmark's published colour intrinsics (fx, fy, cx, cy) per sensor
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}


@dataclass
class TumSequence:
    """Associated frames (times, colour and depth paths) and the ground truth ``T_world_cam``."""

    root: Path
    times: np.ndarray
    rgb: list[Path]
    depth: list[Path]
    gt_times: np.ndarray
    gt_poses: np.ndarray
    intrinsics: Intrinsics
    depth_scale: float = DEPTH_SCALE
    """Depth image units per metre (the benchmark's 5000)."""

    def frame(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Colour (RGB uint8) and depth (float32 metres, 0 = none) of frame ``i``."""
        import cv2

        bgr = cv2.imread(str(self.rgb[i]), cv2.IMREAD_COLOR)
        d = cv2.imread(str(self.depth[i]), cv2.IMREAD_UNCHANGED)
        if bgr is None or d is None:
            raise DataError(f"cannot read frame {i} of {self.root}", "check the rgb/ and depth/ PNG files")
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), d.astype(np.float32) / np.float32(self.depth_scale)

    def truth_at(self, t: float, max_dt: float = 0.02) -> np.ndarray | None:
        """Ground-truth pose nearest to ``t`` (None if none within ``max_dt``)."""
        i = int(np.argmin(np.abs(self.gt_times - t)))
        return self.gt_poses[i] if abs(self.gt_times[i] - t) <= max_dt else None


def _list(path: Path) -> tuple[np.ndarray, list[str]]:
    if not path.is_file():
        raise DataError(f"{path} is missing", "give a TUM RGB-D sequence folder (rgb.txt, depth.txt, ...)")
    t, names = [], []
    for line in path.read_text().splitlines():
        f = line.split()
        if not f or f[0].startswith("#"):
            continue
        t.append(float(f[0]))
        names.append(f[1])
    return np.asarray(t), names


def load_tum(
    root: str | Path,
    max_dt: float = 0.02,
    max_frames: int | None = None,
    intrinsics: Intrinsics | None = None,
    depth_scale: float = DEPTH_SCALE,
) -> TumSequence:
    """Read a TUM RGB-D sequence folder (see the module docstring); ``intrinsics`` overrides the
    calibration chosen from the folder name, ``depth_scale`` the depth units per metre."""
    root = Path(root)
    tc, rgb = _list(root / "rgb.txt")
    td, dep = _list(root / "depth.txt")
    gt = root / "groundtruth.txt"
    if not gt.is_file():
        raise DataError(f"{gt} is missing", "the ATE needs the sequence's ground truth")
    rows = np.array(
        [[float(v) for v in ln.split()] for ln in gt.read_text().splitlines() if ln.strip() and ln[0] != "#"]
    )
    if rows.ndim != 2 or rows.shape[1] != 8:
        raise DataError(f"{gt}: expected 'timestamp tx ty tz qx qy qz qw' lines", "use the benchmark's file")
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(rows[:, 4:8]).as_matrix()
    T[:, :3, 3] = rows[:, 1:4]
    times, rp, dp = [], [], []
    used: set[int] = set()
    for t, name in zip(tc, rgb, strict=True):
        j = int(np.argmin(np.abs(td - t)))
        if abs(td[j] - t) <= max_dt and j not in used:
            used.add(j)
            times.append(t)
            rp.append(root / name)
            dp.append(root / dep[j])
    if len(times) < 2:
        raise DataError(f"{root}: fewer than 2 colour/depth pairs within {max_dt} s", "check the time stamps")
    if max_frames:
        times, rp, dp = times[:max_frames], rp[:max_frames], dp[:max_frames]
    import cv2

    h, w = cv2.imread(str(rp[0]), cv2.IMREAD_UNCHANGED).shape[:2]
    key = next((k for k in CALIBRATION if k in str(root)), None)
    fx, fy, cx, cy = CALIBRATION[key] if key else (525.0 * w / 640, 525.0 * w / 640, (w - 1) / 2, (h - 1) / 2)
    K = intrinsics or Intrinsics(w, h, fx, fy, cx, cy)
    return TumSequence(root, np.asarray(times), rp, dp, rows[:, 0], T, K, float(depth_scale))


def run_visual(seq: TumSequence, settings, every: int = 1) -> dict:
    """The mapping estimator, visual only (no IMU, no GNSS), over the sequence; key-frame ATE after
    SE(3) alignment, before and after the global optimisation."""
    from weldcell.plugins.mapping.estimator import VioEstimator
    from weldcell.plugins.mapping.frontend import OrbFrontEnd
    from weldcell.plugins.mapping.interp import ate_rmse

    es = settings.estimator.model_copy(update={"use_imu": False, "use_gnss": False})
    est = VioEstimator(es, OrbFrontEnd(settings.frontend), np.eye(4), settings.imu_noise)
    truth: dict[int, np.ndarray] = {}
    for i in range(0, len(seq.times), every):
        rgb, depth = seq.frame(i)
        res = est.process_frame(float(seq.times[i]), rgb, depth, seq.intrinsics)
        if res.keyframe is not None:
            g = seq.truth_at(seq.times[i])
            if g is not None:
                truth[res.keyframe.index] = g
    keep = [k for k in est.keyframes if k.index in truth]
    if len(keep) < 3:
        raise DataError("fewer than 3 key frames have ground truth", "check groundtruth.txt's time span")
    ref = np.array([truth[k.index][:3, 3] for k in keep])
    before = ate_rmse(np.array([k.T_world_imu[:3, 3] for k in keep]), ref)[0]
    est.finalize()
    after = ate_rmse(np.array([k.T_world_imu[:3, 3] for k in keep]), ref)[0]
    return {
        "ate_m": after,
        "ate_smoother_m": before,
        "keyframes": len(est.keyframes),
        "frames": len(range(0, len(seq.times), every)),
        "lost": sum(e["kind"] == "lost" for e in est.events),
        "loops": len(est.global_graph.loops),
        "timing": {k: float(np.mean(v)) for k, v in est.timing.items() if v},
    }
