"""Generate docs/profile-reference.md: every key a cell profile accepts, from the code itself.

Walks the profile's own tables (``weldcell.sdk.profile``, ``weldcell.sdk.cell``) and everything the
installed first-party plugins register (jobs, devices, stages, exporters), and writes one table per
settings model: key, type, default, SI unit and description. Units come from the unit-aware types of
``weldcell.sdk.units`` (their JSON schema carries ``"unit"``).

    python docs/gen_profile_reference.py            rewrite docs/profile-reference.md
    python docs/gen_profile_reference.py --check    exit 1 when the file is out of date

Only plugins of the ``weldcell`` distribution are documented (so the page does not depend on which
third-party plugins happen to be installed) unless ``--all`` is given; ``WELDCELL_DISABLE_PLUGINS`` is
ignored. The output is deterministic: everything is sorted by name.
"""

from __future__ import annotations

import argparse
import difflib
import os
import sys
import types
import typing
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

OUT = Path(__file__).resolve().parent / "profile-reference.md"
NOTE = "<!-- GENERATED: do not edit; run `python docs/gen_profile_reference.py` to rewrite this file -->"
CONSTRAINTS = (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤"))


# -- types, units, defaults -----------------------------------------------------------------------
def _unit_of(metadata: list) -> tuple[str, str] | None:
    """(dimension, SI unit) of a unit-aware type's metadata, else None."""
    for m in metadata:
        schema = getattr(m, "json_schema", None)
        if isinstance(schema, dict) and "unit" in schema:
            return schema.get("dimension", "quantity").replace("_", " "), schema["unit"]
    return None


def _constraints(metadata: list) -> str:
    out = []
    for m in metadata:
        for attr, sym in CONSTRAINTS:
            v = getattr(m, attr, None)
            if v is not None:
                out.append(f"{sym} {v:g}" if isinstance(v, int | float) else f"{sym} {v}")
        pattern = getattr(m, "pattern", None)
        if pattern:
            out.append(f"matching `{pattern}`")
    return ", ".join(out)


def describe_type(annotation: Any, metadata: list | None = None) -> tuple[str, list[str]]:
    """A readable type and the SI units it carries (``("(length, length, length)", ["m"])``)."""
    metadata = list(metadata or [])
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        base, *extra = typing.get_args(annotation)
        return describe_type(base, [*extra, *metadata])
    unit = _unit_of(metadata)
    if unit is not None:
        return unit[0], [unit[1]]
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        parts = [describe_type(a) for a in args]
        units = [u for _, us in parts for u in us]
        text = " or ".join(t for t, _ in parts)
        if len(args) < len(typing.get_args(annotation)):
            text += " or none"
        return text, units
    if origin is Literal:
        return "one of " + ", ".join(
            f'"{a}"' if isinstance(a, str) else str(a) for a in typing.get_args(annotation)
        ), []
    if origin is tuple:
        args = typing.get_args(annotation)
        if len(args) == 2 and args[1] is Ellipsis:
            inner, units = describe_type(args[0])
            return f"list of {inner}", units
        parts = [describe_type(a) for a in args]
        units = [u for _, us in parts for u in us]
        return "(" + ", ".join(t for t, _ in parts) + ")", units
    if origin is list:
        (arg,) = typing.get_args(annotation) or (Any,)
        if isinstance(arg, type) and issubclass(arg, BaseModel):
            return "array of tables", []
        inner, units = describe_type(arg)
        return f"list of {inner}", units
    if origin is dict:
        return "table", []
    names = {bool: "bool", int: "int", float: "float", str: "string", type(None): "none"}
    if annotation in names:
        return names[annotation], []
    if annotation is Any:
        return "any", []
    return getattr(annotation, "__name__", str(annotation)), []


def _unique(units: list[str]) -> str:
    return ", ".join(dict.fromkeys(units))


def toml_value(v: Any) -> str:
    """A default written the way a profile would write it."""
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + "}" if v else "{}"
    if isinstance(v, BaseModel):
        return "(table)"
    return str(v)


def _default(f: FieldInfo) -> str:
    if f.default is PydanticUndefined and f.default_factory is None:
        return "**required**"
    value = f.default_factory() if f.default_factory is not None else f.default
    return toml_value(value)


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _is_model(annotation: Any) -> bool:
    return isinstance(annotation, type) and issubclass(annotation, BaseModel)


def settings_rows(model: type[BaseModel], prefix: str = "", skip: tuple[str, ...] = ()) -> list[list[str]]:
    """Rows (key, type, default, unit, description); nested settings models become dotted keys."""
    rows = []
    for name, f in model.model_fields.items():
        if name in skip:
            continue
        key = prefix + (f.alias or name)
        if _is_model(f.annotation):
            rows.extend(settings_rows(f.annotation, key + "."))
            continue
        optional_model = [a for a in typing.get_args(f.annotation) if _is_model(a)]
        if optional_model:  # e.g. ``intrinsics: IntrinsicsBlock | None``: the table, then its keys
            rows.append([f"`{key}`", "table or none", f"`{_default(f)}`", "", f.description or ""])
            rows.extend(settings_rows(optional_model[0], key + "."))
            continue
        type_text, units = describe_type(f.annotation, f.metadata)
        cons = _constraints(f.metadata)
        if cons:
            type_text += f" ({cons})"
        default = _default(f)
        default = default if default == "**required**" else f"`{default}`"
        rows.append([f"`{key}`", type_text, default, _unique(units) or "", f.description or ""])
    return rows


def table(model: type[BaseModel], skip: tuple[str, ...] = ()) -> list[str]:
    rows = settings_rows(model, skip=skip)
    if not rows:
        return ["No settings.", ""]
    out = ["| key | type | default | unit | description |", "|---|---|---|---|---|"]
    out += ["| " + " | ".join(_cell(c) for c in r) + " |" for r in rows]
    return [*out, ""]


# -- the page -------------------------------------------------------------------------------------
def profile_section() -> list[str]:
    from weldcell.sdk.cell import CellSettings, SafetyLimits
    from weldcell.sdk.profile import (
        SCHEMA,
        DeviceEntry,
        JobEntry,
        Mount,
        OutputSettings,
        Profile,
        SimSection,
        StageEntry,
        WorkpiecePlacement,
    )

    top = ("job", "cell", "devices", "stages", "calibration", "sim", "output")
    out = [
        "## The profile's own tables",
        "",
        f'A profile is a TOML file with `schema = "{SCHEMA}"`. Every table refuses unknown keys. '
        "Lengths, angles, speeds, ... may be plain numbers in SI units or strings with a unit "
        '(`"15 mm"`, `"30 deg"`, `"250 mm/s"`); the *unit* column gives the SI unit of a plain number.',
        "",
        "### Top level",
        "",
        *table(Profile, skip=top),
    ]
    out += [
        "### [job]",
        "",
        "The job this cell runs. `settings` is checked against the job's settings model (see [Jobs](#jobs)).",
        "",
        *table(JobEntry),
    ]
    out += ["### [cell]", "", *table(CellSettings, skip=("safety",))]
    out += [
        "### [cell.safety]",
        "",
        "Checked by the safety gate before every motion command (docs/safety.md).",
        "",
        *table(SafetyLimits),
    ]
    out += [
        "### [devices.\\<role\\>]",
        "",
        "One table per device role of the job (the roles are listed under "
        "[Jobs](#jobs)). `settings` is checked against the device plugin's settings model "
        "(see [Devices](#devices)).",
        "",
        *table(DeviceEntry, skip=("mount",)),
    ]
    out += ["### [devices.\\<role\\>.mount]", "", *table(Mount)]
    out += [
        "### [stages.\\<role\\>]",
        "",
        "One table per stage role of the job; a role left out uses the job's "
        "default plugin with default settings (see [Stages](#stages)).",
        "",
        *table(StageEntry),
    ]
    out += [
        "### [calibration]",
        "",
        "Names mapped to files, relative to the profile file that names them; every file must exist when "
        "the profile is validated. The `scan-and-plan` job reads `hand_eye` (a `weldcell/hand-eye@1` file "
        "whose `T` is `T_flange_camera`).",
        "",
        "| key | type | default | unit | description |",
        "|---|---|---|---|---|",
        '| `<name>` | string | | | path of a calibration file, e.g. `hand_eye = "calib/handeye.json"` |',
        "",
    ]
    out += [
        "### [sim]",
        "",
        "The scene of the simulated cell; ignored by hardware devices.",
        "",
        *table(SimSection, skip=("workpieces",)),
    ]
    out += ["### [[sim.workpieces]]", "", *table(WorkpiecePlacement)]
    out += ["### [output]", "", *table(OutputSettings)]
    return out


def plugin_sections(pm, first_party_only: bool) -> list[str]:
    reg = pm.registry

    def keep(entry) -> bool:
        return not first_party_only or entry.provider.distribution == "weldcell"

    out = ["## Jobs", ""]
    for e in reg.all("job"):
        if not keep(e):
            continue
        j = e.descriptor
        out += [
            f"### job `{j.name}`",
            "",
            f"{j.summary} (plugin `{e.provider.plugin}`)",
            "",
            "Device roles (`[devices.<role>]`):",
            "",
            "| role | kind | required | what |",
            "|---|---|---|---|",
        ]
        out += [
            f"| `{r.role}` | {r.kind} | {'no' if r.optional else 'yes'} | {_cell(r.summary)} |"
            for r in j.devices
        ]
        out += [
            "",
            "Stage roles (`[stages.<role>]`):",
            "",
            "| role | kind | default plugin | what |",
            "|---|---|---|---|",
        ]
        out += [f"| `{r.role}` | {r.kind} | `{r.default}` | {_cell(r.summary)} |" for r in j.stages]
        out += ["", f"`[job.settings]` of `{j.name}`:", "", *table(j.settings)]
    for category, title, where in (
        ("device", "Devices", "Settings go in `[devices.<role>.settings]`."),
        ("stage", "Stages", "Settings go in `[stages.<role>.settings]`."),
        ("exporter", "Exporters", "Listed by name in `[output] exporters`."),
    ):
        out += [f"## {title}", ""]
        if category == "exporter":
            out += [
                "A profile names exporters in `[output] exporters`; the job runs each one with the default "
                "settings below (a profile cannot change them yet).",
                "",
            ]
        for e in reg.all(category):
            if not keep(e):
                continue
            d = e.descriptor
            bits = [f"kind `{d.kind}`", f"plugin `{e.provider.plugin}`"]
            if getattr(d, "simulated", False):
                bits.append("simulated")
            if d.requires:
                bits.append(
                    "needs " + ", ".join(f"`weldcell[{x}]`" for x in sorted(set(d.requires.values())))
                )
            if category == "exporter":
                bits.append(f"writes `{d.suffix}`")
            out += [
                f"### `{d.name}`",
                "",
                f"{d.summary} ({'; '.join(bits)}). {where}",
                "",
                *table(d.settings),
            ]
    return out


def render(first_party_only: bool = True) -> str:
    os.environ.pop("WELDCELL_DISABLE_PLUGINS", None)
    from weldcell.sdk.plugins import PluginManager

    pm = PluginManager(discover=True, strict=False)
    for f in pm.registry.failures:
        print(f"warning: {f}", file=sys.stderr)
    lines = [
        NOTE,
        "",
        "# Profile reference",
        "",
        "Every key a cell profile accepts, generated from the settings models in the code. "
        "How to write a profile: [profiles.md](profiles.md).",
        "",
    ]
    lines += profile_section()
    lines += plugin_sections(pm, first_party_only)
    while lines and lines[-1] == "":
        lines.pop()
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when the file is out of date; write nothing")
    ap.add_argument("--all", action="store_true", help="include plugins of other installed distributions")
    ap.add_argument("-o", "--output", type=Path, default=OUT, help=f"file to write (default {OUT})")
    args = ap.parse_args(argv)
    text = render(first_party_only=not args.all)
    if args.check:
        current = args.output.read_text() if args.output.is_file() else ""
        if current == text:
            print(f"{args.output} is up to date")
            return 0
        diff = difflib.unified_diff(
            current.splitlines(), text.splitlines(), str(args.output), "generated", lineterm=""
        )
        print("\n".join(list(diff)[:40]), file=sys.stderr)
        print(f"{args.output} is out of date; run: python docs/gen_profile_reference.py", file=sys.stderr)
        return 1
    args.output.write_text(text)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
