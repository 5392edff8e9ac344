"""Cell 4 estimator sweep (paper 004 §II-B): key-frame ATE of the visual-inertial(-GNSS) estimator on
several seeded routes of the simulated site, per configuration, on cached rendered sequences.

    .venv/bin/python benchmarks/mapping_sweep.py --seeds 0 1 2 --length 60 --configs full no-gnss
    .venv/bin/python benchmarks/mapping_sweep.py --list            # the configurations

It drives the estimator directly (no map, detector or report: those are ``mapping_ate.py``), with the
same sensors, mounts and models as profiles/cell4-map-sim.toml: ZED 2i colour + depth (decimated),
BMI088-class IMU at 200 Hz with turn-on biases, u-blox M8T GNSS (standalone or RTK). Rendered frames
are cached in ``--cache`` so that configurations are compared on the same images. Diagnostic
configurations switch one error source off (``no-depth-noise``: noise-free depth) or one part of the
estimator (``no-loop``, ``no-gnss``, ``imu-inflate-1``) to show where the error comes from.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

T_BASE_CAM_RPY = (np.radians([-95.0, 0.0, -90.0]), [0.3, 0.0, 1.0])
T_BASE_IMU_XYZ = [0.0, 0.0, 0.5]
T_BASE_ANT_XYZ = [0.0, 0.0, 1.5]

CONFIGS: dict[str, dict] = {
    "full": {},
    "no-gnss": {"estimator": {"use_gnss": False}},
    "rtk": {"gnss": "rtk", "estimator": {"gnss_correlation_time": 1.0}},
    "no-imu": {"estimator": {"use_imu": False}},
    "no-loop": {"estimator": {"loop_closure": False}},
    "no-loop-no-gnss": {"estimator": {"loop_closure": False, "use_gnss": False}},
    "imu-inflate-1": {"imu_noise": {"inflate": 1.0}},
    "links-1": {"estimator": {"links": 1, "use_gnss": False}},
    "no-depth-noise": {"depth_noise": False},
    "head-on-depth": {"frontend": {"incidence_noise": False}},  # and no plane fit
    "no-depth-fit": {"frontend": {"depth_fit": False}},
    "no-pnp-floor": {"estimator": {"pnp_sigma_t": 1e-4, "pnp_sigma_r": 1e-5}},
    # the estimator before the key-frame depth model: head-on depth sigma, the measured depth
    "before": {"frontend": {"incidence_noise": False}},
}


@dataclass
class Sequence:
    seed: int
    t: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    T_world_cam: np.ndarray
    K: object
    imu: tuple
    imu_bias: tuple
    gnss: list
    T_imu_cam: np.ndarray
    T_imu_ant: np.ndarray
    depth_noise: float
    """The camera's stereo noise coefficient sigma_z / z² [1/m] (the estimator's ``frontend.depth_noise``)."""


def _mounts():
    from weldcell.sdk.geometry import T_from_rpy

    T_base_cam = T_from_rpy(*T_BASE_CAM_RPY)
    T_base_imu = T_from_rpy([0.0, 0.0, 0.0], T_BASE_IMU_XYZ)
    T_base_ant = T_from_rpy([0.0, 0.0, 0.0], T_BASE_ANT_XYZ)
    return T_base_cam, T_base_imu, T_base_ant


def camera_preset(resolution: str | None):
    """The ZED 2i preset at a real video mode (``--resolution``: HD, VGA...) or its native HD720."""
    from weldcell.hal.sim.camera_model import get_preset, zed_mode

    return zed_mode(resolution) if resolution else get_preset("zed2i")


def make_sequence(
    seed: int,
    length: float,
    decimation: int,
    fps: float,
    gnss_mode: str,
    depth_noise: bool,
    cache: Path,
    resolution: str | None = None,
    frames: int | None = None,
) -> Sequence:
    """Render (or load from ``cache``) one route of the site and sample its IMU and GNSS."""
    from weldcell.hal.readings import Intrinsics
    from weldcell.hal.sim.gnss_model import GnssModel, GnssSimulator
    from weldcell.hal.sim.inertial import ImuModel, ImuSimulator
    from weldcell.hal.sim.rgbd import RgbdCamera
    from weldcell.hal.sim.site import RouteSettings, install_site
    from weldcell.hal.sim.world import SimWorld

    site = install_site(SimWorld([]), seed=seed)
    site.set_route(RouteSettings(length=length, seed=seed))
    route = site.route
    T_base_cam, T_base_imu, T_base_ant = _mounts()

    def kin(t):
        R, v, a, w = route.kinematics(t)
        return R, v, a, w, route.pos(np.clip(t, 0.0, route.duration))

    imu = ImuSimulator(
        ImuModel(gyro_turn_on_bias=0.005, accel_turn_on_bias=0.05),
        kin,
        T_base_imu,
        seed + 4,
        site.distance_to_steel,
    )
    ti, acc, gyr, _, truth = imu.samples_until(route.duration)

    def ant(t):
        return (route.pose(t) @ T_base_ant)[:3, 3]

    gsim = GnssSimulator(GnssModel(mode=gnss_mode), ant, site.under_roof, site.distance_to_steel, seed + 5)
    gnss = [g for g in gsim.samples_until(route.duration) if g["enu"] is not None]
    t = np.arange(0.0, route.duration, 1.0 / fps)[:frames]
    Tc = np.array([route.pose(x) @ T_base_cam for x in t])
    preset = camera_preset(resolution)
    mode = f"_{resolution.upper()}" if resolution else ""
    part = f"_first{frames}" if frames else ""
    f = cache / f"seq_s{seed}_L{length:g}_d{decimation}{mode}_f{fps:g}_n{int(depth_noise)}{part}_v2.npz"
    if f.is_file():
        z = np.load(f)
        rgb, depth = z["rgb"], z["depth"]
        K = Intrinsics(*[int(v) for v in z["K"][:2]], *[float(v) for v in z["K"][2:]])
    else:
        cam = RgbdCamera(preset, site.world.meshes(), decimation=decimation, noise=depth_noise)
        rgb, depth = _render(cam, Tc, seed, f)
        K = cam.intrinsics
    T_imu_cam = np.linalg.inv(T_base_imu) @ T_base_cam
    T_imu_ant = np.linalg.inv(T_base_imu) @ T_base_ant
    return Sequence(
        seed,
        t,
        rgb,
        depth,
        Tc,
        K,
        (ti, acc, gyr),
        (truth["b_g"], truth["b_a"]),
        gnss,
        T_imu_cam,
        T_imu_ant,
        preset.sigma2,
    )


def _render(cam, Tc: np.ndarray, seed: int, f: Path) -> tuple[np.ndarray, np.ndarray]:
    """Colour and depth of every camera pose, saved to ``f`` (via a part file renamed when complete, so an
    interrupted run leaves no cache behind)."""
    rng = np.random.default_rng(seed + 1)
    rgbs, depths = [], []
    for T in Tc:
        d, c = cam.render_rgbd(T, rng=rng)
        rgbs.append(c)
        depths.append(d.depth.astype(np.float32))
    rgb, depth = np.array(rgbs), np.array(depths)
    K = cam.intrinsics
    f.parent.mkdir(parents=True, exist_ok=True)
    part_file = f.with_suffix(".part.npz")
    np.savez(part_file, rgb=rgb, depth=depth, K=np.array([K.width, K.height, K.fx, K.fy, K.cx, K.cy]))
    part_file.replace(f)
    return rgb, depth


STAGES = {
    "_predict": "IMU prediction (preintegration)",
    "extract": "ORB extraction",
    "add_depth_sigmas": "key-frame depth model (incidence, plane fit)",
    "_track": "tracking PnP (by projection)",
    "fill_missing_depth": "eq. 4 triangulation",
    "_visual_factors": "key-frame PnP links + covariance",
    "_update": "iSAM2 update",
    "_close_loops": "loop check",
}


def instrument(est) -> dict[str, list[tuple[float, float]]]:
    """Time the estimator's stages (CPU of the whole process, all threads, and wall) per call: the
    benchmark wraps the methods, the estimator is unchanged. Returns {stage: [(cpu s, wall s), ...]}."""
    from weldcell.plugins.mapping import estimator as module

    spent: dict[str, list[tuple[float, float]]] = {v: [] for v in STAGES.values()}

    def timed(fn, name):
        def wrapper(*a, **kw):
            c0, w0 = time.process_time(), time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                spent[name].append((time.process_time() - c0, time.perf_counter() - w0))

        return wrapper

    for attr, name in STAGES.items():
        if attr in ("extract", "add_depth_sigmas"):  # the front end's methods
            setattr(est.fe, attr, timed(getattr(est.fe, attr), name))
        elif attr == "fill_missing_depth":
            module.fill_missing_depth = timed(module.fill_missing_depth, name)
        else:
            setattr(est, attr, timed(getattr(est, attr), name))
    return spent


def run(seq: Sequence, cfg: dict, stages: bool = False, dump: Path | None = None) -> dict:
    """The estimator over ``seq`` with the configuration's settings; ATE of the key frames."""
    from weldcell.plugins.mapping.estimator import VioEstimator
    from weldcell.plugins.mapping.frontend import OrbFrontEnd
    from weldcell.plugins.mapping.interp import ate_rmse
    from weldcell.plugins.mapping.settings import MapJobSettings

    given = {k: cfg[k] for k in ("estimator", "frontend", "imu_noise") if k in cfg}
    # the stereo noise of the camera that rendered the sequence, not assumed
    given["frontend"] = {"depth_noise": seq.depth_noise} | given.get("frontend", {})
    s = MapJobSettings.model_validate(given)
    est = VioEstimator(s.estimator, OrbFrontEnd(s.frontend), seq.T_imu_cam, s.imu_noise, seq.T_imu_ant)
    spent = instrument(est) if stages else {}
    ti, acc, gyr = seq.imu
    gi = 0
    truth = {}
    cpu_kf, cpu_fr = [], []
    t0 = time.perf_counter()
    for n, t in enumerate(seq.t):
        m = ti <= t + 1e-9
        est.add_imu(ti[m], acc[m], gyr[m])
        while gi < len(seq.gnss) and seq.gnss[gi]["t"] <= t + 1e-9:
            g = seq.gnss[gi]
            est.add_gnss(g["t"], g["enu"], np.array([g["sigma_h"], g["sigma_h"], g["sigma_v"]]))
            gi += 1
        c0 = time.process_time()
        res = est.process_frame(float(t), seq.rgb[n], seq.depth[n], seq.K, seq.T_world_cam[n])
        (cpu_kf if res.keyframe is not None else cpu_fr).append(time.process_time() - c0)
        if res.keyframe is not None:
            truth[res.keyframe.index] = seq.T_world_cam[n]
    wall = time.perf_counter() - t0
    Tr = np.array([truth[k.index] for k in est.keyframes])
    T_smoother = est.keyframe_trajectory()[1]
    ate_smoother = ate_rmse(T_smoother[:, :3, 3], Tr[:, :3, 3])[0]
    if hasattr(est, "finalize"):
        est.finalize()
    tk, Tk = est.keyframe_trajectory()
    ref = Tr[:, :3, 3]
    ate, _ = ate_rmse(Tk[:, :3, 3], ref)
    if dump is not None:  # the key-frame trajectories, for per-segment analysis (mapping_segments.py)
        dump.parent.mkdir(parents=True, exist_ok=True)
        loops = np.array([(lp.old, lp.new) for lp in est.global_graph.loops], int).reshape(-1, 2)
        np.savez(dump, t=tk, T_est=Tk, T_smoother=T_smoother, T_true=Tr, loops=loops)
    tm = {k: (1000 * float(np.mean(v)), 1000 * float(np.std(v))) for k, v in est.timing.items() if v}
    return {
        "ate_m": ate,
        "ate_smoother_m": ate_smoother,
        "keyframes": len(est.keyframes),
        "lost": sum(e["kind"] == "lost" for e in est.events),
        "loops": sum(e["kind"] == "loop" for e in est.events),
        "timing_ms": tm,
        "wall_s": wall,
        "cpu_ms": {  # process time (all threads): independent of other jobs' load, unlike wall time
            "tracking_frame": (1000 * float(np.mean(cpu_fr)), 1000 * float(np.std(cpu_fr))),
            "keyframe": (1000 * float(np.mean(cpu_kf)), 1000 * float(np.std(cpu_kf))),
            "all": 1000 * float(np.mean(cpu_fr + cpu_kf)),
        },
        "bias_g_err": float(np.abs(est.keyframes[-1].bias[3:] - seq.imu_bias[0][-1]).max()),
        "stages_ms": {  # per call: CPU mean, wall mean, CPU std, wall std, calls
            k: (*(1000 * np.mean(v, axis=0)), *(1000 * np.std(v, axis=0)), len(v))
            for k, v in spent.items()
            if v
        },
        "frames": len(seq.t),
        "cpu_frames_ms": 1000 * np.array(cpu_fr + cpu_kf),
    }


def frontend_components(decimation: int) -> None:
    """CPU time of ORB extraction and PnP (by projection / brute force) on rendered frames of the route
    at ``decimation`` (1 = the ZED 2i's 1280x720), without rendering a whole sequence."""
    from weldcell.hal.sim.rgbd import RgbdCamera
    from weldcell.hal.sim.site import RouteSettings, install_site
    from weldcell.hal.sim.world import SimWorld
    from weldcell.plugins.mapping.frontend import OrbFrontEnd
    from weldcell.plugins.mapping.settings import MapJobSettings

    site = install_site(SimWorld([]), seed=0)
    site.set_route(RouteSettings(length=60.0))
    T_base_cam = _mounts()[0]
    cam = RgbdCamera("zed2i", site.world.meshes(), decimation=decimation)
    fe = OrbFrontEnd(MapJobSettings().frontend)
    frames = []
    for t in (30.0, 30.4, 30.8):
        T = site.route.pose(t) @ T_base_cam
        d, c = cam.render_rgbd(T, rng=1)
        frames.append((T, d.depth, c))
    K = cam.intrinsics
    ex, gm, bm = [], [], []
    for _ in range(3):
        c0 = time.process_time()
        f = [fe.extract(c, d, K) for _, d, c in frames]
        ex.append((time.process_time() - c0) / 3)
        c0 = time.process_time()
        r1 = fe.relative_pose(f[0], f[1], K, np.linalg.inv(frames[0][0]) @ frames[1][0])
        gm.append(time.process_time() - c0)
        c0 = time.process_time()
        r2 = fe.relative_pose(f[0], f[2], K)
        bm.append(time.process_time() - c0)
    print(
        f"{K.width}x{K.height}: ORB {1000 * np.median(ex):.0f} ms ({len(f[0].pixels)} features), PnP by "
        f"projection {1000 * np.median(gm):.0f} ms ({r1.inliers} inliers), brute force "
        f"{1000 * np.median(bm):.0f} ms ({r2.inliers} inliers)  [CPU time]"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--length", type=float, default=60.0, help="route length [m]")
    ap.add_argument("--decimation", type=int, default=4, help="camera decimation (1 = 1280x720)")
    ap.add_argument(
        "--resolution",
        choices=["2K", "FHD", "HD", "VGA"],
        help="a real ZED 2i video mode (VGA = 672x376) instead of HD720 decimated; use with --decimation 1",
    )
    ap.add_argument("--fps", type=float, default=5.0)
    ap.add_argument("--frames", type=int, help="only the first N camera frames (time per frame at 720p)")
    ap.add_argument("--configs", nargs="+", default=["full", "no-gnss", "rtk"])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/weldcell-mapping-cache"))
    ap.add_argument("--list", action="store_true")
    ap.add_argument("--components", action="store_true", help="front-end CPU per component, then stop")
    ap.add_argument("--stages", action="store_true", help="CPU and wall time per estimator stage")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--dump", type=Path, help="folder: key-frame trajectories per config and seed (.npz)")
    args = ap.parse_args()
    if args.components:
        frontend_components(args.decimation)
        return
    if args.list:
        for k, v in CONFIGS.items():
            print(f"{k:30s} {v}")
        return
    rows: dict = {}
    for name in args.configs:
        cfg = CONFIGS[name]
        for seed in args.seeds:
            seq = make_sequence(
                seed,
                args.length,
                args.decimation,
                args.fps,
                cfg.get("gnss", "standalone"),
                cfg.get("depth_noise", True),
                args.cache,
                args.resolution,
                args.frames,
            )
            mode = args.resolution or f"d{args.decimation}"
            dump = args.dump / f"{name}_s{seed}_L{args.length:g}_{mode}.npz" if args.dump else None
            r = run(seq, cfg, args.stages, dump)
            rows.setdefault(name, {})[seed] = r
            for k, (cm, wm, cs, ws, n) in r.pop("stages_ms").items():
                print(f"  {k:36s} CPU {cm:6.1f} ± {cs:5.1f} ms   wall {wm:6.1f} ± {ws:5.1f} ms   ({n} calls)")
            fr = r.pop("cpu_frames_ms")
            print(f"  per frame (CPU, all stages): {fr.mean():.1f} ± {fr.std():.1f} ms over {len(fr)} frames")
            tm = "  ".join(f"{k} {m:.0f}±{s:.0f} ms" for k, (m, s) in r["timing_ms"].items())
            c = r["cpu_ms"]
            tm += (
                f"  | CPU: frame {c['tracking_frame'][0]:.0f}±{c['tracking_frame'][1]:.0f} ms, "
                f"key frame {c['keyframe'][0]:.0f}±{c['keyframe'][1]:.0f} ms, mean {c['all']:.0f} ms"
            )
            print(
                f"{name:28s} seed {seed}  ATE {r['ate_m']:.4f} m (smoother alone {r['ate_smoother_m']:.4f})  "
                f"kf {r['keyframes']}  lost {r['lost']}  loops {r['loops']}  bg err {r['bias_g_err']:.1e}  "
                f"{tm}  wall {r['wall_s']:.0f} s",
                flush=True,
            )
        a = [r["ate_m"] for r in rows[name].values()]
        print(f"{name:28s} mean ATE {np.mean(a):.4f} m  max {np.max(a):.4f} m  ({len(a)} seeds)", flush=True)
    if args.json:
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "rows": rows}))


if __name__ == "__main__":
    main()
