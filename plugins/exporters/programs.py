"""Turn a ``weldcell/weld-path@1`` document into robot programs: URScript, ABB RAPID, CSV and JSON.

URScript poses are ``p[x, y, z, rx, ry, rz]`` in metres and a rotation vector (the robot base frame);
RAPID robtargets are millimetres and quaternions ``[q1, q2, q3, q4] = [w, x, y, z]``. Both programs
come from one motion plan (:mod:`.plan`): reduced poses, non-overlapping blends, approach and retract,
arc on/off, one procedure per seam and a main calling them in the planned order (docs/exporters.md).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
from pydantic import Field
from weldcell.sdk.artifacts import dumps
from weldcell.sdk.geometry import T_to_pose7, T_to_ur_pose
from weldcell.sdk.settings import Settings
from weldcell.sdk.units import AngularAcceleration, AngularSpeed, Duration, Length, Speed
from weldcell.sdk.weldpath import WeldPath

from .confdata import plan_configs
from .plan import ProgramPlan, ProgramSettings, build_plan, check_plan


@dataclass(frozen=True)
class ExportResult:
    """A program's text and the plan it was written from (achieved deviation, checks, skipped seams)."""

    text: str
    plan: ProgramPlan


# -- URScript ------------------------------------------------------------------------------------
class URScriptSettings(ProgramSettings):
    tool_speed: Speed = Field(0.01, gt=0, description="welding travel speed [m/s] (a seam's weld_speed wins)")
    approach_speed: Speed = Field(0.1, gt=0, description="speed to and from the seam [m/s]")
    joint_speed: AngularSpeed = Field(0.5, gt=0, description="joint speed of the first movej [rad/s]")
    joint_accel: AngularAcceleration = Field(1.0, gt=0, description="joint acceleration of movej [rad/s^2]")
    blend: Length = Field(
        0.001, ge=0, description="blend radius along the seam [m], clipped to 45 % of the shorter segment"
    )
    program_name: str = Field("weldcell_path", pattern=r"^[A-Za-z]\w*$", description="URScript function name")
    use_movep: bool = Field(True, description="movep (constant tool speed) along the seam; movel otherwise")
    arc_output: int | None = Field(
        0, ge=0, le=7, description="standard digital output that turns the arc on (None: use the calls)"
    )
    arc_on_call: str | None = Field(None, description="URCap call that starts the arc, e.g. 'weld_start()'")
    arc_off_call: str | None = Field(None, description="URCap call that ends the arc, e.g. 'weld_end()'")
    arc_on_delay: Duration = Field(0.0, ge=0, description="wait after arc on before moving [s]")


def _ur_p(T: np.ndarray) -> str:
    return "p[" + ", ".join(f"{v:.6f}" for v in T_to_ur_pose(T)) + "]"


def _ur_arc(s: URScriptSettings, on: bool) -> list[str]:
    call = s.arc_on_call if on else s.arc_off_call
    if call:
        out = [call]
    elif s.arc_output is not None:
        out = [f"set_standard_digital_out({s.arc_output}, {'True' if on else 'False'})"]
    else:
        return []
    if on and s.arc_on_delay > 0:
        out.append(f"sleep({s.arc_on_delay:g})")
    return out


def export_urscript(data: dict, settings: URScriptSettings | None = None) -> ExportResult:
    """A URScript program: set_tcp, one function per seam (approach, arc on, weld, arc off, retract)."""
    s = settings or URScriptSettings()
    plan = build_plan(data, s, s.tool_speed, s.approach_speed, s.blend)
    check_plan(plan, s)
    a = f"{s.accel:g}"
    note = "the controller picks the IK solution closest to the current joints (movej/movel to poses)"
    lines = [f"# {h}" for h in plan.header(note, "the TCP active in the installation is used")]
    lines.append(f"def {s.program_name}():")
    if plan.tcp_given:  # else keep the installation's TCP: a zero TCP would weld with the flange
        lines.append(f"  set_tcp({_ur_p(plan.T_flange_tcp)})")
    for seam in plan.seams:
        lines.append(f"  # seam {seam.id} ({seam.joint}, {seam.length * 1000:.1f} mm)")
        lines.append(f"  def {seam.routine}():")
        for m in seam.motions:
            if m.kind == "joint":
                lines.append(f"    movej({_ur_p(m.pose)}, a={s.joint_accel:g}, v={s.joint_speed:g})")
            elif m.process in ("weld", "arc_end") and s.use_movep:
                lines.append(f"    movep({_ur_p(m.pose)}, a={a}, v={m.speed:g}, r={m.blend:.6g})")
            else:
                lines.append(f"    movel({_ur_p(m.pose)}, a={a}, v={m.speed:g}, r={m.blend:.6g})")
            if m.process == "arc_start":
                lines += [f"    {c}" for c in _ur_arc(s, True)]
            elif m.process == "arc_end":
                lines += [f"    {c}" for c in _ur_arc(s, False)]
        lines.append("  end")
    lines += [f"  {seam.routine}()" for seam in plan.seams]
    lines += ["end", f"{s.program_name}()"]
    return ExportResult("\n".join(lines) + "\n", plan)


def to_urscript(data: dict, settings: URScriptSettings | None = None) -> str:
    """The URScript program's text (see :func:`export_urscript`)."""
    return export_urscript(data, settings).text


NAME = r"^[A-Za-z]\w{0,31}$"  # a RAPID identifier


# -- ABB RAPID -----------------------------------------------------------------------------------
class RapidSettings(ProgramSettings):
    module_name: str = Field("WeldcellPath", pattern=NAME, description="RAPID module name")
    tool: str = Field("tWeldGun", pattern=NAME, description="tooldata declared in the module")
    tool_mass: float = Field(1.5, gt=0, description="torch mass for the tooldata [kg]")
    wobj: str = Field("wobj0", pattern=NAME, description="wobjdata (declared unless wobj0)")
    speed: str = Field("vWeld", pattern=NAME, description="speeddata name along the seam")
    approach_speed: str = Field("vApproach", pattern=NAME, description="speeddata to/from")
    weld_speed: Speed = Field(0.01, gt=0, description="welding speed [m/s] (a seam's weld_speed wins)")
    travel_speed: Speed = Field(0.1, gt=0, description="speed to and from the seam [m/s]")
    zone: str = Field("z1", pattern=r"^z\d+(\.\d+)?$|^fine$", description="zone; its radius is the blend")
    blend: Length | None = Field(None, ge=0, description="blend radius along the seam [m] (default: zone's)")
    seamdata: str = Field("smWeld", pattern=NAME, description="seamdata name")
    welddata: str = Field("wdWeld", pattern=r"^[A-Za-z]\w{0,23}$", description="welddata name prefix")
    purge_time: Duration = Field(0.5, ge=0, description="gas purge time in the seamdata [s]")
    preflow_time: Duration = Field(0.5, ge=0, description="gas preflow time in the seamdata [s]")
    weld_schedule: int = Field(1, ge=0, description="power-source schedule number in the welddata")


def _blend_of(s: RapidSettings) -> float:
    if s.blend is not None:
        return s.blend
    return 0.0 if s.zone == "fine" else float(s.zone[1:]) / 1000.0


def _zone_mm(blend: float) -> float:
    """The zone radius in mm, rounded down to 0.01 mm (never over the non-overlap bound)."""
    return math.floor(blend * 1e5 + 1e-6) / 100.0


def _speeddata(mm_s: float) -> str:
    return f"[{mm_s:.1f},30,200,15]"


def export_rapid(data: dict, settings: RapidSettings | None = None) -> ExportResult:
    """An ABB RAPID module with declared tool, work object, speed, zone, seam and weld data; one PROC per
    seam (MoveJ/MoveL approach, ArcLStart/ArcL/ArcLEnd weld, MoveL retract) and a main calling them."""
    s = settings or RapidSettings()
    plan = build_plan(data, s, s.weld_speed, s.travel_speed, _blend_of(s))
    check_plan(plan, s)
    decl, zones = _rapid_declarations(plan, s)
    configs, how = plan_configs(plan, "abb")
    conf = iter(configs or [])
    targets, procs = [], []
    for si, seam in enumerate(plan.seams):
        procs += _rapid_seam(si, seam, s, zones, conf, decl, targets)
    if configs is not None:
        head = plan.header(f"confdata {how}; configuration monitoring on")
        conf_note = [
            "    ! ConfJ\\On / ConfL\\On: each robtarget's confdata [cf1,cf4,cf6,cfx] is the configuration",
            "    ! the path was checked with; the robot stops rather than run another configuration.",
        ]
        switch = "On"
    else:
        head = plan.header(f"confdata not computed ({how}); configuration monitoring off")
        conf_note = [
            "    ! ConfL\\Off / ConfJ\\Off: robtargets carry no computed confdata; the robot keeps the",
            "    ! configuration closest to its current one. Run the program once in manual reduced speed.",
        ]
        switch = "Off"
    out = [
        f"MODULE {s.module_name}",
        *(f"    ! {h}" for h in head),
        *conf_note,
        *decl,
        *targets,
        "",
        "    PROC main()",
        f"        ConfJ\\{switch};",
        f"        ConfL\\{switch};",
        *(f"        {seam.routine};" for seam in plan.seams),
        "    ENDPROC",
        "",
        *procs,
        "ENDMODULE",
    ]
    return ExportResult("\n".join(out) + "\n", plan)


def _rapid_declarations(plan, s: RapidSettings) -> tuple[list[str], dict[float, str]]:
    """The module's tool, work object, speed, zone and seam data; the zone name of each blend (mm)."""
    x, y, z, qx, qy, qz, qw = T_to_pose7(plan.T_flange_tcp)
    cog_z = 0.5 * z * 1000.0
    decl = [
        f"    PERS tooldata {s.tool} := [TRUE,[[{x * 1000:.3f},{y * 1000:.3f},{z * 1000:.3f}],"
        f"[{qw:.7f},{qx:.7f},{qy:.7f},{qz:.7f}]],[{s.tool_mass:g},[0,0,{cog_z:.1f}],[1,0,0,0],0,0,0]];",
    ]
    if s.wobj != "wobj0":
        frame = "[[0,0,0],[1,0,0,0]]"
        decl.append(f'    PERS wobjdata {s.wobj} := [FALSE,TRUE,"",{frame},{frame}];')
    decl.append(f"    CONST speeddata {s.approach_speed} := {_speeddata(s.travel_speed * 1000)};")
    decl.append(f"    CONST speeddata {s.speed} := {_speeddata(s.weld_speed * 1000)};")
    zones: dict[float, str] = {}
    for m in plan.motions:
        if _zone_mm(m.blend) > 0:
            zones.setdefault(_zone_mm(m.blend), f"zW{len(zones)}")
    for r, name in zones.items():
        o = f"{0.1 * r:.3g}"
        decl.append(f"    CONST zonedata {name} := [FALSE,{r:g},{r:g},{r:g},{o},{r:g},{o}];")
    decl.append(
        f"    PERS seamdata {s.seamdata} := [{s.purge_time:g},{s.preflow_time:g},{_ZERO9},0,0,0,0,0,"
        f"{_ZERO9},0,0,{_ZERO9},0,0,{_ZERO9},0];"
    )
    return decl, zones


_ZERO9 = "[0,0,0,0,0,0,0,0,0]"


def _rapid_seam(si: int, seam, s: RapidSettings, zones: dict[float, str], conf, decl: list, targets: list):
    """One seam's PROC (returned, with an empty line after it); its welddata goes to ``decl``, its
    robtargets (with the next confdata of ``conf``) to ``targets``."""
    wd = f"{s.welddata}_{si}"
    decl.append(
        f"    PERS welddata {wd} := [{seam.weld_speed * 1000:.1f},0,"
        f"[{s.weld_schedule},0,0,0,0,0,0,0,0],{_ZERO9}];"
    )
    proc = seam.routine
    body = [f"    ! seam {seam.id} ({seam.joint}, {seam.length * 1000:.1f} mm)", f"    PROC {proc}()"]
    tool, arc = f"{s.tool}\\WObj:={s.wobj}", f"{s.seamdata}, {wd}"
    for k, m in enumerate(seam.motions):
        name = f"p{si}_{k}"
        px, py, pz, ax, ay, az, aw = T_to_pose7(m.pose)
        cf = ",".join(str(v) for v in next(conf, (0, 0, 0, 0)))
        targets.append(
            f"    CONST robtarget {name} := [[{px * 1000:.3f},{py * 1000:.3f},{pz * 1000:.3f}],"
            f"[{aw:.7f},{ax:.7f},{ay:.7f},{az:.7f}],[{cf}],[9E9,9E9,9E9,9E9,9E9,9E9]];"
        )
        zone = zones[_zone_mm(m.blend)] if _zone_mm(m.blend) > 0 else "fine"
        if m.kind == "joint":
            body.append(f"        MoveJ {name}, {s.approach_speed}, fine, {tool};")
        elif m.process == "arc_start":
            body.append(f"        ArcLStart {name}, {s.approach_speed}, {arc}, fine, {tool};")
        elif m.process == "weld":
            body.append(f"        ArcL {name}, {s.speed}, {arc}, {zone}, {tool};")
        elif m.process == "arc_end":
            body.append(f"        ArcLEnd {name}, {s.speed}, {arc}, fine, {tool};")
        else:
            body.append(f"        MoveL {name}, {s.approach_speed}, fine, {tool};")
    return [*body, "    ENDPROC", ""]


def to_rapid(data: dict, settings: RapidSettings | None = None) -> str:
    """The RAPID module's text (see :func:`export_rapid`)."""
    return export_rapid(data, settings).text


# -- tables --------------------------------------------------------------------------------------
class CsvSettings(Settings):
    units: str = Field("mm", pattern="^(mm|m)$", description="position units in the table")


def to_csv(data: dict, settings: CsvSettings | None = None) -> str:
    """``seam,index,x,y,z,qx,qy,qz,qw`` with positions in the chosen units (every planned pose)."""
    s = settings or CsvSettings()
    path = WeldPath.from_json(data)
    scale = 1000.0 if s.units == "mm" else 1.0
    buf = io.StringIO()
    buf.write(f"seam,index,x_{s.units},y_{s.units},z_{s.units},qx,qy,qz,qw\n")
    for seam in path.seams:
        for i, T in enumerate(seam.poses):
            x, y, z, qx, qy, qz, qw = T_to_pose7(T)
            buf.write(
                f"{seam.id},{i},{x * scale:.4f},{y * scale:.4f},{z * scale:.4f},"
                f"{qx:.7f},{qy:.7f},{qz:.7f},{qw:.7f}\n"
            )
    return buf.getvalue()


def to_json(data: dict, settings=None) -> str:
    """The validated weld-path document as JSON text."""
    return dumps(WeldPath.from_json(data).to_json()) + "\n"


__all__ = [
    "CsvSettings",
    "ExportResult",
    "RapidSettings",
    "URScriptSettings",
    "export_rapid",
    "export_urscript",
    "to_csv",
    "to_json",
    "to_rapid",
    "to_urscript",
]
