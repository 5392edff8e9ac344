"""The hand-eye methods as stage plugins (kind ``handeye``): settings models and the objects jobs use.

* ``handeye.flange`` (:class:`FlangeHandEye`): paper 003 — flange segmentation and RANSAC circle
  (§2.1.4, §3.2.2), the scaled SVD point fit (eqs. 9-12), the robust variant, and Algorithm 1 with
  the ICP metric (eq. 13), its cost (§3.1 / §4.2) and compensation (eq. 21). Online, Algorithm 1 runs
  one pair at a time through :class:`IncrementalPool`.
* ``handeye.opencv`` (:class:`ClassicalHandEye`): the AX=XB / AX=YB solvers (Tsai, Park, Horaud,
  Andreff, Daniilidis, Shah, Li) on board poses or board photos; online it measures the flange's
  full pose (circle + ISO 9409-1 model ICP) and uses it as the target.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field
from weldcell.plugins.handeye.calibrate import calibrate
from weldcell.plugins.handeye.circle import ransac_circle
from weldcell.plugins.handeye.flange_model import ISO9409_1, FlangeModel, iso9409_model, load_clean_model
from weldcell.plugins.handeye.segmentation import SegmentSettings, segment_flange
from weldcell.plugins.handeye.verification import (
    ConsensusVerifier,
    IcpVerifier,
    compensate,
    radius_cost,
    translation_cost,
)
from weldcell.sdk.errors import DataError, UsageError
from weldcell.sdk.geometry import frame_from_axes, invert
from weldcell.sdk.handeye_files import HandEyeResult, HandEyeSample
from weldcell.sdk.pointfit import rigid_fit_batch
from weldcell.sdk.repeatable import open3d_serial
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import Length

IsoSize = Literal[31.5, 40.0, 50.0, 63.0, 80.0, 100.0]
Vec3 = tuple[Length, Length, Length]


class FlangeSettings(Settings):
    """Flange-based hand-eye calibration (paper 003 §2.1.3-2.1.4, §3, Algorithm 1)."""

    method: Literal["flange", "flange-svd", "flange-iterative"] = Field(
        "flange",
        description="final fit: 'flange' (outlier-proof, eqs. 10-12 on the inliers), 'flange-svd' "
        "(eqs. 9-12 on all samples) or 'flange-iterative' (Algorithm 1's 4-pair pool)",
    )
    feature: Vec3 = Field((0.0, 0.0, 0.0), description="the circle centre in the flange frame (the TCP) [m]")
    flange_d1: IsoSize = Field(50.0, description="ISO 9409-1 pitch circle d1 [mm] (50: UR, Franka, AUBO)")
    flange_model: str | None = Field(
        None,
        description="flange CAD (STL) or cloud (PCD/PLY) for the ICP metric; "
        "default: the ISO 9409-1 plate of flange_d1",
    )
    flange_model_units: Literal["auto", "mm", "m"] = Field(
        "auto", description="units of flange_model ('auto': from its size, a flange is 20-400 mm across)"
    )
    # segmentation (§2.1.4)
    box_min: Vec3 | None = Field(None, description="pass-through box, lower corner, camera frame [m]")
    box_max: Vec3 | None = Field(None, description="pass-through box, upper corner, camera frame [m]")
    voxel: Length = Field(0.001, gt=0, description="voxel of the clustering copy [m]")
    cluster_eps: Length = Field(0.004, gt=0, description="Euclidean cluster distance [m]")
    plane_distance: Length = Field(0.001, gt=0, description="flange face plane inlier distance [m]")
    max_planes: int = Field(
        5, ge=1, le=20, description="planes peeled off to separate the face from the link"
    )
    track_radius: Length | None = Field(
        0.08, gt=0, description="once an estimate exists, keep points this close to the predicted flange [m]"
    )
    # RANSAC circle (§3.2.2)
    radius: Length | None = Field(
        None,
        gt=0,
        description="circle radius R [m]; default d3/2 - 0.5 mm (31 mm for d1 = 50, the paper's value)",
    )
    e_d: Length = Field(0.0003, gt=0, description="circle inlier distance e_d [m]")
    e_r: Length = Field(0.001, gt=0, description="radius tolerance e_r [m]")
    circle_k_max: int = Field(10_000, ge=10, description="RANSAC hypotheses k_max")
    # fit and diagnostics
    inlier_threshold: Length | None = Field(
        None, gt=0, description="fixed inlier residual [m]; default robust"
    )
    n_sigma: float = Field(3.0, gt=0, description="inlier threshold in robust sigmas")
    min_threshold: Length = Field(0.0003, ge=0, description="floor of the robust inlier threshold [m]")
    allow_coplanar: bool = Field(False, description="accept flange positions on one plane (with a warning)")
    normal_weight: float = Field(
        1.0,
        ge=1.0,
        description="eye-in-hand (feature position estimated): weight of each centre's component along "
        "its measured face normal against the in-plane ones; > 1 keeps an oblique rim's in-plane drift "
        "out of the camera translation (1 = the plain point fit)",
    )
    bootstrap: int = Field(100, ge=0, description="bootstrap resamples for the confidence (0 = off)")
    # Algorithm 1
    verifier: Literal["icp", "consensus"] = Field(
        "icp", description="Algorithm 1 error: 'icp' (eq. 13 on a verification scan) or 'consensus'"
    )
    cost: Literal["translation", "radius"] = Field(
        "translation", description="cost of e: ||dt|| (§3.1) or the work-radius metric (§4.2)"
    )
    work_radius: Length = Field(0.3, gt=0, description="work radius r of the §4.2 cost [m]")
    e_required: Length | None = Field(
        None,
        ge=0,
        description="Algorithm 1 stops once the cost is this low (the eye-in-hand job: the fit's predicted "
        "1-sigma translation error) [m]; default 0.5 mm with the ICP metric, "
        "0 (use every pair) with the consensus verifier, whose cost is ~0 on the first pairs",
    )
    pool_k_max: int = Field(10_000, ge=0, description="Algorithm 1 iteration limit k_max")
    pool_search: Literal["published", "wide"] = Field(
        "published",
        description="Algorithm 1's pool search (offline solve): 'published' (the paper's loop) or 'wide' "
        "(also pool_budget 4-subsets with each new pair; docs/methods/hand-eye.md §3.1)",
    )
    pool_budget: int = Field(64, gt=0, description="'wide' pool search: 4-subsets tried per new pair")
    compensate: bool = Field(False, description="apply eq. 21 (H @ e_optimal) to Algorithm 1's result")
    pool_max_verifications: int | None = Field(
        2000,
        gt=0,
        description="Algorithm 1 takes no new pair after this many verifier calls (bounded run time; the "
        "same cut on every run)",
    )
    pool_time_limit: float | None = Field(
        None,
        gt=0,
        description="Algorithm 1 takes no new pair after this many seconds; not repeatable (where it cuts "
        "depends on the host's load), so off unless set [s]",
    )


@dataclass
class FlangeMeasurement:
    """The flange centre ``p_cam`` (m, camera), the face normal (toward the camera), the face points
    used and a report (segmentation and circle statistics)."""

    p_cam: np.ndarray
    normal: np.ndarray
    face: np.ndarray
    report: dict = field(default_factory=dict)


class IncrementalPool:
    """Algorithm 1 fed one point pair at a time (the online form of
    :func:`weldcell.plugins.handeye.iterative.iterative_pool`, with identical steps).

    ``make_verifier(src, dst)`` returns the verifier for the pairs collected so far (the ICP metric
    ignores them; the consensus verifier uses them). Steps 1-3 run when the fourth pair arrives; each
    later pair runs one pass of steps 5-15 while ``cost > e_required`` and ``k <= k_max``.
    """

    def __init__(self, make_verifier, cost, e_required: float, k_max: int, pool_size: int = 4) -> None:
        self.make_verifier = make_verifier
        self.cost_fn = cost
        self.e_required = float(e_required)
        self.k_max = int(k_max)
        self.pool_size = pool_size
        self.src: list[np.ndarray] = []
        self.dst: list[np.ndarray] = []
        self.pool: list[int] = []
        self.H: np.ndarray | None = None
        self.e: np.ndarray | None = None
        self.cost = float("inf")
        self.history: list[float] = []
        self.k = 0
        self.events: list[str] = []

    @property
    def converged(self) -> bool:
        return self.H is not None and self.cost <= self.e_required

    @property
    def H_compensated(self) -> np.ndarray | None:
        return None if (self.H is None or self.e is None) else compensate(self.H, self.e)

    def add(self, src: np.ndarray, dst: np.ndarray) -> float:
        """Add the pair ``src -> dst`` (camera point, base point); return the cost after it."""
        self.src.append(np.asarray(src, float))
        self.dst.append(np.asarray(dst, float))
        n = len(self.src)
        S, D = np.array(self.src), np.array(self.dst)
        if n < self.pool_size:
            self.history.append(float("inf"))
            return self.cost
        verify = self.make_verifier(S, D)
        if self.H is None:  # steps 1-3
            self.pool = list(range(self.pool_size))
            self.H = rigid_fit_batch(S[None, self.pool], D[None, self.pool])[0]
            self.e = verify(self.H)
            self.cost = self.cost_fn(self.e)
        elif self.cost > self.e_required and self.k <= self.k_max:  # steps 5-15 for the new pair
            new = n - 1
            cand = np.array([self.pool[:i] + [new] + self.pool[i + 1 :] for i in range(self.pool_size)])
            Hs = rigid_fit_batch(S[cand], D[cand])
            es = [verify(Hc) for Hc in Hs]
            costs = np.array([self.cost_fn(ec) for ec in es])
            if getattr(verify, "moves_with_data", False) and np.isfinite(self.cost):
                self.e = verify(self.H)  # the consensus reference moved with the new pair
                self.cost = self.cost_fn(self.e)
            i = int(np.argmin(costs))
            if costs[i] < self.cost:
                self.pool = [int(p) for p in cand[i]]
                self.H, self.e, self.cost = Hs[i], es[i], float(costs[i])
                self.events.append(f"pair {new} replaced slot {i}: cost {self.cost:.3g}")
            self.k += 1
        self.history.append(self.cost)
        return self.cost


class _Consensus:
    moves_with_data = True

    def __init__(self, src: np.ndarray, dst: np.ndarray) -> None:
        self.v = ConsensusVerifier(src, dst)

    def __call__(self, H: np.ndarray):
        return self.v(H)


class FlangeHandEye:
    """The ``handeye.flange`` stage: measures flange centres in scans and solves the hand-eye."""

    name = "handeye.flange"
    needs = "flange"

    def __init__(self, s: FlangeSettings) -> None:
        self.s = s

    # -- geometry --------------------------------------------------------------------------------
    @property
    def d3(self) -> float:
        return ISO9409_1[float(self.s.flange_d1)]["d3"] * 1e-3

    @property
    def circle_radius(self) -> float:
        return self.s.radius if self.s.radius is not None else self.d3 / 2 - 0.0005

    @cached_property
    def flange_model(self) -> FlangeModel:
        """The flange model for the ICP metric (eq. 13): the file cleaned (:func:`clean_flange_model`,
        its diameter checked against flange_d1's d3) or the ISO 9409-1 plate."""
        if self.s.flange_model:
            return load_clean_model(self.s.flange_model, self.s.flange_model_units, expected_diameter=self.d3)
        return FlangeModel(iso9409_model(float(self.s.flange_d1), spacing=0.001, rim_depth=0.002))

    @property
    def model(self) -> np.ndarray:
        """Flange model points (flange frame, m) for the ICP metric (eq. 13)."""
        return self.flange_model.points

    def segment_settings(self) -> SegmentSettings:
        return SegmentSettings(
            box_min=self.s.box_min,
            box_max=self.s.box_max,
            voxel=self.s.voxel,
            cluster_eps=self.s.cluster_eps,
            flange_diameter=self.d3,
            plane_distance=self.s.plane_distance,
        )

    def circle_settings(self) -> dict:
        return {
            "radius": self.circle_radius,
            "e_d": self.s.e_d,
            "e_r": self.s.e_r,
            "k_max": self.s.circle_k_max,
        }

    # -- measuring -------------------------------------------------------------------------------
    def crop(self, points: np.ndarray, predicted: np.ndarray | None = None) -> np.ndarray:
        """The pass-through box, then (with a predicted flange centre) a ball of ``track_radius``."""
        P = np.asarray(getattr(points, "points", points), float).reshape(-1, 3)
        P = P[np.all(np.isfinite(P), axis=1) & np.any(P != 0, axis=1)]
        if self.s.box_min is not None:
            P = P[np.all(P >= np.asarray(self.s.box_min), axis=1)]
        if self.s.box_max is not None:
            P = P[np.all(P <= np.asarray(self.s.box_max), axis=1)]
        if predicted is not None and self.s.track_radius is not None:
            near = np.linalg.norm(P - np.asarray(predicted, float), axis=1) <= self.s.track_radius
            if near.sum() >= 200:  # a poor early estimate must not crop the flange away
                P = P[near]
        return P

    def segment(self, P: np.ndarray) -> tuple[np.ndarray, dict]:
        """The flange face points: the paper's segmentation (pass-through, statistical filter,
        flange-size cluster, face plane); when the face and the last link form one cluster, planes
        are peeled off (largest first) and each plane's points are segmented again, so the first
        flange-sized planar cluster wins (e.g. the link's wider end face right behind the plate is
        rejected by the size constraint)."""
        import open3d as o3d

        seg = self.segment_settings()
        seg_nobox = SegmentSettings(**{**seg.__dict__, "box_min": None, "box_max": None})
        try:
            out = segment_flange(P, seg_nobox)
            return out.face, {**out.report, "planes_peeled": 0}
        except DataError as first:
            error = first
        rest = P
        o3d.utility.random.seed(0)
        for k in range(self.s.max_planes):
            if len(rest) < seg.cluster_min_points:
                break
            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(rest))
            with open3d_serial():  # threaded RANSAC draws in a load-dependent order
                _, idx = pc.segment_plane(self.s.plane_distance, 3, seg.plane_iterations)
            on = np.zeros(len(rest), bool)
            on[np.asarray(idx, int)] = True
            try:
                out = segment_flange(rest[on], seg_nobox)
                return out.face, {**out.report, "planes_peeled": k + 1}
            except DataError:
                rest = rest[~on]
        raise DataError(f"no flange found: {error.message}", error.fix)

    def measure(self, points, predicted: np.ndarray | None = None, seed: int = 0) -> FlangeMeasurement:
        """Flange centre in the camera from a raw scan (N, 3, m, camera frame). ``predicted``: where
        the current estimate expects it (crops the scan). Raises DataError when no flange is found."""
        P = self.crop(points, predicted)
        if len(P) < 50:
            raise DataError(
                f"no flange found: only {len(P)} points inside the pass-through box",
                "check the flange is in view and in range, and [stages.handeye] box_min/box_max",
            )
        face, report = self.segment(P)
        circ = ransac_circle(face, rng=seed, **self.circle_settings())
        report.update(radius=circ.radius, circle_rms=circ.rms, support=circ.stats["support"])
        return FlangeMeasurement(circ.center, circ.normal, face, report)

    def measure_pose(self, m: FlangeMeasurement, step_deg: float = 0.5) -> np.ndarray:
        """The flange's full pose ``T_cam_flange`` from a measurement: origin at the circle centre, z
        along the face normal (out of the face, toward the camera), x toward the pin hole. The
        in-plane angle is where the fewest measured face points fall inside the ISO holes (4 tapped
        holes + the pin hole: one angle only fits), taken at the middle of the best plateau, then
        refined by point-to-point ICP of the face model within 1 mm."""
        import open3d as o3d
        from weldcell.plugins.handeye.flange_model import iso9409_dimensions

        z = np.asarray(m.normal, float)
        z /= np.linalg.norm(z)
        u = np.cross(z, [1.0, 0, 0]) if abs(z[0]) < 0.9 else np.cross(z, [0, 1.0, 0])
        u /= np.linalg.norm(u)
        v = np.cross(z, u)
        q = (m.face - m.p_cam) @ np.stack([u, v]).T
        d = iso9409_dimensions(float(self.s.flange_d1))
        rp, n = d["d1"] / 2e3, int(d["n"])
        holes = [(np.pi / n + 2 * np.pi * k / n, d["d4"] / 2e3) for k in range(n)] + [(0.0, d["d5"] / 2e3)]
        rho = np.linalg.norm(q, axis=1)
        near = q[np.abs(rho - rp) < max(r for _, r in holes)]
        theta = np.radians(np.arange(0.0, 360.0, step_deg))
        inside = np.zeros(len(theta))
        for a, r in holes:
            c = rp * np.stack([np.cos(theta + a), np.sin(theta + a)], 1)
            inside += (np.linalg.norm(near[None] - c[:, None], axis=2) < r - 0.0003).sum(1)
        best = np.flatnonzero(inside == inside.min())
        # the middle of the longest run of best angles (circularly)
        runs, start = [], best[0]
        for a, b in zip(best, np.r_[best[1:], best[0] + len(theta)], strict=True):
            if b != a + 1:
                runs.append((start, a))
                start = b % len(theta)
        if len(runs) > 1 and runs[0][0] == 0 and runs[-1][1] == len(theta) - 1:
            runs = [(runs[-1][0], runs[0][1] + len(theta))] + runs[1:-1]
        lo, hi = max(runs, key=lambda r: r[1] - r[0])
        ang = theta[0] + ((lo + hi) / 2) * np.radians(step_deg)
        x = np.cos(ang) * u + np.sin(ang) * v
        T0 = frame_from_axes(x, z, m.p_cam)
        face_model = self.model[self.model[:, 2] > -0.0003]  # the face (a CAD model's is voxel-thinned)
        with open3d_serial():  # repeatable: the threaded correspondence sums vary with the host's load
            reg = o3d.pipelines.registration.registration_icp(
                o3d.geometry.PointCloud(o3d.utility.Vector3dVector(face_model)),
                o3d.geometry.PointCloud(o3d.utility.Vector3dVector(m.face)),
                0.001,
                T0,
                o3d.pipelines.registration.TransformationEstimationPointToPoint(),
                o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=30),
            )
        T = np.asarray(reg.transformation)
        m.report["pose"] = {
            "holes_violated": int(inside.min()),
            "icp_fitness": float(reg.fitness),
            "icp_rmse": float(reg.inlier_rmse),
        }
        return T if reg.fitness > 0.5 else T0

    # -- solving ---------------------------------------------------------------------------------
    def calibrate_settings(self) -> dict:
        """Settings for :func:`weldcell.plugins.handeye.calibrate.calibrate`."""
        return {
            "feature": list(self.s.feature),
            "allow_coplanar": self.s.allow_coplanar,
            "normal_weight": self.s.normal_weight,
            "inlier_threshold": self.s.inlier_threshold,
            "n_sigma": self.s.n_sigma,
            "min_threshold": self.s.min_threshold,
            "circle": self.circle_settings(),
            "segment": {
                k: v
                for k, v in self.segment_settings().__dict__.items()
                if v != getattr(SegmentSettings(), k)
            },
            "verifier": self.s.verifier,
            "cost": self.s.cost,
            "work_radius": self.s.work_radius,
            "e_required": self.e_required,
            "k_max": self.s.pool_k_max,
            "search": self.s.pool_search,
            "budget": self.s.pool_budget,
            "compensate": self.s.compensate,
            "time_limit": self.s.pool_time_limit,
            "max_verifications": self.s.pool_max_verifications,
            "bootstrap": self.s.bootstrap,
        }

    @property
    def e_required(self) -> float:
        if self.s.e_required is not None:
            return self.s.e_required
        return 0.0005 if self.s.verifier == "icp" else 0.0

    def cost_function(self):
        return translation_cost if self.s.cost == "translation" else radius_cost(self.s.work_radius)

    def icp_verifier(self, cloud_v: np.ndarray, T_base_flange_v: np.ndarray) -> IcpVerifier:
        """Eq. 13 at a verification pose: the model (moved to the feature) against the scan's face."""
        model = self.model - np.asarray(self.s.feature, float)
        return IcpVerifier(model, np.asarray(T_base_flange_v, float), np.asarray(cloud_v, float))

    def pool(
        self, verification: tuple[np.ndarray, np.ndarray] | None = None, verifier: str | None = None
    ) -> IncrementalPool:
        """A fresh online Algorithm 1 (``verification`` = (face cloud, T_base_flange) for 'icp');
        ``verifier`` overrides the setting."""
        e_req = self.e_required if (verifier or self.s.verifier) == self.s.verifier else 0.0
        if (verifier or self.s.verifier) == "icp":
            if verification is None:
                raise UsageError(
                    "Algorithm 1 with the ICP metric needs a verification scan and its pose",
                    "take a verification scan first, or set verifier = 'consensus'",
                )
            v = self.icp_verifier(*verification)

            def make(src, dst):
                return v
        else:
            make = _Consensus
        return IncrementalPool(make, self.cost_function(), e_req, self.s.pool_k_max)

    def solve(
        self,
        samples: list[HandEyeSample],
        config: str = "eye-on-base",
        verification: tuple[np.ndarray, np.ndarray] | None = None,
        method: str | None = None,
        **extra,
    ) -> HandEyeResult:
        """:func:`calibrate` with this stage's settings. Samples carry ``p_cam`` (or clouds)."""
        kw = self.calibrate_settings()
        method = method or self.s.method
        if method == "flange-iterative" and self.s.verifier == "icp":
            if verification is None:
                kw["verifier"] = "consensus"
            else:
                kw["verifier"] = self.icp_verifier(*verification)
        kw.update(extra)
        return calibrate(samples, config, method=method, **kw)


class ClassicalSettings(Settings):
    """Target-based hand-eye (AX=XB: Tsai, Park, Horaud, Andreff, Daniilidis; AX=YB: Shah, Li)."""

    method: Literal["tsai", "park", "horaud", "andreff", "daniilidis", "shah", "li"] = Field(
        "park", description="solver"
    )
    backend: Literal["auto", "opencv", "numpy"] = Field(
        "auto", description="OpenCV when it has the solver, else the numpy implementation"
    )
    board: dict = Field(
        default_factory=dict,
        description="board for photos: kind, squares_x, squares_y, square "
        "[m], marker [m], separation [m], dictionary (see board.BoardSpec)",
    )
    intrinsics: str | None = Field(
        None, description="OpenCV YAML with camera_matrix and distortion_coefficients (for board photos)"
    )
    bootstrap: int = Field(50, ge=0, description="bootstrap resamples for the confidence (0 = off)")
    flange: FlangeSettings = Field(
        default_factory=FlangeSettings,
        description="online: how the flange pose is measured in the scans (it is the target)",
    )


class ClassicalHandEye:
    """The ``handeye.opencv`` stage: classical solvers on board poses, board photos, or (online) the
    flange pose measured in each scan."""

    name = "handeye.opencv"
    needs = "pose"

    def __init__(self, s: ClassicalSettings) -> None:
        self.s = s
        self.flange = FlangeHandEye(s.flange)

    def measure(self, points, predicted: np.ndarray | None = None, seed: int = 0) -> FlangeMeasurement:
        m = self.flange.measure(points, predicted, seed)
        m.report["T_cam_flange"] = self.flange.measure_pose(m)
        return m

    def calibrate_settings(self) -> dict:
        kw: dict = {"backend": self.s.backend, "bootstrap": self.s.bootstrap, "board": self.s.board or None}
        if self.s.intrinsics:
            from weldcell.plugins.handeye.board import read_intrinsics

            kw["intrinsics"] = read_intrinsics(Path(self.s.intrinsics))
        return kw

    def solve(
        self,
        samples: list[HandEyeSample],
        config: str = "eye-on-base",
        verification=None,
        method: str | None = None,
        **extra,
    ) -> HandEyeResult:
        kw = {**self.calibrate_settings(), **extra}
        return calibrate(samples, config, method=method or self.s.method, **kw)


def predicted_p_cam(T_base_camera: np.ndarray, T_base_flange: np.ndarray, feature) -> np.ndarray:
    """Where the feature should appear in the camera under an estimate (eye-on-base)."""
    p = np.asarray(T_base_flange, float) @ np.r_[np.asarray(feature, float), 1.0]
    return (invert(np.asarray(T_base_camera, float)) @ p)[:3]
