"""Cell 4 estimator: are its factors' sigmas right? (docs/methods/mapping.md, "The ×2 on the IMU sigmas")

    .venv/bin/python benchmarks/mapping_consistency.py --imu     # preintegration discretisation error
    .venv/bin/python benchmarks/mapping_consistency.py --pnp     # PnP relative pose: true error vs sigma

``--imu``: a noise-free, bias-free simulated IMU (200 Hz, the profile's mount) on the 100 m route of the
site (seed 0), preintegrated over windows of 0.2 / 0.4 / 1.0 s like the estimator (gtsam, zero-order
hold) and compared with the ground-truth state: what the discretisation alone costs, beside the
preintegration's own sigma from the datasheet densities.
``--pnp``: RANSAC PnP between frames ``--gap`` apart on the sweep's cached sequence (benchmarks/
mapping_sweep.py renders it into ``--cache`` if missing) with an IMU-like prediction (truth + 1 cm /
0.3°), its error against the truth vs the sigma it reports (what the estimator's factor uses).
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


def pnp_consistency(gap: int, cache: Path, decimation: int) -> None:
    from scipy.spatial.transform import Rotation
    from weldcell.plugins.mapping.frontend import OrbFrontEnd
    from weldcell.plugins.mapping.settings import MapJobSettings

    sys.path.insert(0, str(Path(__file__).parent))
    from mapping_sweep import make_sequence

    seq = make_sequence(0, 100.0, decimation, 5.0, "standalone", True, cache)
    s = MapJobSettings()
    fe = OrbFrontEnd(s.frontend)
    rng = np.random.default_rng(0)
    et, er, st, sr = [], [], [], []
    for a in range(20, len(seq.t) - gap, 8):
        b = a + gap
        fa = fe.extract(seq.rgb[a], seq.depth[a], seq.K)
        fb = fe.extract(seq.rgb[b], seq.depth[b], seq.K)
        T_true = np.linalg.inv(seq.T_world_cam[a]) @ seq.T_world_cam[b]
        G = T_true.copy()
        G[:3, 3] += rng.normal(0, 0.01, 3)
        G[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.005, 3)).as_matrix() @ G[:3, :3]
        r = fe.relative_pose(fa, fb, seq.K, G)
        if not r.ok:
            continue
        E = np.linalg.inv(T_true) @ r.T_ref_cur
        et.append(E[:3, 3])
        er.append(Rotation.from_matrix(E[:3, :3]).as_rotvec())
        st.append(max(s.estimator.pnp_sigma_t, r.sigma_t))
        sr.append(max(s.estimator.pnp_sigma_r, r.sigma_r))
    et, er, st, sr = map(np.array, (et, er, st, sr))
    print(
        f"{seq.K.width}x{seq.K.height}, frames {gap} apart, {len(et)} pairs: translation error rms "
        f"{rms(et) * 1e3:.1f} mm vs reported sigma {rms(st) * 1e3:.1f} mm (ratio {rms(et) / rms(st):.2f}); "
        f"rotation {np.degrees(rms(er)):.3f} vs {np.degrees(rms(sr)):.3f} deg (ratio {rms(er) / rms(sr):.2f})"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--imu", action="store_true")
    ap.add_argument("--pnp", action="store_true")
    ap.add_argument("--gap", type=int, default=3, help="frames between the PnP pair (5 fps)")
    ap.add_argument("--decimation", type=int, default=4)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/weldcell-mapping-cache"))
    args = ap.parse_args()
    if args.imu or not args.pnp:
        imu_discretisation()
    if args.pnp or not args.imu:
        pnp_consistency(args.gap, args.cache, args.decimation)


if __name__ == "__main__":
    main()
