"""Deformation servo and online torch-trajectory generation (paper 003 §2.2.2, eqs. 14-18, Algorithm 2).

Geometry (Fig. 8), in the working plane orthogonal to the base z axis:

* ``P_r`` robot end effector = the TCP, placed at the SRM tip's *undeformed* centre;
* ``t_d = [cos α, sin α]``, ``n_d = [-sin α, cos α]`` the tool's direction (α about base +z);
* the torch trails the tip: ``P_t = P_r - ‖d‖ t_d`` (eq. 14);
* the actual tip ``P_s = P_r - δ`` (eq. 15), δ the SRM deformation sensed through the ArUco tag;
* SERVO: ``V_r = V_const t_v - k_p (δ^{n_s} - δ_d) n_v`` (eq. 16, Alg. 2 line 24), t_v, n_v the planned
  path's tangent and (into-the-wall) normal at the point nearest to P_r;
* REFINE: the tip positions ``P_s`` form the refined path the torch follows (Alg. 2 lines 16-20);
* the torch's velocity ``V_t = V_r - ω ‖d‖ n_d`` (eq. 17) must have no component along the refined
  path's normal ``n_t`` at the torch (eq. 18), which gives ω (Alg. 2 line 13).

Where this module differs from the paper (details in docs/methods/tactile-tracking.md):

* Sign of ω: with eq. 14 and α counter-clockwise, dP_t/dt = V_r − ω‖d‖n_d; the paper's eq. 17 writes
  "+", i.e. measures ω clockwise. We use the right-handed ω of the twist, so line 13's leading minus
  drops; line 13's ``V_r^{n_d}·t_t`` is read as ``V_r^{n_d}·n_t`` (eq. 18).
* Torch position feedback: eq. 18 only keeps the torch *velocity* tangent; we add ``-k_t e_t`` (e_t the
  torch's lateral distance to the refined path) so an initial offset decays (``torch_gain = 0`` = paper).
* Singularity n_d ⟂ n_t (§5.2): ω uses damped least squares with a damping that is zero outside
  ``|n_d·n_t| < singular_cos`` (so ω is exact there) and bounds ω inside; in that zone the travel speed
  is scaled down and the heading is steered back towards the path tangent, which leaves the
  singular set; |ω| is saturated at ``omega_max``.
* End of seam (§3.3, §5.2): instead of resetting δ_d to 0 (the jitter of Fig. 13), contact has hysteresis
  and debouncing; on loss of contact the tool holds the last refined tangent, commands no normal motion
  and decelerates to rest along a quintic (jerk-bounded) profile. ``end_mode="paper"`` reproduces the
  paper's behaviour for comparison.
* The planned and refined paths are projected onto segments (not nearest vertices) within a window
  around the last foot point, so a path that comes back near itself cannot make the servo jump.
* Every command is data (:class:`ServoCommand`), optionally passed through ``gate(twist, T)``; a
  :class:`~weldcell.sdk.errors.SafetyError` from the gate stops the servo with a zero twist.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from pydantic import Field
from weldcell.sdk.errors import DataError, SafetyError, UsageError
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import AngularSpeed, Duration, Length, Speed

from .paths import Polyline, left_normal
from .refined_path import RefinedPath, seam_from_tip_path  # noqa: F401  (seam_from_tip_path re-exported)
from .servo_equations import (  # noqa: F401  (the equations re-exported: this module's old public names)
    OmegaSolution,
    quintic_ramp_down,
    refine_point,
    servo_velocity,
    split_deformation,
    tool_directions,
    torch_angular_velocity,
    torch_position,
)

Gate = Callable[[np.ndarray, np.ndarray], None]


class ServoSettings(Settings):
    """Settings of the tactile seam-tracking servo (SI; profiles may write ``"5 mm/s"``)."""

    speed: Speed = Field(0.005, gt=0, description="V_const, travel speed along the planned tangent (eq. 16)")
    k_p: float = Field(4.0, gt=0, description="deformation servo gain k_p (1/s), eq. 16")
    delta_d: Length = Field(0.001, gt=0, description="desired normal deformation δ_d (into the wall)")
    torch_offset: Length = Field(0.04, gt=0, description="‖d‖, tip-to-torch distance in the plane (eq. 14)")
    wall_side: Literal["left", "right"] = Field("left", description="side of travel where the wall is")
    tip_radius: Length = Field(
        0.002, ge=0, description="SRM tip radius, to offset the refined path onto the seam"
    )
    contact_on: Length = Field(0.0004, gt=0, description="δ^n above which contact is declared")
    contact_off: Length = Field(0.00015, ge=0, description="δ^n below which contact counts as lost")
    contact_debounce: int = Field(3, ge=1, description="consecutive frames below contact_off to declare loss")
    approach_speed_scale: float = Field(
        0.3, ge=0, le=1, description="travel speed fraction before first contact"
    )
    max_normal_speed: Speed = Field(0.006, gt=0, description="clamp of the servo's normal velocity")
    max_accel: float = Field(0.1, gt=0, description="linear acceleration limit of commands (m/s²)")
    stop_time: Duration = Field(0.5, gt=0, description="duration of the smooth stop on loss of contact")
    end_mode: Literal["hold-and-stop", "paper"] = Field("hold-and-stop", description="end-of-seam behaviour")
    plan_overrun: Length = Field(
        0.005, ge=0, description="distance allowed past the planned end while in contact"
    )
    torch_gain: float = Field(2.0, ge=0, description="k_t (1/s): torch lateral error feedback (0 = paper)")
    singular_cos: float = Field(
        0.35, gt=0, lt=1, description="|n_d·n_t| below which the singular handling acts"
    )
    damping: float = Field(0.3, gt=0, description="DLS damping at the singularity, as a fraction of ‖d‖")
    align_gain: float = Field(1.5, ge=0, description="heading re-alignment gain (1/s) in the singular zone")
    omega_max: AngularSpeed = Field(0.6, gt=0, description="|ω| limit")
    max_lost_frames: int = Field(5, ge=0, description="marker-lost frames tolerated before stopping")
    max_deflection: Length = Field(0.005, gt=0, description="|δ| beyond which the servo stops (overload)")
    z_gain: float = Field(2.0, ge=0, description="gain (1/s) holding the TCP at the planned height")
    window: Length = Field(0.02, gt=0, description="search window (±) for the nearest planned/refined point")
    refine_step: Length = Field(0.0003, gt=0, description="minimum spacing of recorded refined points")
    tangent_window: Length = Field(0.003, gt=0, description="half window of the refined-path tangent fit")


# ---------------------------------------------------------------------------------------------- #
# The online loop (Algorithm 2 lines 2-15) as a stateful, data-only controller
# ---------------------------------------------------------------------------------------------- #

State = Literal["approach", "tracking", "stopping", "stopped", "fault"]


@dataclass(frozen=True)
class ServoCommand:
    """One control period's output. ``twist`` = [vx, vy, vz, wx, wy, wz] of the TCP in the base frame."""

    t: float
    twist: np.ndarray
    state: State
    reason: str
    in_contact: bool
    delta_n: float
    delta_t: float
    delta_d: float
    P_r: np.ndarray
    P_s: np.ndarray | None
    P_t: np.ndarray
    s_plan: float
    omega: float
    singular_weight: float
    torch_error: float

    @property
    def done(self) -> bool:
        return self.state in ("stopped", "fault")


@dataclass
class _Memory:
    state: State = "approach"
    reason: str = ""
    s_plan: float | None = None
    s_torch: float | None = None
    below: int = 0
    lost: int = 0
    last_delta: np.ndarray | None = None
    contact: bool = False
    ever_contact: bool = False
    v_prev: np.ndarray = field(default_factory=lambda: np.zeros(3))
    t_prev: float | None = None
    stop_t0: float = 0.0
    stop_v0: float = 0.0
    stop_omega0: float = 0.0
    stop_dir: np.ndarray = field(default_factory=lambda: np.zeros(2))


class TactileSeamServo:
    """Algorithm 2 as a controller: call :meth:`step` once per camera frame.

    ``planned_points`` (N, 2|3) is the path from 3-D vision (base frame), ordered along travel.
    ``gate(twist, T_base_tool)`` may raise :class:`SafetyError`; the servo then stops (zero twist,
    state ``"fault"``) and never sends another motion.
    """

    def __init__(
        self, planned_points: np.ndarray, settings: ServoSettings | None = None, gate: Gate | None = None
    ) -> None:
        self.settings = settings or ServoSettings()
        if self.settings.contact_off >= self.settings.contact_on:
            raise UsageError(
                "servo: contact_off must be below contact_on (hysteresis)",
                "e.g. contact_on = 0.4 mm, contact_off = 0.15 mm",
            )
        if self.settings.contact_on >= self.settings.delta_d:
            raise UsageError(
                "servo: contact_on must be below the desired deformation delta_d",
                "lower contact_on or raise delta_d",
            )
        P = np.asarray(planned_points, dtype=float)
        if P.ndim == 2 and P.shape[1] == 2:
            P = np.column_stack([P, np.zeros(len(P))])
        self.plan = Polyline(P, "planned path")
        self.gate = gate
        self.refined = RefinedPath(self.settings.refine_step)
        self._m = _Memory()
        self._sigma = 1.0 if self.settings.wall_side == "left" else -1.0

    @property
    def state(self) -> State:
        return self._m.state

    def _plan_frame(self, P_r: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, bool]:
        m, S = self._m, self.settings
        pr = self.plan.project(P_r, m.s_plan, S.window if m.s_plan is not None else None)
        m.s_plan = pr.s
        t_v = self.plan.smooth_tangent(pr.s, S.tangent_window)
        return pr.s, pr.point, t_v, self._sigma * left_normal(t_v), pr.past_end

    def _torch_frame(self, P_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Tangent, normal, signed lateral error of the torch w.r.t. the refined path (plan as fallback)."""
        S, m = self.settings, self._m
        line = self.refined.polyline()
        use_refined = line is not None and line.length >= min(S.torch_offset, 0.01)
        if use_refined:
            pr = line.project(P_t, m.s_torch, S.window + S.torch_offset if m.s_torch is not None else None)
            m.s_torch = pr.s
            # before the refined path's start: extrapolate its initial direction (fitted over ≤ 10 mm)
            hw = min(line.length, 0.01) if pr.before_start else S.tangent_window
            t_t = line.smooth_tangent(pr.s, hw)
            if pr.before_start:
                pr = replace(pr, point=line.points[0])
        else:
            pr = self.plan.project(P_t)
            t_t = self.plan.smooth_tangent(pr.s, S.tangent_window)
        n_t = left_normal(t_t)
        e = float((np.asarray(P_t)[:2] - pr.point[:2]) @ n_t)
        return t_t, n_t, e

    def _begin_stop(self, t: float, reason: str, direction: np.ndarray, omega: float) -> None:
        m = self._m
        m.state, m.reason = "stopping", reason
        m.stop_t0 = t
        n = np.linalg.norm(direction)
        m.stop_dir = direction / n if n > 1e-9 else np.zeros(2)
        m.stop_v0 = max(0.0, float(m.v_prev[:2] @ m.stop_dir))  # keep only the travel along the held tangent
        m.stop_omega0 = omega

    def stop(self, t: float, reason: str = "requested") -> None:
        """Ask for a smooth stop (e.g. operator request)."""
        if self._m.state in ("approach", "tracking"):
            self._begin_stop(t, reason, self._m.v_prev[:2], 0.0)

    def step(self, t: float, T_base_tool: np.ndarray, delta_tool: np.ndarray | None) -> ServoCommand:
        """One period: ``delta_tool`` = δ = P_r − P_s in the tool frame (3,), None if the marker is lost."""
        S, m = self.settings, self._m
        T = np.asarray(T_base_tool, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise DataError("servo: robot pose must be a finite 4x4 transform", "pass the measured TCP pose")
        dt = 0.0 if m.t_prev is None else max(0.0, t - m.t_prev)
        m.t_prev = t
        t_d, n_d, P_r, P_t = self._tool_pose(T)  # lines 3-5
        delta_tool, lost = self._deformation(delta_tool)  # line 6
        delta_base = (T[:3, :3] @ delta_tool) if delta_tool is not None else np.zeros(3)
        # line 22-23: nearest planned point
        s_plan, P_v, t_v, n_v, past_end = self._plan_frame(P_r)
        delta_n, delta_t = split_deformation(delta_base, t_v, n_v)
        self._update_contact(delta_tool is not None, delta_n)
        # lines 7, 16-20: REFINE (only from real, in-contact measurements)
        P_s = None
        if m.contact and not lost and m.state in ("approach", "tracking"):
            P_s2 = refine_point(P_r, delta_base)
            P_s = np.array([P_s2[0], P_s2[1], P_r[2] - delta_base[2]])
            self.refined.append(P_s, t)
        self._end_of_seam(t, lost, delta_tool, past_end, s_plan, P_r, t_v)
        V2, delta_d = self._travel_velocity(t, delta_tool, delta_n, t_v, n_v)  # line 8 / 21-26
        V2, sol, e_t = self._torch_rate(V2, t_d, n_d, P_t, t_v)  # lines 9-13
        omega = sol.omega
        if m.state == "stopping":
            omega *= quintic_ramp_down((t - m.stop_t0) / S.stop_time)
        if m.state in ("stopped", "fault"):
            omega = 0.0
        twist = self._command(T, V2, omega, P_v[2] - P_r[2], dt)  # line 14
        m.v_prev = twist[:3].copy()
        return ServoCommand(
            t,
            twist,
            m.state,
            m.reason,
            m.contact,
            delta_n,
            delta_t,
            delta_d,
            P_r,
            P_s,
            P_t,
            s_plan,
            float(twist[5]),
            sol.weight,
            e_t,
        )

    def _tool_pose(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Algorithm 2 lines 3-5: tool travel direction t_d and its normal n_d (plane), end-effector P_r
        and torch P_t positions."""
        x_axis = T[:2, 0]
        if np.linalg.norm(x_axis) < 1e-6:
            raise DataError(
                "servo: tool x axis is vertical; the planar method needs a horizontal travel axis",
                "orient the tool with its x (travel) axis in the working plane",
            )
        t_d = x_axis / np.linalg.norm(x_axis)
        n_d = left_normal(t_d)
        P_r = T[:3, 3].copy()
        P_t2 = torch_position(P_r, t_d, self.settings.torch_offset)
        P_t = np.array([P_t2[0], P_t2[1], P_r[2]])
        return t_d, n_d, P_r, P_t

    def _deformation(self, delta_tool: np.ndarray | None) -> tuple[np.ndarray | None, bool]:
        """Line 6: the deformation to use (the last one held through short marker losses) and whether
        this frame's marker was lost."""
        m = self._m
        lost = delta_tool is None
        if lost:
            m.lost += 1
            delta_tool = m.last_delta if m.last_delta is not None else None
        else:
            m.lost = 0
            delta_tool = np.asarray(delta_tool, dtype=float)
            if delta_tool.shape != (3,) or not np.all(np.isfinite(delta_tool)):
                raise DataError(
                    "servo: deformation must be a finite 3-vector (tool frame)",
                    "pass P_r - P_s in the tool frame, or None when the marker is lost",
                )
            m.last_delta = delta_tool
        return delta_tool, lost

    def _update_contact(self, measured: bool, delta_n: float) -> None:
        """Contact with hysteresis and debounce (paper mode: a plain threshold); approach → tracking."""
        S, m = self.settings, self._m
        if S.end_mode == "paper":
            m.contact = measured and delta_n > S.contact_on
        elif measured:
            if delta_n > S.contact_on:
                m.contact, m.below = True, 0
            elif delta_n < S.contact_off:
                m.below += 1
                if m.below >= S.contact_debounce:
                    m.contact = False
        m.ever_contact = m.ever_contact or m.contact
        if m.state == "approach" and m.contact:
            m.state = "tracking"

    def _end_of_seam(
        self,
        t: float,
        lost: bool,
        delta_tool: np.ndarray | None,
        past_end: bool,
        s_plan: float,
        P_r: np.ndarray,
        t_v: np.ndarray,
    ) -> None:
        """State transitions of the safe end-of-seam logic (paper mode: stop at once)."""
        S, m = self.settings, self._m
        if m.state in ("approach", "tracking") and S.end_mode == "hold-and-stop":
            if lost and m.lost > S.max_lost_frames:
                self._begin_stop(t, "marker lost", m.v_prev[:2], 0.0)
            elif delta_tool is not None and float(np.linalg.norm(delta_tool)) > S.max_deflection:
                self._begin_stop(t, "overload", m.v_prev[:2], 0.0)
            elif m.state == "tracking" and not m.contact:
                self._begin_stop(t, "contact lost", self._hold_direction(t_v), 0.0)
            elif (
                past_end
                and (m.state == "approach" or s_plan >= self.plan.length - 1e-9)
                and (float((P_r[:2] - self.plan.xy[-1]) @ self.plan.vertex_tangent[-1]) >= S.plan_overrun)
            ):
                self._begin_stop(t, "end of planned path", self._hold_direction(t_v), 0.0)
        elif m.state in ("approach", "tracking") and S.end_mode == "paper":
            if lost and m.lost > S.max_lost_frames:
                m.state, m.reason = "stopped", "marker lost"
            elif past_end:
                m.state, m.reason = "stopped", "end of planned path"

    def _travel_velocity(
        self, t: float, delta_tool: np.ndarray | None, delta_n: float, t_v: np.ndarray, n_v: np.ndarray
    ) -> tuple[np.ndarray, float]:
        """Line 8 / 21-26, SERVO: the planar velocity V2 and the desired deformation δ_d used."""
        S, m = self.settings, self._m
        delta_d = S.delta_d
        if m.state in ("approach", "tracking"):
            if S.end_mode == "paper" and m.ever_contact and not m.contact:
                delta_d = 0.0  # §3.3: δ_d reset to zero when the SRM loses contact
            speed = S.speed * (S.approach_speed_scale if m.state == "approach" else 1.0)
            if delta_tool is None:
                V2 = speed * t_v
            else:
                V2 = servo_velocity(t_v, n_v, delta_n, delta_d, speed, S.k_p, S.max_normal_speed)
                if S.end_mode != "paper" and m.state == "tracking" and delta_n < S.contact_on:
                    # contact fading (the wall recedes, e.g. the tip rolls round the seam's end): fade the
                    # wall-seeking normal velocity out between contact_on and contact_off instead of
                    # accelerating towards a wall that is no longer there
                    fade = float(
                        np.clip((delta_n - S.contact_off) / (S.contact_on - S.contact_off), 0.0, 1.0)
                    )
                    vn = float(V2 @ n_v)
                    vn_band = min(vn, S.k_p * (S.delta_d - S.contact_on)) * fade
                    V2 = V2 + (vn_band - vn) * n_v
        elif m.state == "stopping":
            scale = quintic_ramp_down((t - m.stop_t0) / S.stop_time)
            V2 = m.stop_v0 * scale * m.stop_dir
            if scale <= 0.0:
                m.state = "stopped"
        else:
            V2 = np.zeros(2)
        return V2, delta_d

    def _torch_rate(
        self, V2: np.ndarray, t_d: np.ndarray, n_d: np.ndarray, P_t: np.ndarray, t_v: np.ndarray
    ) -> tuple[np.ndarray, OmegaSolution, float]:
        """Lines 9-13: the torch frame and ω; in the singular zone the travel slows (the deformation
        servo's normal part kept). Returns V2, the ω solution and the torch's lateral error."""
        S, m = self.settings, self._m
        t_t, n_t, e_t = self._torch_frame(P_t)
        heading_error = math.atan2(t_d[0] * t_t[1] - t_d[1] * t_t[0], float(t_d @ t_t))

        def omega_for(V: np.ndarray):
            return torch_angular_velocity(
                V,
                t_d,
                n_d,
                n_t,
                S.torch_offset,
                e_t,
                S.torch_gain,
                S.singular_cos,
                S.damping,
                heading_error,
                S.align_gain,
                S.omega_max,
            )

        sol = omega_for(V2)
        if m.state in ("approach", "tracking") and sol.weight < 1.0:
            # slow the travel in the singular zone, keep the deformation servo's normal part
            along = float(V2 @ t_v)
            V2 = V2 + (sol.weight - 1.0) * along * t_v
            sol = omega_for(V2)
        return V2, sol, e_t

    def _command(self, T: np.ndarray, V2: np.ndarray, omega: float, dz: float, dt: float) -> np.ndarray:
        """The twist sent: height servo on ``dz`` (plan minus TCP), acceleration limit, then (line 14)
        the safety gate; a refusal is a fault and a zero twist."""
        S, m = self.settings, self._m
        vz = S.z_gain * dz if m.state in ("approach", "tracking") else 0.0
        V = np.array([V2[0], V2[1], vz])
        if m.state in ("approach", "tracking") and dt > 0:  # acceleration limit
            dv = V - m.v_prev
            lim = S.max_accel * dt
            nd = float(np.linalg.norm(dv))
            if nd > lim:
                V = m.v_prev + dv * (lim / nd)
        twist = np.array([V[0], V[1], V[2], 0.0, 0.0, omega])
        if m.state == "fault":
            twist = np.zeros(6)
        elif self.gate is not None and np.any(twist != 0.0):
            try:
                self.gate(twist.copy(), T.copy())
            except SafetyError as exc:
                m.state, m.reason = "fault", f"safety: {exc.message}"
                twist = np.zeros(6)
        return twist

    def _hold_direction(self, t_v: np.ndarray) -> np.ndarray:
        """Direction to coast in while stopping: the refined path's last tangent, else the plan's."""
        S = self.settings
        line = self.refined.polyline()
        # skip the last tip radius: there the tip may already be rolling round the end of the wall
        s_hold = (line.length - S.tip_radius - S.tangent_window) if line is not None else -1.0
        if line is not None and s_hold > S.tangent_window:
            return line.smooth_tangent(s_hold, S.tangent_window)
        return np.asarray(t_v, dtype=float)


def box_gate(lo: np.ndarray, hi: np.ndarray, horizon: float = 0.1, max_speed: float = 0.05) -> Gate:
    """Workspace gate: refuses a too fast twist, or one taking the TCP out of the box within ``horizon``."""
    lo_a, hi_a = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)

    def gate(twist: np.ndarray, T: np.ndarray) -> None:
        v = np.asarray(twist, dtype=float)[:3]
        if float(np.linalg.norm(v)) > max_speed:
            raise SafetyError(
                f"speed {np.linalg.norm(v) * 1e3:.1f} mm/s above the limit {max_speed * 1e3:.1f} mm/s",
                "lower the servo speed or raise the cell's speed limit",
            )
        p = np.asarray(T, dtype=float)[:3, 3] + horizon * v
        if np.any(p < lo_a) or np.any(p > hi_a):
            raise SafetyError(
                f"TCP would leave the workspace box at {np.round(p * 1e3, 1).tolist()} mm",
                "check the planned path against the cell's workspace limits",
            )

    return gate
