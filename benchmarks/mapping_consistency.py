"""Cell 4 estimator: are its factors' sigmas right? (docs/methods/mapping.md, "The ×2 on the IMU sigmas")

    .venv/bin/python benchmarks/mapping_consistency.py --imu     # preintegration discretisation error
    .venv/bin/python benchmarks/mapping_consistency.py --pnp     # PnP relative pose: true error vs sigma
    .venv/bin/python benchmarks/mapping_consistency.py --depth --resolution VGA   # feature depth vs sigma
    .venv/bin/python benchmarks/mapping_consistency.py --segments DUMP.npz [DUMP2.npz]  # error per segment

``--imu``: a noise-free, bias-free simulated IMU (200 Hz, the profile's mount) on the 100 m route of the
site (seed 0), preintegrated over windows of 0.2 / 0.4 / 1.0 s like the estimator (gtsam, zero-order
hold) and compared with the ground-truth state: what the discretisation alone costs, beside the
preintegration's own sigma from the datasheet densities.
``--pnp``: RANSAC PnP between frames ``--gap`` apart on the sweep's cached sequence (benchmarks/
mapping_sweep.py renders it into ``--cache`` if missing) with an IMU-like prediction (truth + 1 cm /
0.3°), its error against the truth vs the sigma it reports (what the estimator's factor uses), with the
feature depth sigma grown by the incidence angle (the default) and head-on (``frontend.incidence_noise``
off, the estimator before).
``--depth``: on rendered frames of the route, each ORB feature's depth error (against the noise-free ray
cast) over the depth sigma the front end gives it: head-on ``depth_noise``·z², with the estimated
incidence angle, with the true one.
``--segments``: the key-frame trajectories that ``mapping_sweep.py --dump`` writes, aligned as for the
ATE, cut into 10 m pieces of the route: RMS error, under the roof (no GNSS), turning, key-frame spacing
and loop factors per piece.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def imu_discretisation(length: float = 100.0) -> None:
    import gtsam
    from weldcell.hal.sim.inertial import GRAVITY, ImuModel, ImuSimulator
    from weldcell.hal.sim.site import RouteSettings, install_site
    from weldcell.hal.sim.world import SimWorld
    from weldcell.sdk.geometry import T_from_rpy

    site = install_site(SimWorld([]), seed=0)
    site.set_route(RouteSettings(length=length, seed=0))
    route = site.route
    T_bi = T_from_rpy([0, 0, 0], [0, 0, 0.5])

    def kin(t):
        R, v, a, w = route.kinematics(t)
        return R, v, a, w, route.pos(np.clip(t, 0.0, route.duration))

    zero = ImuModel(
        gyro_noise_density=0.0,
        accel_noise_density=0.0,
        gyro_random_walk=0.0,
        accel_random_walk=0.0,
        gyro_turn_on_bias=0.0,
        accel_turn_on_bias=0.0,
    )
    ti, acc, gyr, _, _ = ImuSimulator(zero, kin, T_bi, 0).samples_until(route.duration)
    dt = ti[1] - ti[0]

    def state(t):
        R, v, _, w = route.kinematics(t)
        p = route.pos(np.atleast_1d(t))
        r = T_bi[:3, 3]
        return gtsam.NavState(
            gtsam.Rot3(R[0] @ T_bi[:3, :3]), gtsam.Point3(*(p[0] + R[0] @ r)), v[0] + R[0] @ np.cross(w[0], r)
        )

    m = ImuModel()
    p = gtsam.PreintegrationCombinedParams.MakeSharedU(GRAVITY)
    p.setGyroscopeCovariance(np.eye(3) * m.gyro_noise_density**2)
    p.setAccelerometerCovariance(np.eye(3) * m.accel_noise_density**2)
    p.setIntegrationCovariance(np.eye(3) * 1e-8)
    p.setBiasOmegaCovariance(np.eye(3) * m.gyro_random_walk**2)
    p.setBiasAccCovariance(np.eye(3) * m.accel_random_walk**2)
    zero_bias = gtsam.imuBias.ConstantBias()
    for gap in (0.2, 0.4, 1.0):
        e, sig = [], []
        for t0 in np.arange(3.0, route.duration - 3, 1.7):
            pim = gtsam.PreintegratedCombinedMeasurements(p, zero_bias)
            i0, n = int(np.searchsorted(ti, t0)), int(round(gap / dt))
            for i in range(i0, i0 + n):
                pim.integrateMeasurement(acc[i], gyr[i], dt)
            s1, pr = state(ti[i0 + n]), pim.predict(state(ti[i0]), zero_bias)
            e.append(
                [
                    np.linalg.norm(gtsam.Rot3.Logmap(s1.attitude().between(pr.attitude()))),
                    np.linalg.norm(pr.position() - s1.position()),
                    np.linalg.norm(pr.velocity() - s1.velocity()),
                ]
            )
            C = pim.preintMeasCov()
            sig.append([np.sqrt(np.trace(C[k : k + 3, k : k + 3])) for k in (0, 3, 6)])
        e, sig = np.array(e), np.array(sig)
        print(
            f"gap {gap:.1f} s ({len(e)} windows): discretisation / noise sigma: rotation "
            f"{rms(e[:, 0]) * 1e3:.2f} / {rms(sig[:, 0]) * 1e3:.2f} mrad, "
            f"position {rms(e[:, 1]) * 1e3:.2f} / {rms(sig[:, 1]) * 1e3:.2f} mm, "
            f"velocity {rms(e[:, 2]) * 1e3:.2f} / {rms(sig[:, 2]) * 1e3:.2f} mm/s"
        )


def pnp_consistency(gap: int, cache: Path, decimation: int, resolution: str | None) -> None:
    from weldcell.plugins.mapping.settings import MapJobSettings

    sys.path.insert(0, str(Path(__file__).parent))
    from mapping_sweep import make_sequence

    seq = make_sequence(0, 100.0, decimation, 5.0, "standalone", True, cache, resolution)
    for incidence in (True, False):
        s = MapJobSettings.model_validate(
            {"frontend": {"depth_noise": seq.depth_noise, "incidence_noise": incidence}}
        )
        _pnp_pairs(seq, s, gap, "incidence" if incidence else "head-on")


def _pnp_pairs(seq, s, gap: int, label: str) -> None:
    from scipy.spatial.transform import Rotation
    from weldcell.plugins.mapping.frontend import OrbFrontEnd

    fe = OrbFrontEnd(s.frontend)
    rng = np.random.default_rng(0)
    et, er, st, sr, scale, mt, mr = [], [], [], [], [], [], []
    for a in range(20, len(seq.t) - gap, 8):
        b = a + gap
        fa = fe.extract(seq.rgb[a], seq.depth[a], seq.K)
        fe.add_depth_sigmas(fa, seq.depth[a], seq.K)  # the reference, as a key frame
        fb = fe.extract(seq.rgb[b], seq.depth[b], seq.K)
        T_true = np.linalg.inv(seq.T_world_cam[a]) @ seq.T_world_cam[b]
        G = T_true.copy()
        G[:3, 3] += rng.normal(0, 0.01, 3)
        G[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.005, 3)).as_matrix() @ G[:3, :3]
        r = fe.relative_pose(fa, fb, seq.K, G)
        if not r.ok:
            continue
        E = np.linalg.inv(T_true) @ r.T_ref_cur
        scale.append((r.T_ref_cur[:3, 3] @ T_true[:3, 3], T_true[:3, 3] @ T_true[:3, 3]))
        et.append(E[:3, 3])
        er.append(Rotation.from_matrix(E[:3, :3]).as_rotvec())
        st.append(max(s.estimator.pnp_sigma_t, r.sigma_t))
        sr.append(max(s.estimator.pnp_sigma_r, r.sigma_r))
        mt.append(r.sigma_t)
        mr.append(r.sigma_r)
    et, er, st, sr, mt, mr = map(np.array, (et, er, st, sr, mt, mr))
    print(
        f"{seq.K.width}x{seq.K.height} ({label} depth sigma), frames {gap} apart, {len(et)} pairs: "
        "translation error rms "
        f"{rms(et) * 1e3:.1f} mm vs reported sigma {rms(st) * 1e3:.1f} mm (ratio {rms(et) / rms(st):.2f}); "
        f"rotation {np.degrees(rms(er)):.3f} vs {np.degrees(rms(sr)):.3f} deg (ratio {rms(er) / rms(sr):.2f})"
    )
    sc = np.sum(scale, axis=0)
    print(
        f"  translation scale (least squares, estimate / truth): {sc[0] / sc[1]:.4f}; sigma of the model "
        f"alone (no floor): translation {rms(mt) * 1e3:.1f} mm (ratio {rms(et) / rms(mt):.2f}), rotation "
        f"{np.degrees(rms(mr)):.3f} deg (ratio {rms(er) / rms(mr):.2f})"
    )


def depth_consistency(resolution: str | None, decimation: int, times=(20.0, 45.0, 70.0)) -> None:
    from weldcell.hal.sim.rgbd import RgbdCamera
    from weldcell.hal.sim.site import RouteSettings, install_site
    from weldcell.hal.sim.world import SimWorld
    from weldcell.plugins.mapping.frontend import MIN_COS, OrbFrontEnd
    from weldcell.plugins.mapping.settings import MapJobSettings

    sys.path.insert(0, str(Path(__file__).parent))
    from mapping_sweep import _mounts, camera_preset

    site = install_site(SimWorld([]), seed=0)
    site.set_route(RouteSettings(length=100.0, seed=0))
    preset = camera_preset(resolution)
    cam = RgbdCamera(preset, site.world.meshes(), decimation=decimation)
    s = MapJobSettings.model_validate({"frontend": {"depth_noise": preset.sigma2}})
    fe = OrbFrontEnd(s.frontend)
    ratios: dict[str, list] = {"head-on": [], "now (incidence, plane fit)": [], "true incidence": []}
    for t in times:
        T = site.route.pose(t) @ _mounts()[0]
        d, c = cam.render_rgbd(T, rng=1)
        _, cos_true, _ = cam.cast(T)
        f = fe.extract(c, d.depth, cam.intrinsics)
        raw = f.points.copy()
        fe.add_depth_sigmas(f, d.depth, cam.intrinsics)
        ok = np.isfinite(f.points[:, 2])
        u, v = (np.round(f.pixels[ok, i]).astype(int) for i in (0, 1))
        z_true = _true_depth(cam, T, raw[ok] / raw[ok, 2:3])  # along each key point's (sub-pixel) ray
        head_on = s.frontend.depth_noise * raw[ok, 2] ** 2
        ratios["head-on"].append((raw[ok, 2] - z_true) / head_on)
        ratios["now (incidence, plane fit)"].append((f.points[ok, 2] - z_true) / f.depth_sigma[ok])
        ratios["true incidence"].append(
            (raw[ok, 2] - z_true) / (head_on / np.maximum(cos_true[v, u], MIN_COS))
        )
    print(
        f"{cam.intrinsics.width}x{cam.intrinsics.height}, feature depth error / sigma, {len(times)} frames:"
    )
    for k, r in ratios.items():
        r = np.concatenate(r)
        r = r[np.isfinite(r)]
        print(
            f"  {k:28s} rms {rms(r):.2f}, median |.| {np.median(np.abs(r)):.2f}, p90 |.| "
            f"{np.percentile(np.abs(r), 90):.2f}  (consistent: 1.00, 0.67, 1.64; {len(r)} features)"
        )


def _true_depth(cam, T: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Noise-free z-depth of the scene along the camera rays (x, y, 1) ``r`` (N, 3) of camera pose T."""
    import open3d as o3d

    rays = np.empty((len(r), 6), np.float32)
    rays[:, :3] = T[:3, 3]
    rays[:, 3:] = r @ T[:3, :3].T  # unit z in the camera: the hit distance is the z-depth
    return cam.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(float)


def segments(dumps: list[Path], piece: float = 10.0) -> None:
    """Per 10 m of the route: RMS of the aligned key-frame error, for each dump side by side."""
    from weldcell.hal.sim.site import install_site
    from weldcell.hal.sim.world import SimWorld
    from weldcell.plugins.mapping.interp import ate_rmse

    site = install_site(SimWorld([]), seed=0)
    data = []
    for f in dumps:
        z = np.load(f)
        ref = z["T_true"][:, :3, 3]
        _, T = ate_rmse(z["T_est"][:, :3, 3], ref)
        err = np.linalg.norm(z["T_est"][:, :3, 3] @ T[:3, :3].T + T[:3, 3] - ref, axis=1)
        _, Ts = ate_rmse(z["T_smoother"][:, :3, 3], ref)
        err_s = np.linalg.norm(z["T_smoother"][:, :3, 3] @ Ts[:3, :3].T + Ts[:3, 3] - ref, axis=1)
        dist = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(ref, axis=0), axis=1))]
        data.append((f.stem, dist, err, err_s))
    z = np.load(dumps[0])
    ref = z["T_true"][:, :3, 3]
    s = data[0][1]
    yaw = np.unwrap(np.arctan2(z["T_true"][:, 1, 0], z["T_true"][:, 0, 0]))
    roof = site.under_roof(ref)
    loops = z["loops"]
    print(
        f"{'piece':>10s} {'kf':>4s} {'roof':>5s} {'turn deg':>8s} {'loops':>5s}  "
        + "  ".join(f"{n[:30]:>30s}" for n, *_ in data)
    )
    for a in np.arange(0.0, s[-1], piece):
        m = (s >= a) & (s < a + piece)
        if not m.any():
            continue
        idx = np.flatnonzero(m)
        nl = int(np.isin(loops[:, 1], idx).sum()) if len(loops) else 0
        turn = np.degrees(abs(yaw[idx[-1]] - yaw[idx[0]]))
        sel = [(d >= a) & (d < a + piece) for _, d, _, _ in data]
        cols = "  ".join(
            f"{rms(e[k]) * 1e3:13.1f} mm ({rms(es[k]) * 1e3:6.1f} sm)"
            for (_, _, e, es), k in zip(data, sel, strict=True)
        )
        print(f"{a:4.0f}-{a + piece:3.0f} m {m.sum():4d} {roof[m].mean():5.2f} {turn:8.0f} {nl:5d}  {cols}")
    print(
        "all: "
        + "  ".join(f"{n}: {rms(e) * 1e3:.1f} mm (smoother {rms(es) * 1e3:.1f})" for n, _, e, es in data)
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--imu", action="store_true")
    ap.add_argument("--pnp", action="store_true")
    ap.add_argument("--gap", type=int, default=3, help="frames between the PnP pair (5 fps)")
    ap.add_argument("--decimation", type=int, default=4)
    ap.add_argument("--depth", action="store_true")
    ap.add_argument("--segments", type=Path, nargs="+", help="mapping_sweep.py --dump files")
    ap.add_argument("--resolution", help="a ZED 2i video mode (VGA, HD) instead of HD720 decimated")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/weldcell-mapping-cache"))
    args = ap.parse_args()
    if args.segments:
        segments(args.segments)
        return
    if args.depth:
        depth_consistency(args.resolution, args.decimation)
        return
    if args.imu or not args.pnp:
        imu_discretisation()
    if args.pnp or not args.imu:
        pnp_consistency(args.gap, args.cache, args.decimation, args.resolution)


if __name__ == "__main__":
    main()
