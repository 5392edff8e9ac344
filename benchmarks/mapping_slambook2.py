"""Cell 4 estimator on real Kinect v1 RGB-D frames with reference poses: the five frames of ``ch5/rgbd``
in https://github.com/gaoxiang12/slambook2 (MIT licence), converted to the TUM RGB-D folder format in a
temporary folder, visual only, key-frame ATE against the frames' ``pose.txt`` after SE(3) alignment.

    .venv/bin/python benchmarks/mapping_slambook2.py /path/to/slambook2
    .venv/bin/python benchmarks/mapping_slambook2.py /path/to/slambook2.git --git   # a bare mirror

Frames 3-5 are shipped in tests/mapping/data/slambook2_rgbd (tests/mapping/test_real_rgbd.py).
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np

INTRINSICS = (518.0, 519.0, 325.5, 253.5)  # the source's joinMap.cpp
DEPTH_SCALE = 1000.0  # its depth/*.pgm: millimetres


def _read(src: Path, rel: str, git: bool) -> bytes:
    if git:
        return subprocess.run(
            ["git", "-C", str(src), "show", f"HEAD:{rel}"], check=True, capture_output=True
        ).stdout
    return (src / rel).read_bytes()


def convert(src: Path, out: Path, git: bool = False) -> Path:
    """ch5/rgbd of a slambook2 checkout (or bare mirror) -> a TUM folder (depth 5000 per metre)."""
    (out / "rgb").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(exist_ok=True)
    poses = np.loadtxt(_read(src, "ch5/rgbd/pose.txt", git).decode().splitlines())
    rl, dl, gl = [], [], []
    for i in range(1, len(poses) + 1):
        t = 1000.0 + i
        c = cv2.imdecode(
            np.frombuffer(_read(src, f"ch5/rgbd/color/{i}.png", git), np.uint8), cv2.IMREAD_COLOR
        )
        raw = np.frombuffer(_read(src, f"ch5/rgbd/depth/{i}.pgm", git), np.uint8)
        z = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED).astype(np.float64) / DEPTH_SCALE
        cv2.imwrite(str(out / "rgb" / f"{t:.6f}.png"), c)
        cv2.imwrite(str(out / "depth" / f"{t:.6f}.png"), np.round(z * 5000).clip(0, 65535).astype(np.uint16))
        rl.append(f"{t:.6f} rgb/{t:.6f}.png")
        dl.append(f"{t:.6f} depth/{t:.6f}.png")
        gl.append(f"{t:.6f} " + " ".join(f"{v:.7g}" for v in poses[i - 1]))
    for name, lines in (("rgb.txt", rl), ("depth.txt", dl), ("groundtruth.txt", gl)):
        (out / name).write_text("\n".join(lines) + "\n")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("source", type=Path, help="a slambook2 checkout (or, with --git, a git directory)")
    ap.add_argument("--git", action="store_true", help="read the files from the repository's HEAD")
    args = ap.parse_args()
    from weldcell.hal.readings import Intrinsics
    from weldcell.plugins.mapping.settings import MapJobSettings
    from weldcell.plugins.mapping.tum import load_tum, run_visual

    with tempfile.TemporaryDirectory() as d:
        seq = load_tum(convert(args.source, Path(d), args.git), intrinsics=Intrinsics(640, 480, *INTRINSICS))
        s = MapJobSettings.model_validate({"frontend": {"depth_noise": 1.4e-3}})  # Kinect v1
        r = run_visual(seq, s)
    span = np.linalg.norm(seq.gt_poses[-1][:3, 3] - seq.gt_poses[0][:3, 3])
    print(
        f"slambook2 ch5/rgbd (Kinect v1, {r['frames']} frames over {span:.2f} m): "
        f"{r['keyframes']} key frames, "
        f"lost {r['lost']}: ATE {r['ate_m']:.4f} m (smoother alone {r['ate_smoother_m']:.4f} m)"
    )


if __name__ == "__main__":
    main()
