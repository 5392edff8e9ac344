"""Cell 4 estimator on a real RGB-D sequence: the TUM RGB-D benchmark's folder format (e.g. fr1/xyz,
fr1/desk), visual only (the sequences have no gyroscope), key-frame ATE against the motion-capture
ground truth after SE(3) alignment, before and after the global optimisation.

    .venv/bin/python benchmarks/mapping_tum.py /data/rgbd_dataset_freiburg1_xyz
    .venv/bin/python benchmarks/mapping_tum.py SEQ --every 2 --max-frames 300
    .venv/bin/python benchmarks/mapping_tum.py tests/mapping/data/slambook2_rgbd \
        --intrinsics 518 519 325.5 253.5
    .venv/bin/python benchmarks/mapping_slambook2.py SLAMBOOK2_CHECKOUT   # all 5 real Kinect frames

The sequence is not shipped (it is downloaded from the benchmark's site, CC BY licence); the reader is
tested on an excerpt of the simulated site written in the same format (tests/mapping/test_estimation.py).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "folder", type=Path, help="a TUM RGB-D sequence folder (rgb.txt, depth.txt, groundtruth.txt)"
    )
    ap.add_argument("--every", type=int, default=1, help="use every n-th frame")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--depth-noise", type=float, default=1.4e-3, help="Kinect v1: sigma_z ~ 1.4e-3 z^2 [1/m]")
    ap.add_argument(
        "--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"), help="override the calibration"
    )
    ap.add_argument("--depth-scale", type=float, default=5000.0, help="depth units per metre (TUM: 5000)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    from weldcell.plugins.mapping.settings import MapJobSettings
    from weldcell.plugins.mapping.tum import load_tum, run_visual

    K = None
    if args.intrinsics:
        import cv2
        from weldcell.hal.readings import Intrinsics

        first = next(
            ln.split()[1] for ln in (args.folder / "rgb.txt").read_text().splitlines() if ln[:1] != "#"
        )
        h, w = cv2.imread(str(args.folder / first)).shape[:2]
        K = Intrinsics(w, h, *args.intrinsics)
    seq = load_tum(args.folder, max_frames=args.max_frames, intrinsics=K, depth_scale=args.depth_scale)
    s = MapJobSettings.model_validate({"frontend": {"depth_noise": args.depth_noise}})
    r = run_visual(seq, s, every=args.every)
    print(
        f"{args.folder.name}: {r['frames']} frames, {r['keyframes']} key frames, lost {r['lost']}, "
        f"loops {r['loops']}: ATE {r['ate_m']:.4f} m (smoother alone {r['ate_smoother_m']:.4f} m)"
    )
    if args.json:
        args.json.write_text(json.dumps(r, indent=2))


if __name__ == "__main__":
    main()
