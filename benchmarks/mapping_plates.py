"""What limits the weld plates' AE (issue 11): re-measure each plate of a finished ``map`` run from its
key-frame store, with the estimated and with the true key-frame poses, and show per plate the views
(how many, how far, how steep), the error of each of the plate's four edges and the AE: the box fitted
to the depth images (plate.py's measurement, plate_fit.py) and, with ``--points``, the points' interval
measurement it starts from (the measurement before the box fit).

The pixels are those of the key frames that saw the plate's region, within the box the job took them
from (``pixels_box`` in regions.json; a run without it: the region's points' oriented box + 0.15 m,
close to the job's 2-98 % extent + 0.15 m); with ``--truth-crop`` within 0.55 m (horizontally) and
0.25 m (vertically) of the plate's true centre instead (the truth then only chooses which pixels are
handed over; the measurement never sees it).

    .venv/bin/python benchmarks/mapping_ate.py --resolution VGA --decimation 1 --keep /tmp/ate   # a run
    .venv/bin/python benchmarks/mapping_plates.py /tmp/ate/runs/<run> --seed 0 --depth-noise 2.98e-3

The run's map folder holds every key frame's depth image and pose; ``regions.json`` which key frames
saw each region; ``truth_keyframes.tum`` the true camera poses; the site (its plates' true corners)
is rebuilt from the seed.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def _tum(path: Path) -> dict[float, np.ndarray]:
    from scipy.spatial.transform import Rotation

    out = {}
    for line in path.read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        v = [float(x) for x in line.split()]
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(v[4:8]).as_matrix()
        T[:3, 3] = v[1:4]
        out[round(v[0], 6)] = T
    return out


def plate_views(T_cams: list[np.ndarray], plate) -> dict:
    """Distance, elevation above the plate's top (deg) and the side of the plate each view looks from."""
    c = plate.center
    R = plate.corners
    ax = (R[1] - R[0])[:2] / np.linalg.norm((R[1] - R[0])[:2])
    ay = np.array([-ax[1], ax[0]])
    d, el, sides = [], [], []
    for T in T_cams:
        v = T[:3, 3] - c
        d.append(np.linalg.norm(v[:2]))
        el.append(np.degrees(np.arctan2(v[2], np.linalg.norm(v[:2]))))
        sides.append((float(v[:2] @ ax), float(v[:2] @ ay)))
    return {
        "n": len(T_cams),
        "dist": np.array(d),
        "elev": np.array(el),
        "sides": np.array(sides),
        "axes": (ax, ay),
    }


def edge_errors(corners: np.ndarray, plate, axes) -> np.ndarray:
    """Signed error (m) of the measured plate's four edges along the true plate axes (+x, -x, +y, -y):
    positive = the measured edge lies outside the true one."""
    ax, ay = axes
    c = plate.center[:2]
    out = []
    for a in (ax, ay):
        t = (plate.corners[:, :2] - c) @ a
        m = (corners[:, :2] - c) @ a
        out += [m.max() - t.max(), t.min() - m.min()]
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--depth-noise", type=float, default=1.488e-3, help="the estimator's sigma_z / z² [1/m]")
    ap.add_argument("--rectangle", action="store_true", help="the points' rectangle (regions.plate_corners)")
    ap.add_argument("--points", action="store_true", help="the points' interval fit (the box fit's start)")
    ap.add_argument("--plates", type=int, nargs="*", help="only these plates (indices)")
    ap.add_argument(
        "--truth-crop",
        action="store_true",
        help="pixels within 0.55 m / 0.25 m of the true plate centre (default: the region's box + 0.15 m, "
        "as the job)",
    )
    ap.add_argument("--max-distance", type=float, help="only key frames this close to the plate [m]")
    ap.add_argument(
        "--no-pose-correction", action="store_true", help="the box fit without the per-pass pose correction"
    )
    ap.add_argument(
        "--pose-sigma",
        type=float,
        nargs=3,
        metavar=("MRAD_RP", "MRAD_YAW", "MM"),
        help="for a store without key-frame covariances: an assumed pose sigma per key frame instead (roll "
        "and pitch, yaw in mrad, translation in mm; stated in the output; not the estimator's)",
    )
    args = ap.parse_args()
    from weldcell.hal.sim.site import install_site
    from weldcell.hal.sim.world import SimWorld
    from weldcell.plugins.mapping.interp import ate_rmse
    from weldcell.plugins.mapping.mapstore import KeyFrameStore
    from weldcell.plugins.mapping.plate import frame_observations, merge, plate_corners_points, plate_fit
    from weldcell.plugins.mapping.plate_poses import camera_pose_cov
    from weldcell.plugins.mapping.regions import corner_distance_error, plate_corners

    site = install_site(SimWorld([]), seed=args.seed)
    store = KeyFrameStore.load(args.run / "map")
    truth = _tum(args.run / "truth_keyframes.tum")
    recs = {r.index: r for r in store.records if round(r.t, 6) in truth}
    est = np.array([recs[i].T_world_cam[:3, 3] for i in sorted(recs)])
    ref = np.array([truth[round(recs[i].t, 6)][:3, 3] for i in sorted(recs)])
    ate, A = ate_rmse(est, ref)
    print(f"{len(recs)} key frames, ATE {ate:.4f} m")
    have_cov = sum(r.covariance is not None for r in recs.values())
    sub = None
    if args.pose_sigma and have_cov < len(recs):
        rp, yaw, tr = np.asarray(args.pose_sigma) * 1e-3
        sub = np.diag([rp**2, rp**2, yaw**2] + [tr**2] * 3)  # body frame: z is near the vertical
        print(f"key frames without covariance: {len(recs) - have_cov}; ASSUMED pose sigma {args.pose_sigma}")
    else:
        print(f"key frames with the estimator's pose covariance: {have_cov} of {len(recs)}")
    regions = json.loads((args.run / "regions.json").read_text())["regions"]
    K = store.intrinsics
    rows = []
    for j, plate in enumerate(site.layout.plates):
        if args.plates and j not in args.plates:
            continue
        best = None
        for r in regions:
            if r["decision"] == "rejected":
                continue
            c = A[:3, :3] @ np.asarray(r["center"]) + A[:3, 3]
            e = np.linalg.norm(c - plate.center)
            if e < 0.8 and (best is None or e < best[1]):
                best = (r, e)
        if best is None:
            print(f"{plate.name}: not found")
            continue
        r = best[0]
        views = [i for i in dict.fromkeys(r["observations"]) if i in recs]
        if args.max_distance:
            views = [
                i
                for i in views
                if np.linalg.norm(truth[round(recs[i].t, 6)][:2, 3] - plate.center[:2]) <= args.max_distance
            ]
        out = {}
        for which in ("estimated", "true"):
            obs = []
            # the estimated poses in the map's own frame with the job's crop there (corners mapped to the
            # truth frame by A afterwards: AE does not depend on it, the edges' errors do); the true poses
            # in the truth frame with the crop's corners mapped there
            M = np.eye(4) if which == "estimated" else A
            if not args.truth_crop and "pixels_box" in r:  # the job's own crop (runs since issue 11)
                lo, hi = (np.asarray(b, float) for b in r["pixels_box"])
                V = np.array(np.meshgrid(*zip(lo, hi, strict=True))).reshape(3, -1).T
            elif not args.truth_crop:  # older runs: the region's points' oriented box + 0.15 m
                ob = r["oriented_box"]
                Rb, e = np.asarray(ob["R"]), np.asarray(ob["extent"]) / 2
                V = (
                    np.asarray(ob["center"])
                    + (np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T * e) @ Rb.T
                )
            else:
                lo, hi = plate.center - [0.55, 0.55, 0.25], plate.center + [0.55, 0.55, 0.25]
                V = np.array(np.meshgrid(*zip(lo, hi, strict=True))).reshape(3, -1).T
                V = (V - A[:3, 3]) @ A[:3, :3]  # the truth frame -> the map's (M maps back for the truth)
            V = V @ M[:3, :3].T + M[:3, 3]
            margin = 0.15 if not args.truth_crop and "pixels_box" not in r else 0.0
            lo, hi = V.min(0) - margin, V.max(0) + margin
            for i in views:
                T = recs[i].T_world_cam if which == "estimated" else truth[round(recs[i].t, 6)]
                cov = recs[i].covariance if recs[i].covariance is not None else sub
                pc = None
                if which == "estimated" and cov is not None and not args.no_pose_correction:
                    pc = camera_pose_cov(recs[i].T_world_imu, cov, T)
                depth = store.read(recs[i])["depth"]
                obs.append(frame_observations(depth, K, T, lo, hi, args.depth_noise, i, pc))
            merged = merge(obs)
            note = ""
            if args.rectangle:
                corners = plate_corners(merged.points)
            elif args.points:
                corners = plate_corners_points(merged)
            else:
                t0 = time.process_time()
                fit = plate_fit(merged)
                corners = fit.corners if fit is not None and fit.ok else None
                note = "" if fit is None else f"{fit.reason} {fit.labels}"
                print(f"{plate.name} ({which} poses): box fit {time.process_time() - t0:.1f} s CPU {note}")
                if fit is not None:
                    sd = np.sqrt(np.abs(np.diag(fit.cov)))[3:5] * 1000
                    L, W = fit.params[3:5]
                    print(f"  length {L:.4f} m ± {sd[0]:.1f} mm, width {W:.4f} m ± {sd[1]:.1f} mm")
                    for ps in fit.passes:
                        kf = ps["keyframes"]
                        xi = np.asarray(ps["xi"])
                        print(
                            f"  pass {kf[0]}-{kf[-1]} ({len(kf)}): rot {np.round(xi[:3] * 1000, 1)} mrad, "
                            f"t {np.round(xi[3:] * 1000, 1)} mm, d2 {ps['d2']:.1f}"
                        )
            if corners is None:
                print(f"{plate.name} ({which} poses): not measured {note}")
                out[which] = None
                continue
            if which == "estimated":
                corners = corners @ A[:3, :3].T + A[:3, 3]
            out[which] = (corner_distance_error(corners, plate.corners), corners)
        Tv = [truth[round(recs[i].t, 6)] for i in views]
        pv = plate_views(Tv, plate)
        rows.append((plate.name, pv, out))
        ae_e = out["estimated"][0] * 1000 if out["estimated"] else np.nan
        ae_t = out["true"][0] * 1000 if out["true"] else np.nan
        nan4 = np.full(4, np.nan)
        ee = edge_errors(out["estimated"][1], plate, pv["axes"]) * 1000 if out["estimated"] else nan4
        et = edge_errors(out["true"][1], plate, pv["axes"]) * 1000 if out["true"] else nan4
        s = pv["sides"]
        print(
            f"{plate.name}: {pv['n']} views, {pv['dist'].min():.1f}-{pv['dist'].max():.1f} m, elevation "
            f"{pv['elev'].min():.1f}-{pv['elev'].max():.1f} deg, views from +x {np.sum(s[:, 0] > 0.3)} "
            f"-x {np.sum(s[:, 0] < -0.3)} +y {np.sum(s[:, 1] > 0.2)} -y {np.sum(s[:, 1] < -0.2)}; AE "
            f"{ae_e:.1f} mm (true poses {ae_t:.1f}); edges +x {ee[0]:+.0f} -x {ee[1]:+.0f} +y {ee[2]:+.0f} "
            f"-y {ee[3]:+.0f} mm (true poses {et[0]:+.0f} {et[1]:+.0f} {et[2]:+.0f} {et[3]:+.0f})",
            flush=True,
        )
    for which in ("estimated", "true"):
        ae = [o[which][0] for _, _, o in rows if o.get(which)]
        print(f"mean AE ({which} poses) {1000 * np.mean(ae):.1f} mm over {len(ae)} plates")


if __name__ == "__main__":
    main()
