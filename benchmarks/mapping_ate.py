"""Cell 4 mapping benchmark (paper 004 §III-B, Fig. 4, Table I): trajectory ATE, weld-plate AE and time
per frame per stage on the simulated site, with ablations.

    .venv/bin/python benchmarks/mapping_ate.py                      # full protocol: 100 m, 640x360, 5 fps
    .venv/bin/python benchmarks/mapping_ate.py --length 30 --decimation 4 --ablations
    .venv/bin/python benchmarks/mapping_ate.py --decimation 1 --fps 15   # ZED 2i 720p at 15 fps (slow here)
    .venv/bin/python benchmarks/mapping_ate.py --resolution VGA --decimation 1  # ZED 2i VGA mode, 672x376
    .venv/bin/python benchmarks/mapping_sweep.py ...   # the estimator alone on several seeds (faster)

Runs the ``map`` job (profiles/cell4-map-sim.toml with the route/camera/GNSS overridden) and prints a
table; ``--json FILE`` writes the numbers. ATE: RMSE of key-frame camera positions after SE(3)
Umeyama alignment (our code); if the GPL ``evo`` package happens to be installed it is used to
cross-check on the TUM files (it is never a dependency). AE: the paper's measure on fixed-size steel
plates — mean |d_est - d_true| over the 6 corner-to-corner distances of each detected plate.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "profiles" / "cell4-map-sim.toml"
PAPER = {
    "ate_lab_m": 0.138,
    "ate_outdoor_m": 0.341,
    "ae_lab_mm": 80,
    "ae_outdoor_mm": 208,
    "time_ms": {"ORB-SLAM3": "158.2±45.7", "VINS-RGBD": "56.0±28.5", "paper (AGX)": "162.4±19.1"},
}


def run_config(name: str, args, estimator: dict, gnss_mode: str | None, tmp: Path) -> dict:
    from weldcell.hal.sim.camera_model import get_preset, zed_mode
    from weldcell.sdk.jobs import run_job
    from weldcell.sdk.plugins import PluginManager

    est = ", ".join(f"{k} = {json.dumps(v)}" for k, v in estimator.items())
    preset = zed_mode(args.resolution) if args.resolution else get_preset("zed2i")
    text = [
        f'extends = "{PROFILE}"',
        "[job.settings]",
        f"route = {{ length = {args.length}, cruise_speed = {args.speed} }}",
        "revisit = { enabled = false }",  # the first visit only: the second is benchmarks/relocalize.py
        f"estimator = {{ {est} }}" if est else "",
        # the estimator's stereo noise is the camera's (sigma_z / z², doubles at VGA), not assumed
        f"frontend = {{ depth_noise = {preset.sigma2:.6g} }}",
        "[devices.camera]",
        'plugin = "camera.sim"',
        "[devices.camera.settings]",
        f"decimation = {args.decimation}",
        f"fps = {args.fps}",
        f'resolution = "{args.resolution}"' if args.resolution else "",
        f"[cell]\nseed = {args.seed}",
    ]
    if gnss_mode:
        text += ["[devices.gnss.settings]", f'mode = "{gnss_mode}"']
    p = tmp / f"{name}.toml"
    p.write_text("\n".join(text) + "\n")
    pm = PluginManager(discover=True)
    t0 = time.perf_counter()
    run, result = run_job(p, pm, runs_dir=tmp / "runs")
    f = result["figures"]
    f["wall_s"] = time.perf_counter() - t0
    f["run"] = str(run)
    f["evo_ate_m"] = evo_ate(run)
    return f


def evo_ate(run: Path) -> float | None:
    """ATE by evo (GPL-3.0, optional): None when evo is not installed."""
    try:
        from evo.core import metrics, sync
        from evo.tools import file_interface
    except ImportError:
        return None
    est = file_interface.read_tum_trajectory_file(str(run / "trajectory_keyframes.tum"))
    ref = file_interface.read_tum_trajectory_file(str(run / "truth_keyframes.tum"))
    ref, est = sync.associate_trajectories(ref, est)
    est.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    return float(ape.get_statistic(metrics.StatisticsType.rmse))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--length", type=float, default=100.0, help="route length [m]")
    ap.add_argument("--speed", type=float, default=1.2, help="cruise speed [m/s]")
    ap.add_argument("--decimation", type=int, default=2, help="camera decimation (1 = 1280x720)")
    ap.add_argument("--fps", type=float, default=5.0, help="camera frame rate [Hz]")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--resolution",
        choices=["2K", "FHD", "HD", "VGA"],
        help="a real ZED 2i video mode (VGA = 672x376); with --decimation 1",
    )
    ap.add_argument("--keep", type=Path, help="keep the runs here (default: a temporary folder)")
    ap.add_argument("--ablations", action="store_true", help="also without IMU / GNSS / vision, and with RTK")
    ap.add_argument("--json", type=Path, help="write the numbers here")
    args = ap.parse_args()
    configs = [("full (VIO + standalone GNSS)", {}, None)]
    if args.ablations:
        configs += [
            ("without GNSS", {"use_gnss": False}, None),
            ("without IMU", {"use_imu": False}, None),
            ("without vision (IMU + GNSS)", {"use_vision": False}, None),
            ("with RTK GNSS", {"gnss_correlation_time": 1.0}, "rtk"),  # RTK fixed: near-white error
        ]
    rows = {}
    with tempfile.TemporaryDirectory() as d:
        where = args.keep or Path(d)
        where.mkdir(parents=True, exist_ok=True)
        for i, (name, est, gnss) in enumerate(configs):
            try:
                rows[name] = run_config(f"c{i}", args, est, gnss, where)
            except Exception as e:  # noqa: BLE001 - an ablation that fails is a result too
                rows[name] = {"failed": str(e).splitlines()[0]}
                print(f"{name:32s} FAILED: {rows[name]['failed']}", flush=True)
                continue
            print_row(name, rows[name])
    print(
        f"\npaper: ATE {PAPER['ate_lab_m']} m (lab) / {PAPER['ate_outdoor_m']} m (outdoor); "
        f"AE {PAPER['ae_lab_mm']} / {PAPER['ae_outdoor_mm']} mm; time per frame {PAPER['time_ms']}"
    )
    if args.json:
        args.json.write_text(
            json.dumps(
                {"args": vars(args) | {"json": str(args.json)}, "rows": rows, "paper": PAPER},
                indent=2,
                default=str,
            )
        )


def print_row(name: str, f: dict) -> None:
    st = f.get("time_per_stage", {})
    per = ", ".join(f"{k} {v['mean_ms']:.0f}±{v['std_ms']:.0f} ms" for k, v in st.items())
    evo = f"  evo {f['evo_ate_m']:.4f}" if f.get("evo_ate_m") is not None else ""
    print(
        f"{name:32s} ATE {f.get('ate_rmse_m', np.nan):.4f} m "
        f"(frames slerp {f.get('ate_frames_slerp_m', np.nan):.4f}"
        f" / linear {f.get('ate_frames_linear_m', np.nan):.4f}){evo}  AE {f.get('ae_mm', np.nan):.1f} mm "
        f"({f.get('ae_plates', 0)} plates)  kf {f['keyframes']}  lost {f['tracking_lost_events']}  "
        f"frame {1000 * (f.get('frame_seconds_mean') or np.nan):.0f} ms  [{per}]  wall {f['wall_s']:.0f} s",
        flush=True,
    )


if __name__ == "__main__":
    main()
