"""Benchmark of soft tactile seam tracking (paper 003 §2.2, §3.3, Fig. 13).

Measures, on this machine:
  1. marker displacement accuracy from rendered in-finger frames (lateral = the servo's δ plane, axial),
     detection success and throughput (frames/s) of detection + IPPE pose;
  2. refined-path error against the true seam for a planned path with a 2 mm vision error (+ drift,
     wobble, noise), straight and curved seams, both sides of the wall, through the full rendered loop;
     a seed sweep without rendering; an SRM calibration error case;
  3. the end of the seam: our hold-and-stop vs the paper's reset of δ_d (sign flips, jerk, overshoot);
and writes plots like Fig. 13 (paths of SRM tip, torch, robot) plus the deformation over time.

Run:  .venv/bin/python benchmarks/tactile_tracking.py [--out DIR] [--quick]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.plugins.tactile.marker import CameraIntrinsics, MarkerDisplacementEstimator, MarkerReading
from weldcell.plugins.tactile.paths import Polyline, curved_seam, planned_path_with_error, straight_seam
from weldcell.plugins.tactile.render import InFingerCamera
from weldcell.plugins.tactile.servo import ServoSettings
from weldcell.plugins.tactile.simulate import TrackingResult, track_seam


def marker_accuracy(n: int, distorted: bool, seed: int = 0) -> dict[str, float]:
    intr = CameraIntrinsics.default_in_finger()
    if distorted:
        intr = CameraIntrinsics(intr.K, np.array([0.12, -0.4, 0.0, 0.0, 0.3]), 640, 480)
    cam = InFingerCamera(intrinsics=intr, seed=seed)
    est = MarkerDisplacementEstimator(cam.intrinsics, cam.marker_size, filter="none")
    est.capture_rest([cam.render(cam.T_cam_tag_rest) for _ in range(5)])
    rng = np.random.default_rng(seed)
    frames, truths = [], []
    for _ in range(n):
        move = np.array([*rng.uniform(-0.004, 0.004, 2), rng.uniform(-0.001, 0.001)])
        T = cam.T_cam_tag_rest.copy()
        T[:3, 3] += move
        T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix() @ T[:3, :3]
        frames.append(cam.render(T))
        truths.append(move)
    t0 = time.perf_counter()
    res = [est.update(f, i / 50) for i, f in enumerate(frames)]
    dt = time.perf_counter() - t0
    ok = [(r, m) for r, m in zip(res, truths, strict=True) if isinstance(r, MarkerReading)]
    lat = np.array([r.raw[:2] - m[:2] for r, m in ok]) * 1e3
    ax = np.array([r.raw[2] - m[2] for r, m in ok]) * 1e3
    t1 = time.perf_counter()
    for _ in range(min(n, 100)):
        cam.render(cam.T_cam_tag_rest)
    render_fps = min(n, 100) / (time.perf_counter() - t1)
    return {
        "frames": n,
        "detected_fraction": len(ok) / n,
        "lateral_rms_mm": float(np.sqrt(np.mean(lat**2))),
        "lateral_max_mm": float(np.abs(lat).max()),
        "axial_rms_mm": float(np.sqrt(np.mean(ax**2))),
        "axial_max_mm": float(np.abs(ax).max()),
        "detect_pose_fps": n / dt,
        "render_fps": render_fps,
    }


def end_stats(r: TrackingResult, seam: np.ndarray) -> dict[str, float]:
    i0 = int(np.where(r.contact_true)[0][-1]) - 25
    line = Polyline(seam)
    t_end = np.concatenate([line.vertex_tangent[-1], [0.0]])
    n_wall = np.array([-t_end[1], t_end[0], 0.0])  # wall on the left
    v = r.twist[i0:, :3]
    vn = v @ n_wall
    big = vn[np.abs(vn) > 2e-4]
    flips = int(np.sum(np.diff(np.sign(big)) != 0)) if len(big) > 1 else 0
    jerk = float(np.abs(np.diff(r.twist[i0:, :2], n=2, axis=0)).max()) * 50**3
    over = float((r.robot[-1, :2] - seam[-1, :2]) @ t_end[:2]) * 1e3
    return {
        "normal_velocity_sign_flips": flips,
        "max_jerk_m_s3": jerk,
        "overshoot_past_seam_end_mm": over,
        "stop_reason": r.stop_reason,
    }


def plot_paths(r: TrackingResult, title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 6))
    mm = 1e3
    ax.plot(r.true_seam[:, 0] * mm, r.true_seam[:, 1] * mm, "k-", lw=3, alpha=0.35, label="true seam (wall)")
    ax.plot(
        r.planned_path[:, 0] * mm, r.planned_path[:, 1] * mm, "--", color="gray", label="planned (3-D vision)"
    )
    ax.plot(r.robot[:, 0] * mm, r.robot[:, 1] * mm, "-", color="tab:blue", lw=1, label="robot P_r")
    ax.plot(
        r.refined_path[:, 0] * mm,
        r.refined_path[:, 1] * mm,
        "-",
        color="tab:orange",
        lw=1.5,
        label="SRM tip P_s (refined)",
    )
    ax.plot(
        r.seam_estimate[:, 0] * mm,
        r.seam_estimate[:, 1] * mm,
        ":",
        color="tab:red",
        lw=1.5,
        label="seam estimate",
    )
    ax.plot(r.torch[:, 0] * mm, r.torch[:, 1] * mm, "-", color="tab:green", lw=1, label="torch P_t")
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    m = r.metrics
    ax.set_title(
        f"{title}\nplan RMS {m['plan_rms_mm']:.2f} mm → refined RMS {m['refined_seam_rms_mm']:.3f} mm"
    )
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def plot_deformation(ours: TrackingResult, paper: TrackingResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=False)
    for ax, r, name in (
        (axs[0], ours, "this implementation (hysteresis + hold-and-stop)"),
        (axs[1], paper, "paper §3.3 behaviour (δ_d reset to 0 on contact loss)"),
    ):
        ax.plot(r.t, r.delta_n * 1e3, label="δ^{n_s} measured")
        ax.plot(r.t, r.delta_t * 1e3, label="δ^{t_s} measured", alpha=0.7)
        ax.plot(r.t, r.delta_n_true * 1e3, "k:", lw=0.8, label="δ^{n_s} true")
        ax.plot(r.t, r.delta_d * 1e3, "r--", lw=0.8, label="δ_d in force")
        ax.set_ylabel("deformation (mm)")
        ax.set_title(name, fontsize=9)
        ax.legend(fontsize=7, ncol=4)
    for r, name in ((ours, "ours"), (paper, "paper")):
        axs[2].plot(r.t, r.twist[:, 0] * 1e3, label=f"v_x (normal to seam), {name}")
    axs[2].set_ylabel("command (mm/s)")
    axs[2].set_xlabel("time (s)")
    axs[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "tactile_results")
    ap.add_argument("--quick", action="store_true", help="fewer frames and seeds")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    out: dict = {
        "command": ".venv/bin/python benchmarks/tactile_tracking.py" + (" --quick" if args.quick else "")
    }

    n = 60 if args.quick else 300
    out["marker"] = {"pinhole": marker_accuracy(n, False), "distorted": marker_accuracy(n, True)}
    print("marker", json.dumps(out["marker"], indent=1))

    seams = {"straight": straight_seam(0.12), "curved": curved_seam()}
    S = ServoSettings()
    out["tracking_rendered"] = {}
    runs: dict[str, TrackingResult] = {}
    for name, seam in seams.items():
        for off in (0.002, -0.002):
            plan = planned_path_with_error(seam, offset=off, drift=0.01, side="right", seed=1)
            t0 = time.perf_counter()
            r = track_seam(seam, plan, settings=S, render=True, rate_hz=50.0, seed=1)
            key = f"{name}, plan {'+' if off > 0 else '-'}2 mm ({'free side' if off > 0 else 'into wall'})"
            out["tracking_rendered"][key] = {
                **{k: round(v, 4) for k, v in r.metrics.items()},
                "stop_reason": r.stop_reason,
                "wall_clock_s": round(time.perf_counter() - t0, 2),
                "loop_fps": round(len(r.t) / (time.perf_counter() - t0), 1),
            }
            runs[key] = r
            print(key, out["tracking_rendered"][key])

    seeds = range(3 if args.quick else 20)
    sweep = {}
    for name, seam in seams.items():
        vals = []
        for s in seeds:
            off = 0.002 if s % 2 == 0 else -0.002
            plan = planned_path_with_error(
                seam, offset=off, drift=0.01 * (1 if s % 3 else -1), side="right", seed=s
            )
            vals.append(track_seam(seam, plan, settings=S, render=False, seed=s).metrics)
        sweep[name] = {
            k: {"mean": float(np.mean([v[k] for v in vals])), "max": float(np.max([v[k] for v in vals]))}
            for k in ("plan_rms_mm", "refined_seam_rms_mm", "refined_tip_rms_mm", "torch_rms_mm")
        }
    out["tracking_seed_sweep_no_render"] = {"seeds": len(seeds), **sweep}
    print("sweep", json.dumps(sweep, indent=1))

    cal = {}
    for err in (0.05, -0.05):
        seam = seams["curved"]
        plan = planned_path_with_error(seam, offset=0.002, drift=0.01, side="right", seed=2)
        cal[f"tag gain error {err:+.0%}"] = round(
            track_seam(seam, plan, render=False, tag_gain_error=err).metrics["refined_seam_rms_mm"], 4
        )
    out["srm_calibration_error"] = cal
    print("calibration", cal)

    seam = straight_seam(0.06)
    plan = planned_path_with_error(seam, offset=0.002, drift=0.01, side="right", end_error=0.01, seed=3)
    ours = track_seam(seam, plan, settings=ServoSettings(), render=True, seed=3)
    paper = track_seam(seam, plan, settings=ServoSettings(end_mode="paper"), render=True, seed=3)
    out["end_of_seam"] = {"ours": end_stats(ours, seam), "paper_reset_delta_d": end_stats(paper, seam)}
    print("end", out["end_of_seam"])

    keys = list(runs)
    plot_paths(runs[keys[0]], "(a) straight seam, rendered loop", args.out / "fig13a_paths_straight.png")
    plot_paths(runs[keys[2]], "(b) curved seam, rendered loop", args.out / "fig13b_paths_curved.png")
    plot_deformation(ours, paper, args.out / "deformation_over_time.png")
    (args.out / "tactile_tracking.json").write_text(json.dumps(out, indent=1, default=float))
    print("wrote", args.out)


if __name__ == "__main__":
    main()
