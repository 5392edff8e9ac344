"""Grammars (lark) of the subsets of URScript, RAPID, KRL and FANUC TP the exporters emit, and readers that
recover the programmed motions from a parsed program, independently of the exporters' code.

Each reader returns a list of :class:`Read` motions in program order (procedures expanded as main calls
them) with the process events (``arc_on`` / ``arc_off``) attached to the motion they follow, and raises
AssertionError on a rule the controller would refuse (an undeclared name, a bad aggregate, a call to a
routine that does not exist, a blend that is not allowed).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from lark import Lark, Tree
from scipy.spatial.transform import Rotation


@dataclass
class Read:
    kind: str  # joint | linear
    pose: np.ndarray  # 4x4, metres
    speed: float | None  # m/s for linear moves
    blend: float  # m
    events: list[str] = field(default_factory=list)  # arc_on / arc_off after this motion
    config: object = None  # RAPID (cf1, cf4, cf6, cfx); KRL (S, T) or None; TP the CONFIG string


def _T(xyz_m, R) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = xyz_m
    return T


# -- URScript ------------------------------------------------------------------------------------
UR = Lark(
    r"""
    start: COMMENT* "def" NAME "(" ")" ":" body "end" NAME "(" ")"
    body: (funcdef | call | COMMENT)*
    funcdef: "def" NAME "(" ")" ":" body "end"
    call: NAME "(" [arg ("," arg)*] ")"
    arg: NAME "=" value -> kwarg
       | value -> posarg
    value: pose | SIGNED_NUMBER -> number | "True" -> true | "False" -> false
    pose: POSE_OPEN SIGNED_NUMBER ("," SIGNED_NUMBER)~5 "]"
    POSE_OPEN.2: "p["
    COMMENT: /#[^\n]*/
    %import common.CNAME -> NAME
    %import common.SIGNED_NUMBER
    %import common.WS
    %ignore WS
    """,
    parser="lalr",
)
UR_BUILTINS = {"movej", "movel", "movep", "set_tcp", "set_standard_digital_out", "sleep"}


def _ur_value(v: Tree):
    if v.data == "number":
        return float(v.children[0])
    if v.data in ("true", "false"):
        return v.data == "true"
    pose = v.children[0]
    x = np.array([float(t) for t in pose.children[1:]])
    return _T(x[:3], Rotation.from_rotvec(x[3:]).as_matrix())


def read_urscript(text: str, calls: dict[str, str] | None = None) -> tuple[list[Read], np.ndarray | None]:
    """The motions of a URScript program and its set_tcp pose; ``calls`` maps URCap functions to the
    process event they stand for (``{"weld_start": "arc_on"}``)."""
    calls = calls or {}
    tree = UR.parse(text)
    main, body, end_call = tree.children[-3], tree.children[-2], tree.children[-1]
    assert str(main) == str(end_call), "the program must call the function it defines"
    funcs = {str(f.children[0]): f.children[1] for f in body.find_data("funcdef")}
    moves: list[Read] = []
    tcp = [None]

    def run(b: Tree, depth: int = 0) -> None:
        assert depth < 5, "recursive calls"
        for st in b.children:
            if not isinstance(st, Tree) or st.data != "call":
                continue
            name = str(st.children[0])
            args = [a for a in st.children[1:] if a is not None]
            pos = [_ur_value(a.children[0]) for a in args if a.data == "posarg"]
            kw = {str(a.children[0]): _ur_value(a.children[1]) for a in args if a.data == "kwarg"}
            if name in funcs:
                run(funcs[name], depth + 1)
            elif name in ("movej", "movel", "movep"):
                assert set(kw) <= {"a", "v", "r"}, f"{name}: unknown arguments {set(kw)}"
                assert all(kw[k] > 0 for k in ("a", "v")), f"{name} needs a > 0 and v > 0"
                kind = "joint" if name == "movej" else "linear"
                speed = None if kind == "joint" else kw["v"]
                moves.append(Read(kind, pos[0], speed, kw.get("r", 0.0)))
            elif name == "set_tcp":
                tcp[0] = pos[0]
            elif name == "set_standard_digital_out":
                assert 0 <= pos[0] <= 7 and isinstance(pos[1], bool)
                moves[-1].events.append("arc_on" if pos[1] else "arc_off")
            elif name in calls:
                moves[-1].events.append(calls[name])
            else:
                assert name in UR_BUILTINS, f"call to an undefined function {name}()"

    run(body)
    return moves, tcp[0]


# -- ABB RAPID -----------------------------------------------------------------------------------
RAPID = Lark(
    r"""
    start: "MODULE" NAME decl* proc+ "ENDMODULE"
    decl: STORAGE NAME NAME ":=" agg ";"
    STORAGE: "PERS" | "CONST" | "VAR"
    agg: "[" agg ("," agg)* "]" -> list
       | SIGNED_NUMBER -> num
       | /[0-9.]+E[0-9]+/ -> num
       | ESCAPED_STRING -> string
       | "TRUE" -> true
       | "FALSE" -> false
    proc: "PROC" NAME "(" ")" instr* "ENDPROC"
    instr: NAME switch* [arg ("," arg)*] ";"
    arg: NAME option*
    option: "\\" NAME ":=" NAME
    switch: "\\" NAME
    COMMENT: /![^\n]*/
    %import common.CNAME -> NAME
    %import common.SIGNED_NUMBER
    %import common.ESCAPED_STRING
    %import common.WS
    %ignore WS
    %ignore COMMENT
    """,
    parser="lalr",
)
RAPID_PREDEFINED = {"wobj0": "wobjdata", "tool0": "tooldata", "fine": "zonedata"}
RAPID_SIGNATURES = {
    "MoveJ": ("robtarget", "speeddata", "zonedata", "tooldata"),
    "MoveL": ("robtarget", "speeddata", "zonedata", "tooldata"),
    "ArcLStart": ("robtarget", "speeddata", "seamdata", "welddata", "zonedata", "tooldata"),
    "ArcL": ("robtarget", "speeddata", "seamdata", "welddata", "zonedata", "tooldata"),
    "ArcLEnd": ("robtarget", "speeddata", "seamdata", "welddata", "zonedata", "tooldata"),
}
RAPID_SHAPES = {  # nested lengths of the aggregates we declare
    "robtarget": [3, 4, 4, 6],
    "speeddata": 4,
    "zonedata": 7,
    "tooldata": [None, [3, 4], [None, 3, 4, None, None, None]],
    "wobjdata": [None, None, None, [3, 4], [3, 4]],
    "seamdata": [None, None, 9, *[None] * 5, 9, None, None, 9, None, None, 9, None],  # RobotWare 6 Arc
    "welddata": [None, None, 9, 9],
}


def _agg(t: Tree):
    if t.data == "list":
        return [_agg(c) for c in t.children]
    if t.data == "num":
        return float(t.children[0])
    if t.data == "string":
        return str(t.children[0])
    return t.data == "true"


def _shape_ok(value, shape) -> bool:
    if shape is None:
        return not isinstance(value, list)
    if isinstance(shape, int):
        return isinstance(value, list) and len(value) == shape
    return isinstance(value, list) and len(value) == len(shape) and all(map(_shape_ok, value, shape))


def read_rapid(text: str) -> tuple[list[Read], dict[str, tuple[str, object]]]:
    """The motions of a RAPID module (main expanded) and its declarations ``{name: (type, value)}``."""
    tree = RAPID.parse(text)
    decls: dict[str, tuple[str, object]] = {}
    for d in tree.find_data("decl"):
        _, typ, name, agg = d.children
        assert str(name) not in decls, f"{name} declared twice"
        value = _agg(agg)
        assert _shape_ok(value, RAPID_SHAPES.get(str(typ))), f"{typ} {name} has a malformed aggregate {value}"
        decls[str(name)] = (str(typ), value)
    procs = {str(p.children[0]): p.children[1:] for p in tree.find_data("proc")}
    assert "main" in procs, "no PROC main()"
    switches: list[str] = []
    moves: list[Read] = []

    def typ(name: str) -> str:
        if name in decls:
            return decls[name][0]
        assert name in RAPID_PREDEFINED, f"{name} is used but never declared"
        return RAPID_PREDEFINED[name]

    def run(name: str, depth: int = 0) -> None:
        assert depth < 5
        for ins in procs[name]:
            op = str(ins.children[0])
            sw = [str(s.children[0]) for s in ins.children[1:] if isinstance(s, Tree) and s.data == "switch"]
            args = [a for a in ins.children[1:] if isinstance(a, Tree) and a.data == "arg"]
            if op in procs:
                run(op, depth + 1)
                continue
            if op in ("ConfL", "ConfJ"):
                assert sw in (["Off"], ["On"]) and not args
                switches.append(f"{op}\\{sw[0]}")
                continue
            assert op in RAPID_SIGNATURES, f"unknown instruction {op}"
            names = [str(a.children[0]) for a in args]
            want = RAPID_SIGNATURES[op]
            assert len(names) == len(want), f"{op} takes {len(want)} arguments, got {names}"
            for n, w in zip(names, want, strict=True):
                assert typ(n) == w, f"{op}: {n} is a {typ(n)}, expected {w}"
            for opt in args[-1].children[1:]:
                assert str(opt.children[0]) == "WObj" and typ(str(opt.children[1])) == "wobjdata"
            (xyz, q, cf, _ext) = decls[names[0]][1]
            monitored = switches[-1:] == ["ConfL\\On"] and "ConfJ\\On" in switches
            if not monitored:  # without configuration monitoring the confdata means nothing
                assert "ConfL\\Off" in switches, "linear moves before ConfL\\Off"
            assert all(float(v).is_integer() for v in cf) and 0 <= cf[3] <= 7, f"bad confdata {cf}"
            assert abs(np.linalg.norm(q) - 1.0) < 1e-5, f"{names[0]}: quaternion not normalised"
            R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
            zone = names[-2]
            blend = 0.0 if zone == "fine" else decls[zone][1][1] / 1000.0
            if op.startswith("Arc"):
                speed = decls[names[3]][1][0] / 1000.0  # welddata weld_speed (mm/s) drives the weld
                if op == "ArcLStart":
                    speed = decls[names[1]][1][0] / 1000.0  # to the start: the speeddata
            else:
                speed = decls[names[1]][1][0] / 1000.0
            kind = "joint" if op == "MoveJ" else "linear"
            config = tuple(int(v) for v in cf) if monitored else None
            moves.append(Read(kind, _T(np.array(xyz) / 1000.0, R), speed, blend, config=config))
            if op == "ArcLStart":
                moves[-1].events.append("arc_on")
            elif op == "ArcLEnd":
                moves[-1].events.append("arc_off")

    run("main")
    return moves, decls


# -- KUKA KRL ------------------------------------------------------------------------------------
KRL = Lark(
    r"""
    start: HEADER* routine+
    routine: "DEF" NAME "(" ")" stmt* "END"
    stmt: "BAS" "(" "#" NAME "," SIGNED_NUMBER ")" -> bas
        | SYSVAR "=" rhs -> assign
        | "PTP" target -> ptp
        | "LIN" target C_DIS? -> lin
        | "WAIT" "SEC" SIGNED_NUMBER -> wait
        | NAME "(" ")" -> call
    rhs: SIGNED_NUMBER -> num | "TRUE" -> true | "FALSE" -> false | frame | SYSVAR -> sysref
       | NAME "[" INT "]" -> indexed
    target: frame | SYSVAR -> sysref | NAME -> ref
    frame: "{" (TYPE ":")? comp ("," comp)* "}"
    comp: NAME SIGNED_NUMBER
    TYPE.2: "E6POS" | "FRAME"
    C_DIS: "C_DIS"
    SYSVAR: /\$[A-Z_]+(\.[A-Z0-9_]+)?(\[\d+\])?/
    HEADER: /&[^\n]*/
    COMMENT: /;[^\n]*/
    %import common.CNAME -> NAME
    %import common.SIGNED_NUMBER
    %import common.INT
    %import common.WS
    %ignore WS
    %ignore COMMENT
    """,
    parser="lalr",
)
KRL_DAT = Lark(
    r"""
    start: HEADER* "DEFDAT" NAME decl* "ENDDAT"
    decl: "DECL" "E6POS" NAME "=" frame
    frame: "{" "E6POS" ":" comp ("," comp)* "}"
    comp: NAME SIGNED_NUMBER
    HEADER: /&[^\n]*/
    COMMENT: /;[^\n]*/
    %import common.CNAME -> NAME
    %import common.SIGNED_NUMBER
    %import common.WS
    %ignore WS
    %ignore COMMENT
    """,
    parser="lalr",
)


def _krl_frame(t: Tree) -> np.ndarray:
    return _krl_pos(t)[0]


def _krl_pos(t: Tree) -> tuple[np.ndarray, tuple[int, int] | None]:
    """The pose of a KRL frame/E6POS aggregate and its (S, T) when given."""
    comps = {str(c.children[0]): float(c.children[1]) for c in t.find_data("comp")}
    assert set(comps) in (set("XYZABC"), set("XYZABCST")), f"frame components {set(comps)}"
    R = Rotation.from_euler("ZYX", [comps["A"], comps["B"], comps["C"]], degrees=True).as_matrix()
    st = None
    if "S" in comps:
        st = (int(comps["S"]), int(comps["T"]))
        assert 0 <= st[0] <= 7 and 0 <= st[1] <= 63 and all(float(comps[k]).is_integer() for k in "ST")
    return _T(np.array([comps["X"], comps["Y"], comps["Z"]]) / 1000.0, R), st


def read_krl(src: str, dat: str | None = None) -> tuple[list[Read], np.ndarray | None]:
    """The motions of a KRL .src (names resolved in ``dat`` when given) and the $TOOL frame."""
    tree = KRL.parse(src)
    names: dict[str, tuple] = {}
    if dat is not None:
        for d in KRL_DAT.parse(dat).find_data("decl"):
            names[str(d.children[0])] = _krl_pos(d.children[1])
    routines = {str(r.children[0]): r.children[1:] for r in tree.children if isinstance(r, Tree)}
    first = next(r for r in tree.children if isinstance(r, Tree))
    state = {"vel": None, "cdis": 0.0, "tool": None, "bco": False}
    moves: list[Read] = []

    def target(t: Tree):
        if t.data == "ref":
            assert str(t.children[0]) in names, f"{t.children[0]} is not declared in the .dat"
            return names[str(t.children[0])]
        if t.data == "sysref":
            return None, None
        return _krl_pos(t)

    def run(name: str, depth: int = 0) -> None:
        assert depth < 5
        body = routines[name]
        for k, st in enumerate(body):
            prev = body[k - 1] if k else None
            if st.data == "call":
                assert str(st.children[0]) in routines, f"call to an undefined routine {st.children[0]}"
                run(str(st.children[0]), depth + 1)
            elif st.data == "assign":
                var, rhs = str(st.children[0]), st.children[1]
                if var == "$VEL.CP":
                    state["vel"] = float(rhs.children[0])
                    assert 0 < state["vel"] <= 2.0, "$VEL.CP is in m/s"
                elif var == "$APO.CDIS":
                    state["cdis"] = float(rhs.children[0]) / 1000.0
                elif var == "$TOOL":
                    f = rhs.children[0] if rhs.data == "rhs" else rhs
                    state["tool"] = _krl_frame(f) if isinstance(f, Tree) and f.data == "frame" else None
                elif var.startswith("$OUT["):
                    assert prev is not None and prev.data == "wait", "$OUT set in the advance run"
                    moves[-1].events.append("arc_on" if rhs.data == "true" else "arc_off")
            elif st.data == "ptp":
                T, st_bits = target(st.children[0])
                if T is None:
                    state["bco"] = True
                else:
                    assert state["bco"], "the first motion must be a PTP to a full position (BCO run)"
                    moves.append(Read("joint", T, None, 0.0, config=st_bits))
            elif st.data == "lin":
                assert state["bco"] and state["vel"] is not None, "LIN before BCO or without $VEL.CP"
                blend = state["cdis"] if len(st.children) > 1 else 0.0
                T, st_bits = target(st.children[0])
                moves.append(Read("linear", T, state["vel"], blend, config=st_bits))

    run(str(first.children[0]))
    return moves, state["tool"]


# -- FANUC TP ------------------------------------------------------------------------------------
TP = Lark(
    r"""
    start: "/PROG" NAME attr "/MN" line* "/POS" pos* "/END"
    attr: "/ATTR" ATTRLINE*
    ATTRLINE: /(?!\/)[^\n]+/
    line: INT ":" instr ";"
    instr: "J" preg INT "%" TERM -> joint
         | "L" preg INT "mm/sec" TERM -> linear
         | "!" COMMENTTEXT -> comment
         | NAME "=" INT -> assign
         | "LBL" "[" INT ":" /[^\]]+/ "]" -> label
         | "Arc" "Start" "[" INT "]" -> arc_on
         | "Arc" "End" "[" INT "]" -> arc_off
         | "DO" "[" INT "]" "=" ONOFF -> do
    preg: "P" "[" INT "]"
    TERM: "FINE" | /CNT\d+/
    ONOFF: "ON" | "OFF"
    COMMENTTEXT: /[^;\n]+/
    pos: "P" "[" INT "]" "{" "GP1" ":" frames "CONFIG" ":" CONFIG "," coords "}" ";"
    frames: "UF" ":" INT "," "UT" ":" INT ","
    coords: coord~6
    coord: NAME "=" SIGNED_NUMBER UNIT ","?
    UNIT: "mm" | "deg"
    CONFIG: /'[NF] [UD] [TB], -?\d+, -?\d+, -?\d+'/
    %import common.CNAME -> NAME
    %import common.INT
    %import common.SIGNED_NUMBER
    %import common.WS
    %ignore WS
    """,
    parser="lalr",
)


def read_tp(text: str) -> tuple[list[Read], dict[str, int]]:
    """The motions of a FANUC .ls program and its UFRAME_NUM / UTOOL_NUM."""
    tree = TP.parse(text)
    points: dict[int, np.ndarray] = {}
    configs: dict[int, str] = {}
    for p in tree.find_data("pos"):
        n = int(p.children[0])
        c = {str(k.children[0]): float(k.children[1]) for k in p.find_data("coord")}
        R = Rotation.from_euler("xyz", [c["W"], c["P"], c["R"]], degrees=True).as_matrix()
        points[n] = _T(np.array([c["X"], c["Y"], c["Z"]]) / 1000.0, R)
        configs[n] = next(str(t) for t in p.children if getattr(t, "type", "") == "CONFIG").strip("'")
    frames: dict[str, int] = {}
    moves: list[Read] = []
    expect = 1
    for line in tree.find_data("line"):
        assert int(line.children[0]) == expect, "line numbers must count up from 1"
        expect += 1
        ins = line.children[1]
        if ins.data in ("joint", "linear"):
            n = int(ins.children[0].children[0])
            assert n in points, f"P[{n}] has no /POS entry"
            term = str(ins.children[2])
            blend = 0.0 if term == "FINE" else float(term[3:])  # CNT value, not a distance
            speed = float(ins.children[1]) / 1000.0 if ins.data == "linear" else None
            kind = "joint" if ins.data == "joint" else "linear"
            moves.append(Read(kind, points[n], speed, blend, config=configs[n]))
        elif ins.data in ("arc_on", "arc_off"):
            moves[-1].events.append(ins.data)
        elif ins.data == "do":
            moves[-1].events.append("arc_on" if str(ins.children[1]) == "ON" else "arc_off")
        elif ins.data == "assign":
            frames[str(ins.children[0])] = int(ins.children[1])
    assert {"UFRAME_NUM", "UTOOL_NUM"} <= set(frames), "UFRAME_NUM and UTOOL_NUM must be set"
    count = [a for a in tree.find_data("attr")][0]
    lc = [str(t) for t in count.children if str(t).startswith("LINE_COUNT")]
    assert lc and int(lc[0].split("=")[1].strip(" ;")) == expect - 1, "LINE_COUNT does not match /MN"
    return moves, frames
