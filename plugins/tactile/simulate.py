"""Closed-loop simulation of tactile seam tracking (paper 003 §3.3, Fig. 13) against the simulated SRM.

Each camera frame: the SRM contact model gives the tip deflection for the current tool pose, the tag
moves accordingly, the in-finger camera renders it, the detector + PnP measure the tag displacement,
the servo (Algorithm 2) computes a twist, and an ideal velocity-integrating robot applies it until the
next frame. ``render=False`` skips the images and perturbs the true tag pose with Gaussian noise of the
size the rendered pipeline shows (for fast parameter sweeps).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import frame_from_axes, make_T

from .marker import MarkerDisplacementEstimator, MarkerReading
from .paths import Polyline, offset_polyline
from .render import InFingerCamera
from .servo import Gate, ServoSettings, TactileSeamServo, seam_from_tip_path
from .srm_model import SRMParams, Workpiece, contact, tag_pose, tip_deflection_from_tag

SCHEMA = "weldcell/tactile-track@1"


@dataclass
class TrackingResult:
    """Everything a tracking run produced (base frame, SI). Per-frame arrays share the index of ``t``."""

    t: np.ndarray
    robot: np.ndarray  # (K, 3) TCP = undeformed tip centre P_r
    torch: np.ndarray  # (K, 3) P_t
    tip_true: np.ndarray  # (K, 3) actual tip centre
    alpha: np.ndarray  # (K,) tool heading
    twist: np.ndarray  # (K, 6) commanded
    delta_n: np.ndarray  # (K,) measured normal deformation δ^{n_s} (NaN when the marker was lost)
    delta_t: np.ndarray  # (K,) measured tangential deformation δ^{t_s}
    delta_n_true: np.ndarray  # (K,) true normal deformation
    delta_d: np.ndarray  # (K,) reference in force
    in_contact: np.ndarray  # (K,) servo's contact flag
    contact_true: np.ndarray  # (K,) model's contact
    marker_lost: np.ndarray  # (K,) bool
    state: list[str]
    refined_path: np.ndarray  # (M, 3) recorded tip centres P_s (Algorithm 2's refined path)
    refined_times: np.ndarray  # (M,)
    seam_estimate: np.ndarray  # (M, 3) refined path moved onto the wall by the tip radius
    planned_path: np.ndarray
    true_seam: np.ndarray
    stop_reason: str
    final_state: str
    metrics: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (``weldcell/tactile-track@1``): paths in metres, metrics in mm."""
        return {
            "schema": SCHEMA,
            "frame": "base",
            "units": "m",
            "refined_path": self.refined_path.tolist(),
            "seam_estimate": self.seam_estimate.tolist(),
            "stop_reason": self.stop_reason,
            "final_state": self.final_state,
            "metrics": self.metrics,
        }


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def initial_tool_pose(planned_points: np.ndarray) -> np.ndarray:
    """Tool at the planned start, travel axis along the planned start tangent, z pointing down."""
    line = Polyline(planned_points, "planned path")
    p = line.at(0.0)[0]
    t = line.smooth_tangent(0.0, 0.005)
    z0 = p[2] if len(p) == 3 else 0.0
    return frame_from_axes([t[0], t[1], 0.0], [0.0, 0.0, -1.0], [p[0], p[1], z0])


@dataclass
class SimulationOptions:
    """The closed-loop simulation's knobs (the paper §3.1 protocol's), each with its default.

    ``settings``: the servo's (default :class:`ServoSettings`); ``srm``: the true tool (default: the
    servo's tip radius); ``camera``: the in-finger camera (default seeded by ``seed``); ``render``:
    images through the detector, else the true tag pose with ``marker_noise`` (m, σ) added; ``rate_hz``:
    camera frames per second; ``max_time`` (s): default 3× the plan's travel time + 5 s; ``gate``: the
    motion gate; ``wall_normals``: of the seam's wall (default from the seam); ``tag_gain_error``: the
    servo's tag-to-tip gain wrong by this fraction (SRM calibration error); ``start_pose``: the tool's
    (default :func:`initial_tool_pose`); ``seed``: of camera noise and marker noise.
    """

    settings: ServoSettings | None = None
    srm: SRMParams | None = None
    camera: InFingerCamera | None = None
    render: bool = True
    rate_hz: float = 50.0
    max_time: float | None = None
    gate: Gate | None = None
    wall_normals: np.ndarray | None = None
    marker_noise: float = 1.5e-5
    tag_gain_error: float = 0.0
    start_pose: np.ndarray | None = None
    seed: int = 0


# keyword-only simulation options, each with a default (the paper §3.1 protocol's knobs): the call form
# of SimulationOptions, kept for its callers (simulate_tracking takes the object)
def track_seam(
    seam_points_true: np.ndarray,
    planned_path_with_error: np.ndarray,
    *,
    settings: ServoSettings | None = None,
    srm: SRMParams | None = None,
    camera: InFingerCamera | None = None,
    render: bool = True,
    rate_hz: float = 50.0,
    max_time: float | None = None,
    gate: Gate | None = None,
    wall_normals: np.ndarray | None = None,
    marker_noise: float = 1.5e-5,
    tag_gain_error: float = 0.0,
    start_pose: np.ndarray | None = None,
    seed: int = 0,
) -> TrackingResult:
    """Run the servo against the simulated SRM along ``seam_points_true`` starting on the planned path.

    ``settings.wall_side`` says on which side of travel the wall stands (the free side is the other).
    ``tag_gain_error`` makes the servo's tag-to-tip gain wrong by that fraction (SRM calibration error).
    The options are those of :class:`SimulationOptions`.
    """
    options = SimulationOptions(
        settings=settings,
        srm=srm,
        camera=camera,
        render=render,
        rate_hz=rate_hz,
        max_time=max_time,
        gate=gate,
        wall_normals=wall_normals,
        marker_noise=marker_noise,
        tag_gain_error=tag_gain_error,
        start_pose=start_pose,
        seed=seed,
    )
    return simulate_tracking(seam_points_true, planned_path_with_error, options)


def simulate_tracking(
    seam_points_true: np.ndarray,
    planned_path_with_error: np.ndarray,
    options: SimulationOptions | None = None,
) -> TrackingResult:
    """:func:`track_seam` with its options as one :class:`SimulationOptions`."""
    o = options or SimulationOptions()
    S = o.settings or ServoSettings()
    srm = o.srm or SRMParams(tip_radius=S.tip_radius)
    if abs(srm.tip_radius - S.tip_radius) > 1e-9:
        raise DataError(
            "simulation: servo tip_radius differs from the SRM model's tip radius",
            "give both the same tip radius",
        )
    if o.rate_hz <= 0:
        raise DataError("simulation: rate_hz must be > 0", "use the camera rate, e.g. 30-60 Hz")
    seam = np.asarray(seam_points_true, dtype=float)
    plan = np.asarray(planned_path_with_error, dtype=float)
    if plan.ndim == 2 and plan.shape[1] == 2:
        plan = np.column_stack([plan, np.full(len(plan), seam[0, 2] if seam.shape[1] == 3 else 0.0)])
    free_side = "right" if S.wall_side == "left" else "left"
    wp = Workpiece(seam, o.wall_normals, free_side=free_side)
    sensor = _TagSensor(o, srm)
    servo = TactileSeamServo(plan, S, o.gate)
    T = initial_tool_pose(plan) if o.start_pose is None else np.asarray(o.start_pose, dtype=float).copy()
    max_time = o.max_time
    if max_time is None:
        max_time = 3.0 * (Polyline(plan).length + 0.05) / S.speed + 5.0
    rec, cmd = _run_loop(T, wp, srm, sensor, servo, 1.0 / o.rate_hz, max_time)
    return _tracking_result(rec, servo, plan, seam, cmd, S, srm)


class _TagSensor:
    """The in-finger camera and the marker estimator: a true tag pose in, the servo's tip deflection out
    (None when the marker is lost), through rendered images or the noisy true pose."""

    def __init__(self, o: SimulationOptions, srm: SRMParams) -> None:
        self.cam = cam = o.camera or InFingerCamera(seed=o.seed)
        self.est = MarkerDisplacementEstimator(cam.intrinsics, cam.marker_size, cam.marker_id, cam.dictionary)
        self.rng = np.random.default_rng(o.seed + 1)
        self.render, self.marker_noise = o.render, o.marker_noise
        if o.render:
            self.est.capture_rest([cam.render(cam.T_cam_tag_rest) for _ in range(5)])
        else:
            self.est.set_rest(cam.T_cam_tag_rest)
        g = 1.0 + o.tag_gain_error  # the gains the servo assumes
        self.assumed = SRMParams(
            **{**srm.__dict__, "tag_gain": srm.tag_gain * g, "tag_axial_gain": srm.tag_axial_gain * g}
        )

    def deflection(self, T_cam_tag: np.ndarray, t: float) -> np.ndarray | None:
        if self.render:
            reading = self.est.update(self.cam.render(T_cam_tag), t)
        else:
            rng = self.rng
            noisy = make_T(
                Rotation.from_rotvec(rng.normal(0.0, 2e-3, 3)).as_matrix() @ T_cam_tag[:3, :3],
                T_cam_tag[:3, 3] + rng.normal(0.0, self.marker_noise, 3) * np.array([1.0, 1.0, 2.0]),
            )
            reading = self.est.update_pose(noisy, t)
        if isinstance(reading, MarkerReading):
            return -tip_deflection_from_tag(reading.displacement, self.assumed)
        return None


def _run_loop(
    T: np.ndarray,
    wp: Workpiece,
    srm: SRMParams,
    sensor: _TagSensor,
    servo: TactileSeamServo,
    dt: float,
    max_time: float,
):
    """Frames until the servo is done or ``max_time``: contact, marker, servo step, then an ideal
    velocity-integrating robot holds the commanded TCP twist for one frame. (recorded frames, last command)"""
    rec: dict[str, list] = {k: [] for k in _RECORDED}
    v_prev = np.zeros(3)
    k = 0
    cmd = None
    while k * dt <= max_time:
        t = k * dt
        c = contact(T, wp, srm, v_prev)
        delta_tool = sensor.deflection(tag_pose(c.deflection_tool, srm, sensor.cam.T_cam_tag_rest), t)
        cmd = servo.step(t, T, delta_tool)
        _record(rec, t, T, cmd, c, delta_tool is not None)
        if cmd.done:
            break
        v, w = cmd.twist[:3], cmd.twist[3:]
        T = T.copy()
        T[:3, 3] += v * dt
        T[:3, :3] = Rotation.from_rotvec(w * dt).as_matrix() @ T[:3, :3]
        v_prev = v
        k += 1
    return rec, cmd


_RECORDED = (
    "t",
    "robot",
    "torch",
    "tip",
    "alpha",
    "twist",
    "dn",
    "dt",
    "dn_true",
    "dd",
    "contact",
    "contact_true",
    "lost",
    "state",
)


def _record(rec: dict[str, list], t: float, T: np.ndarray, cmd, c, measured: bool) -> None:
    """One frame of the simulation: the servo's command and the true contact."""
    n_true = -c.wall_normal if c.in_contact else None
    true_dn = float((-(T[:3, :3] @ c.deflection_tool))[:2] @ n_true[:2]) if n_true is not None else 0.0
    rec["t"].append(t)
    rec["robot"].append(T[:3, 3].copy())
    rec["torch"].append(cmd.P_t)
    rec["tip"].append(c.tip_position)
    rec["alpha"].append(float(np.arctan2(T[1, 0], T[0, 0])))
    rec["twist"].append(cmd.twist)
    rec["dn"].append(cmd.delta_n if measured else np.nan)
    rec["dt"].append(cmd.delta_t if measured else np.nan)
    rec["dn_true"].append(true_dn)
    rec["dd"].append(cmd.delta_d)
    rec["contact"].append(cmd.in_contact)
    rec["contact_true"].append(c.in_contact)
    rec["lost"].append(not measured)
    rec["state"].append(cmd.state)


def _tracking_result(
    rec: dict[str, list], servo, plan, seam, cmd, S: ServoSettings, srm: SRMParams
) -> TrackingResult:
    """The recorded frames, the refined path and its seam estimate, with :func:`tracking_metrics`."""
    refined = servo.refined.points
    seam_est = seam_from_tip_path(refined, S.tip_radius, S.wall_side, S.tangent_window)
    res = TrackingResult(
        t=np.array(rec["t"]),
        robot=np.array(rec["robot"]),
        torch=np.array(rec["torch"]),
        tip_true=np.array(rec["tip"]),
        alpha=np.array(rec["alpha"]),
        twist=np.array(rec["twist"]),
        delta_n=np.array(rec["dn"]),
        delta_t=np.array(rec["dt"]),
        delta_n_true=np.array(rec["dn_true"]),
        delta_d=np.array(rec["dd"]),
        in_contact=np.array(rec["contact"]),
        contact_true=np.array(rec["contact_true"]),
        marker_lost=np.array(rec["lost"]),
        state=rec["state"],
        refined_path=refined,
        refined_times=servo.refined.times,
        seam_estimate=seam_est,
        planned_path=plan,
        true_seam=seam,
        stop_reason=cmd.reason if cmd is not None else "",
        final_state=cmd.state if cmd is not None else "",
    )
    res.metrics = tracking_metrics(res, S, srm)
    return res


def tracking_metrics(res: TrackingResult, settings: ServoSettings, srm: SRMParams) -> dict[str, float]:
    """Errors in millimetres: refined seam vs true seam, refined tip path vs true tip, plan vs seam, torch."""
    seam_line = Polyline(res.true_seam, "seam")
    free_side = "right" if settings.wall_side == "left" else "left"
    tip_locus = Polyline(offset_polyline(res.true_seam, srm.tip_radius, free_side), "tip locus")
    m: dict[str, float] = {}
    if len(res.seam_estimate):
        inside = np.array(
            [not (p.before_start or p.past_end) for p in map(seam_line.project, res.seam_estimate)]
        )
        d = seam_line.distances(res.seam_estimate[inside])
        m["refined_seam_rms_mm"] = _rms(d) * 1e3
        m["refined_seam_max_mm"] = float(d.max()) * 1e3 if len(d) else float("nan")
        # per-point error of the recorded tip centre vs the true tip at the same instant
        idx = np.searchsorted(res.t, res.refined_times)
        e = np.linalg.norm(
            res.refined_path[:, :2] - res.tip_true[np.clip(idx, 0, len(res.t) - 1), :2], axis=1
        )
        m["refined_tip_rms_mm"] = _rms(e) * 1e3
        m["refined_points"] = float(len(res.refined_path))
        m["refined_coverage"] = (
            float(Polyline(res.refined_path).length / seam_line.length) if len(res.refined_path) >= 2 else 0.0
        )
    plan_inside = np.array(
        [not (p.before_start or p.past_end) for p in map(seam_line.project, res.planned_path)]
    )
    m["plan_rms_mm"] = _rms(seam_line.distances(res.planned_path[plan_inside])) * 1e3
    tproj = [tip_locus.project(p) for p in res.torch]
    on = np.array([not (p.before_start or p.past_end) for p in tproj]) & (np.arange(len(res.torch)) > 0)
    if on.any():
        m["torch_rms_mm"] = _rms(tip_locus.distances(res.torch[on])) * 1e3
    contact_idx = res.in_contact & ~np.isnan(res.delta_n)
    if contact_idx.any():
        m["delta_n_mean_mm"] = float(np.nanmean(res.delta_n[contact_idx])) * 1e3
        m["delta_n_std_mm"] = float(np.nanstd(res.delta_n[contact_idx])) * 1e3
        m["delta_n_meas_err_rms_mm"] = (
            _rms((res.delta_n - res.delta_n_true)[contact_idx & res.contact_true]) * 1e3
        )
    m["duration_s"] = float(res.t[-1]) if len(res.t) else 0.0
    m["frames"] = float(len(res.t))
    m["marker_lost_frames"] = float(res.marker_lost.sum())
    m["max_abs_omega"] = float(np.max(np.abs(res.twist[:, 5]))) if len(res.twist) else 0.0
    return m
