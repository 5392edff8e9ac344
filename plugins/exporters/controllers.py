"""KUKA KRL (.src, optionally with its .dat) and FANUC TP (.ls) programs from a weld path.

Both come from the same motion plan as URScript and RAPID (:mod:`.plan`). KUKA: positions as E6POS
aggregates in millimetres with A, B, C = rotations about Z, Y', X'' in degrees; ``$TOOL``/``$BASE`` from
TOOL_DATA/BASE_DATA numbers (or the TCP frame); LIN/PTP with C_DIS blending at ``$APO.CDIS`` = the
non-overlapping blend radius. FANUC: /PROG /ATTR /MN /POS /END, UFRAME_NUM/UTOOL_NUM, P[n] with
W, P, R = fixed rotations about X, Y, Z in degrees, L/J motions, FINE at stops and CNT elsewhere.
"""

from __future__ import annotations

import textwrap
from datetime import UTC, datetime

import numpy as np
from pydantic import Field
from scipy.spatial.transform import Rotation
from weldcell.sdk.units import Duration, Length, Speed

from .confdata import plan_configs
from .plan import Motion, ProgramPlan, ProgramSettings, build_plan, check_plan
from .programs import ExportResult


def kuka_abc(T: np.ndarray) -> np.ndarray:
    """KUKA A, B, C (deg): ``R = Rz(A) Ry(B) Rx(C)``."""
    return Rotation.from_matrix(np.asarray(T)[:3, :3]).as_euler("ZYX", degrees=True)


def fanuc_wpr(T: np.ndarray) -> np.ndarray:
    """FANUC W, P, R (deg): fixed-axis rotations about X, then Y, then Z (``R = Rz(R) Ry(P) Rx(W)``)."""
    return Rotation.from_matrix(np.asarray(T)[:3, :3]).as_euler("xyz", degrees=True)


# -- KUKA KRL ------------------------------------------------------------------------------------
class KrlSettings(ProgramSettings):
    program_name: str = Field("weldcell_path", pattern=r"^[A-Za-z]\w{0,23}$", description="DEF and file name")
    tool_number: int | None = Field(
        None,
        ge=1,
        le=16,
        description="TOOL_DATA[n] calibrated on the controller (None: $TOOL from tcp_xyz, "
        "or TOOL_DATA[1] without it)",
    )
    base_number: int = Field(0, ge=0, le=32, description="BASE_DATA[n]; 0 = robot base ($NULLFRAME)")
    weld_speed: Speed = Field(0.01, gt=0, description="welding speed [m/s] (a seam's weld_speed wins)")
    travel_speed: Speed = Field(0.1, gt=0, description="speed to and from the seam [m/s]")
    ptp_percent: int = Field(20, ge=1, le=100, description="axis speed of the first PTP [% of max]")
    blend: Length = Field(0.001, ge=0, description="C_DIS blend radius along the seam [m]")
    arc_output: int = Field(1, ge=1, le=4096, description="$OUT[n] that turns the arc on")
    arc_on_delay: Duration = Field(0.0, ge=0, description="wait after arc on before moving [s]")


def _e6pos(T: np.ndarray, status_turn: tuple[int, int] | None = None) -> str:
    x, y, z = np.asarray(T)[:3, 3] * 1000.0
    a, b, c = kuka_abc(T)
    st = f", S {status_turn[0]}, T {status_turn[1]}" if status_turn is not None else ""
    return f"{{E6POS: X {x:.3f}, Y {y:.3f}, Z {z:.3f}, A {a:.4f}, B {b:.4f}, C {c:.4f}{st}}}"


def _krl_seam(seam, si: int, s: KrlSettings, names: bool, conf) -> tuple[list[str], list[str]]:
    """The seam's subprogram lines and (``names``) its .dat declarations; ``conf`` yields each motion's
    (Status, Turn) or None."""
    body, dat = [f"DEF {seam.routine}( )", f"; seam {seam.id} ({seam.joint})"], []
    for k, m in enumerate(seam.motions):
        target = _e6pos(m.pose, next(conf, None))
        if names:
            name = f"XP{si}_{k}"
            dat.append(f"DECL E6POS {name}={target}")
            target = name
        if m.kind == "joint":
            body += [f"  PTP {target}"]
            continue
        body.append(f"  $VEL.CP = {m.speed:.4f}")
        if m.blend > 0:
            body += [f"  $APO.CDIS = {m.blend * 1000.0:.3f}", f"  LIN {target} C_DIS"]
        else:
            body.append(f"  LIN {target}")
        if m.process in ("arc_start", "arc_end"):
            body.append("  WAIT SEC 0  ; advance-run stop: switch the arc only once the robot is there")
        if m.process == "arc_start":
            body.append(f"  $OUT[{s.arc_output}] = TRUE")
            if s.arc_on_delay > 0:
                body.append(f"  WAIT SEC {s.arc_on_delay:g}")
        elif m.process == "arc_end":
            body.append(f"  $OUT[{s.arc_output}] = FALSE")
    return [*body, "END"], dat


def _krl(plan: ProgramPlan, s: KrlSettings, names: bool) -> tuple[str, str]:
    if s.tool_number is not None or not plan.tcp_given:
        tool = f"TOOL_DATA[{s.tool_number or 1}]"
    else:
        x, y, z = plan.T_flange_tcp[:3, 3] * 1000.0
        a, b, c = kuka_abc(plan.T_flange_tcp)
        tool = f"{{X {x:.3f}, Y {y:.3f}, Z {z:.3f}, A {a:.4f}, B {b:.4f}, C {c:.4f}}}"
    base = f"BASE_DATA[{s.base_number}]" if s.base_number else "$NULLFRAME"
    configs, how = plan_configs(plan, "kuka")
    if configs is not None:
        note = f"S and T {how} (PTP moves to them; LIN keeps the posture it starts in)"
    else:
        note = f"no S and T given ({how}): the robot keeps its current posture (try the first PTP slowly)"
    conf = iter(configs or [])
    head = [f"; {h}" for h in plan.header(note, "TOOL_DATA[1] is used unless tool_number says otherwise")]
    src = [
        "&ACCESS RVP",
        "&REL 1",
        f"DEF {s.program_name}( )",
        *head,
        "  BAS(#INITMOV, 0)",
        f"  $TOOL = {tool}",
        f"  $BASE = {base}",
        "  $ADVANCE = 3",
        f"  BAS(#VEL_PTP, {s.ptp_percent})",
        "  PTP $AXIS_ACT",
        *(f"  {seam.routine}( )" for seam in plan.seams),
        "END",
    ]
    dat = ["&ACCESS RVP", "&REL 1", f"DEFDAT {s.program_name}", *head]
    for si, seam in enumerate(plan.seams):
        body, decl = _krl_seam(seam, si, s, names, conf)
        src += ["", *body]
        dat += decl
    dat.append("ENDDAT")
    return "\n".join(src) + "\n", "\n".join(dat) + "\n"


def _krl_plan(data: dict, s: KrlSettings) -> ProgramPlan:
    plan = build_plan(data, s, s.weld_speed, s.travel_speed, s.blend)
    check_plan(plan, s)
    return plan


def export_krl(data: dict, settings: KrlSettings | None = None) -> ExportResult:
    """A self-contained KRL .src (positions inline), accepted without a .dat."""
    s = settings or KrlSettings()
    plan = _krl_plan(data, s)
    return ExportResult(_krl(plan, s, names=False)[0], plan)


def krl_files(data: dict, settings: KrlSettings | None = None) -> dict[str, str]:
    """The classic pair: ``NAME.src`` (motions by name) and ``NAME.dat`` (the E6POS declarations)."""
    s = settings or KrlSettings()
    src, dat = _krl(_krl_plan(data, s), s, names=True)
    return {f"{s.program_name}.src": src, f"{s.program_name}.dat": dat}


def to_krl(data: dict, settings: KrlSettings | None = None) -> str:
    return export_krl(data, settings).text


# -- FANUC TP ------------------------------------------------------------------------------------
class FanucSettings(ProgramSettings):
    program_name: str = Field("WELDCELL_PATH", pattern=r"^[A-Z][A-Z0-9_]{0,35}$", description="TP program")
    uframe: int = Field(0, ge=0, le=9, description="UFRAME_NUM (0 = world)")
    utool: int = Field(1, ge=1, le=10, description="UTOOL_NUM holding the calibrated torch TCP")
    weld_speed: Speed = Field(0.01, gt=0, description="welding speed [m/s] (a seam's weld_speed wins)")
    travel_speed: Speed = Field(0.1, gt=0, description="speed to and from the seam [m/s]")
    joint_percent: int = Field(20, ge=1, le=100, description="speed of the first joint move [%]")
    blend: Length = Field(0.001, ge=0, description="nominal blend along the seam [m]: CNT scaled by the clip")
    cnt: int = Field(50, ge=1, le=100, description="CNT value at the nominal blend")
    arc: str = Field("arctool", pattern="^(arctool|digital_out)$", description="ArcTool instructions or DO")
    arc_schedule: int = Field(1, ge=1, le=99, description="Arc Start[n] weld schedule")
    arc_output: int = Field(1, ge=1, le=512, description="DO[n] turning the arc on (arc = digital_out)")


def _fanuc_motion(m: Motion, n: int, s: FanucSettings) -> str:
    if m.kind == "joint":
        return f"J P[{n}] {s.joint_percent}% FINE"
    term = "FINE"
    if m.blend > 0 and s.blend > 0:
        term = f"CNT{max(1, min(s.cnt, round(s.cnt * m.blend / s.blend)))}"
    return f"L P[{n}] {max(1, round(m.speed * 1000.0))}mm/sec {term}"


def _fanuc_pos(n: int, T: np.ndarray, s: FanucSettings, config: str | None = None) -> list[str]:
    x, y, z = np.asarray(T)[:3, 3] * 1000.0
    w, p, r = fanuc_wpr(T)
    return [
        f"P[{n}]{{",
        "   GP1:",
        f"\tUF : {s.uframe}, UT : {s.utool},\t\tCONFIG : '{config or 'N U T, 0, 0, 0'}',",
        f"\tX = {x:10.3f}  mm,\tY = {y:10.3f}  mm,\tZ = {z:10.3f}  mm,",
        f"\tW = {w:10.3f} deg,\tP = {p:10.3f} deg,\tR = {r:10.3f} deg",
        "};",
    ]


def export_fanuc(data: dict, settings: FanucSettings | None = None) -> ExportResult:
    """A FANUC TP program (.ls): one labelled block per seam in the planned order, P[n] in /POS."""
    s = settings or FanucSettings()
    plan = build_plan(data, s, s.weld_speed, s.travel_speed, s.blend)
    check_plan(plan, s)
    on = f"Arc Start[{s.arc_schedule}]" if s.arc == "arctool" else f"DO[{s.arc_output}]=ON"
    off = f"Arc End[{s.arc_schedule}]" if s.arc == "arctool" else f"DO[{s.arc_output}]=OFF"
    configs, how = plan_configs(plan, "fanuc")
    if configs is not None:
        note = f"CONFIG {how}"
    else:
        note = f"CONFIG N U T 0 0 0 on every P ({how}), check it matches the robots posture"
    conf = iter(configs or [])
    head = plan.header(note, f"UTOOL {s.utool} must hold the torch TCP")
    notes = [h.replace("'", "").replace(";", ",") for h in head]  # TP comments: no ; or '
    mn = [f"!{part}" for h in notes for part in textwrap.wrap(h, 30)]
    mn += [f"UFRAME_NUM={s.uframe}", f"UTOOL_NUM={s.utool}"]
    pos, n = [], 0
    for li, seam in enumerate(plan.seams, start=1):
        mn.append(f"LBL[{li}:seam {str(seam.id)[:10]}]")
        for m in seam.motions:
            n += 1
            mn.append(_fanuc_motion(m, n, s))
            pos += _fanuc_pos(n, m.pose, s, next(conf, None))
            if m.process == "arc_start":
                mn.append(on)
            elif m.process == "arc_end":
                mn.append(off)
    stamp = datetime.now(UTC)
    date, time = stamp.strftime("%y-%m-%d"), stamp.strftime("%H:%M:%S")
    out = [
        f"/PROG  {s.program_name}",
        "/ATTR",
        "OWNER\t\t= MNEDITOR;",
        'COMMENT\t\t= "weldcell";',
        "PROG_SIZE\t= 0;",
        f"CREATE\t\t= DATE {date}  TIME {time};",
        f"MODIFIED\t= DATE {date}  TIME {time};",
        "FILE_NAME\t= ;",
        "VERSION\t\t= 0;",
        f"LINE_COUNT\t= {len(mn)};",
        "MEMORY_SIZE\t= 0;",
        "PROTECT\t\t= READ_WRITE;",
        "TCD:  STACK_SIZE\t= 0,",
        "      TASK_PRIORITY\t= 50,",
        "      TIME_SLICE\t= 0,",
        "      BUSY_LAMP_OFF\t= 0,",
        "      ABORT_REQUEST\t= 0,",
        "      PAUSE_REQUEST\t= 0;",
        "DEFAULT_GROUP\t= 1,*,*,*,*;",
        "CONTROL_CODE\t= 00000000 00000000;",
        "/MN",
        *(f"{i:4d}:{'' if line[:2] in ('J ', 'L ') else '  '}{line} ;" for i, line in enumerate(mn, start=1)),
        "/POS",
        *pos,
        "/END",
    ]
    return ExportResult("\n".join(out) + "\n", plan)


def to_fanuc(data: dict, settings: FanucSettings | None = None) -> str:
    return export_fanuc(data, settings).text
