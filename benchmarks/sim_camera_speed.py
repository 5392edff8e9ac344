"""How fast the simulated depth cameras render, and how fast the workpieces build.

Run:  .venv/bin/python benchmarks/sim_camera_speed.py [--repeats 5]

For every camera preset at full resolution (and the D415 decimated by 2 and 4), it renders a
v-groove butt joint on a floor plate from straight above at a distance inside the camera's range,
with noise (the default: noise, dropouts, stereo shadows) and without (ground truth), and prints
the median wall time per frame, the number of pixels, and the fraction of valid pixels. Then it
times each workpiece builder. Numbers depend on the machine; nothing here is asserted.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import open3d as o3d
from weldcell.hal.sim.camera_model import PRESETS, RaycastCamera
from weldcell.hal.sim.workpieces import WORKPIECES, v_groove_butt
from weldcell.sdk.geometry import make_T


def _timed(fn, repeats: int) -> tuple[float, object]:
    out = fn()  # warm-up (scene build, first-touch allocations)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()

    floor = o3d.geometry.TriangleMesh.create_box(3.0, 3.0, 0.01)
    floor.translate([-1.5, -1.5, -0.01])
    wp = v_groove_butt()
    look_down = np.diag([1.0, -1.0, -1.0])
    print(f"{'camera':<22}{'pixels':>10}{'noise ms':>10}{'truth ms':>10}{'valid':>8}  distance")
    cases = [(name, 1, {}) for name in PRESETS]
    cases[1:1] = [("realsense-d415", 2, {}), ("realsense-d415", 4, {})]
    for name, dec, over in cases:
        cam = RaycastCamera(name, [floor, wp], decimation=dec, **over)
        p = cam.preset
        z = 0.5 * (p.min_range + min(p.max_range, 1.5))
        T = make_T(look_down, [0.0, 0.0, z + wp.params["thickness"]])
        rng = np.random.default_rng(0)
        t_noise, img = _timed(lambda cam=cam, T=T, rng=rng: cam.render(T, rng=rng), args.repeats)
        t_truth, _ = _timed(lambda cam=cam, T=T: cam.render(T, noise=False), args.repeats)
        label = name if dec == 1 else f"{name} /{dec}"
        print(
            f"{label:<22}{p.width * p.height:>10}{t_noise * 1e3:>10.1f}{t_truth * 1e3:>10.1f}"
            f"{img.valid.mean():>8.3f}  {z:.3f} m"
        )

    print(f"\n{'workpiece':<22}{'build ms':>10}{'triangles':>11}{'seam points':>13}")
    for kind, builder in WORKPIECES.items():
        t, w = _timed(builder, max(1, args.repeats // 2))
        n_pts = sum(len(s) for s in w.seams)
        print(f"{kind:<22}{t * 1e3:>10.1f}{len(w.mesh.triangles):>11}{n_pts:>13}")


if __name__ == "__main__":
    main()
