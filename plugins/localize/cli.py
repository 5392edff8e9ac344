"""Offline commands of the localization method (paper 002).

* ``weldcell template CAD -o template.json``: DXF / mesh / template JSON -> ``weldcell/template@1``.
* ``weldcell localize TEMPLATE SCAN -o result.json``: edges of a ``weldcell/laser-scan@1`` CSV (or of a run
  folder's raw recording, synchronised again) fitted to the
  template -> ``weldcell/localization@1``. Exit codes: 0 localized, 1 failed or ambiguous (the result file
  is still written, with the reason), 2 bad input.
"""

from __future__ import annotations

import math
import time
import tomllib
from pathlib import Path

import click
from pydantic import ValidationError
from weldcell.sdk.artifacts import write_json
from weldcell.sdk.errors import JobError, UsageError
from weldcell.sdk.units import parse_quantity

from .stages import EdgeExtractor, Localizer


def _length(text: str | None, what: str) -> float | None:
    if text is None:
        return None
    try:
        return parse_quantity(text, "length")
    except ValueError as e:
        raise UsageError(f"{what}: {e}", "write e.g. '50 mm' or 0.05 (metres)") from None


def _settings(model, sets: tuple[str, ...], base: dict, what: str):
    values = dict(base)
    for item in sets:
        key, sep, raw = item.partition("=")
        if not sep:
            raise UsageError(f"--set {item!r} is not KEY=VALUE", "write e.g. --set window_xy='80 mm'")
        try:
            values[key.strip()] = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            values[key.strip()] = raw.strip()
    try:
        return model.model_validate(values)
    except ValidationError as e:
        problems = "; ".join(f"{'.'.join(map(str, x['loc']))}: {x['msg']}" for x in e.errors())
        raise UsageError(
            f"{what} settings are invalid: {problems}", f"its settings: {', '.join(model.model_fields)}"
        ) from None


def _template_options(f):
    f = click.option(
        "--units",
        type=click.Choice(["m", "mm", "cm", "in", "ft"]),
        help="Units of the CAD file (DXF: overrides $INSUNITS; mesh: default mm).",
    )(f)
    f = click.option("--top", help="Top height of members whose DXF gives none, e.g. '50 mm'.")(f)
    f = click.option(
        "--allow-single-member",
        is_flag=True,
        help="Accept a one-member template (its pose is under-constrained and symmetric).",
    )(f)
    return f


@click.command("template")
@click.argument("cad", type=click.Path(path_type=Path))
@click.option(
    "-o", "--output", required=True, type=click.Path(path_type=Path), help="Template JSON to write."
)
@_template_options
def template_command(cad: Path, output: Path, units: str | None, top: str | None, allow_single_member: bool):
    """Convert CAD (DXF, STL/PLY/OBJ mesh, or template JSON) into a weldcell/template@1 JSON."""
    from .template import load_template

    tpl = load_template(cad, units=units, top=_length(top, "--top"), allow_single_member=allow_single_member)
    tpl.save(output)
    click.echo(
        f"template        {cad}: {len(tpl.members)} members, {len(tpl.welds)} welds, "
        f"levels {', '.join(f'{z * 1000:.1f}' for z in tpl.levels())} mm"
    )
    for m in tpl.members:
        ext = (m.outline.max(axis=0) - m.outline.min(axis=0)) * 1000
        click.echo(
            f"  {m.id:<14} top {m.top * 1000:6.1f} mm  {len(m.outline):3d} vertices  "
            f"{ext[0]:.0f} x {ext[1]:.0f} mm"
        )
    click.echo(f"wrote           {output}")


@click.command("localize")
@click.argument("template", type=click.Path(path_type=Path))
@click.argument("scan", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="Localization JSON.")
@_template_options
@click.option("--method", type=click.Choice(["robust", "paper"]), help="'paper': Powell from seeds only.")
@click.option("--seeds", type=int, help="Powell seeds (paper: 7).")
@click.option(
    "--set",
    "sets",
    multiple=True,
    metavar="KEY=VALUE",
    help="A localize setting, e.g. window_xy='80 mm' (edges.KEY for edge extraction). Repeatable.",
)
def localize_command(
    template: Path, scan: Path, output: Path, units, top, allow_single_member, method, seeds, sets
):
    """Localize the workpiece of TEMPLATE (DXF / mesh / template JSON) from the laser SCAN
    (a weldcell/laser-scan@1 CSV, or a localize-and-weld run folder's raw recording); writes
    weldcell/localization@1."""
    from .edges import EdgeSettings
    from .fit import LocalizeSettings
    from .scan_io import read_laser_scan
    from .template import load_template

    edge_sets = tuple(s.split(".", 1)[1] for s in sets if s.startswith("edges."))
    loc_sets = tuple(s for s in sets if not s.startswith("edges."))
    base = {k: v for k, v in (("method", method), ("seeds", seeds)) if v is not None}
    loc_settings = _settings(LocalizeSettings, loc_sets, base, "localize")
    edge_settings = _settings(EdgeSettings, edge_sets, {}, "edges")
    tpl = load_template(
        template, units=units, top=_length(top, "--top"), allow_single_member=allow_single_member
    )
    if scan.is_dir():  # a localize-and-weld run folder: its raw readings + robot poses + sensor mount
        from .acquisition import scan_from_run

        sc = scan_from_run(scan, tpl.levels())
    else:
        sc = read_laser_scan(scan)
    t0 = time.perf_counter()
    edges = EdgeExtractor(edge_settings)(sc, tpl)
    t_edges = time.perf_counter() - t0
    result = Localizer(loc_settings)(tpl, edges)
    result.timings["edges"] = t_edges
    write_json(output, result.to_json())
    click.echo(
        f"scan            {scan}: {len(sc)} readings, {int((~sc.valid).sum())} out of range, "
        f"{len(edges)} edge points (slot <= {edges.max_gap * 1000:.2f} mm)"
    )
    x, y, th = result.pose
    click.echo(f"status          {result.status}: {result.message}")
    if result.status == "ok":
        sd = [math.sqrt(max(result.covariance[i, i], 0)) for i in range(3)]
        click.echo(
            f"pose            x {x * 1e3:.3f} mm, y {y * 1e3:.3f} mm, theta {math.degrees(th):.4f} deg "
            f"(sigma {sd[0] * 1e3:.3f} mm, {sd[1] * 1e3:.3f} mm, {math.degrees(sd[2]):.4f} deg)"
        )
    click.echo(f"wrote           {output}")
    if result.status != "ok":
        raise JobError(
            f"localization {result.status}: {result.message}", f"see {output}; weld by hand if needed"
        )
