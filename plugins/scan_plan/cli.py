"""Offline commands of the scan-and-plan method: ``weldcell seam`` and ``weldcell reconstruct``.

Both run the same stage plugins as the ``scan-and-plan`` job, looked up by name in the plugin
registry, so a profile that selects another plugin for a stage (``--profile``) is honoured here too.

* ``weldcell seam CLOUD -o path.json``: a cloud in the robot base frame → bilateral denoising →
  edge-intensity seams → 6-DOF torch paths (:func:`.cloud_pipeline.plan_on_cloud`, as the job) →
  ``weldcell/weld-path@1`` (+ robot programs, + a picture).
* ``weldcell reconstruct SCANS_DIR -o model.ply``: posed scans (a run folder, or a folder with a
  ``weldcell/posed-scans@1`` ``scans.json``) + hand-eye → merged model refined by linear ICP.
"""

from __future__ import annotations

import time
import tomllib
from pathlib import Path
from typing import Any

import click
import numpy as np
from pydantic import ValidationError
from weldcell.sdk.artifacts import write_json, write_text
from weldcell.sdk.cloud import PointCloud, write_cloud
from weldcell.sdk.errors import DataError, UsageError
from weldcell.sdk.geometry import T_from_rpy, rotation_angle
from weldcell.sdk.units import parse_quantity
from weldcell.sdk.weldpath import WeldPath

from .cloud_pipeline import SeamRun, plan_on_cloud
from .scans_io import SCANS_SCHEMA, PosedScans, check_mount, load_posed_scans, read_input_cloud  # noqa: F401

JOB = "scan-and-plan"
EXPORT_ALIASES = {
    "urscript": "export.urscript",
    "abb-rapid": "export.abb-rapid",
    "rapid": "export.abb-rapid",
    "csv": "export.csv",
    "json": "export.json",
}


# ------------------------------------------------------------------------------------------------ stages
def parse_sets(sets: tuple[str, ...] | list[str]) -> dict[str, dict[str, Any]]:
    """``ROLE.KEY=VALUE`` options → ``{role: {key: value}}`` (VALUE read as TOML, else a string)."""
    out: dict[str, dict[str, Any]] = {}
    for item in sets:
        key, sep, raw = item.partition("=")
        role, dot, name = key.strip().partition(".")
        if not sep or not dot or not role or not name:
            raise UsageError(
                f"--set {item!r} is not ROLE.KEY=VALUE", "write e.g. --set seam.min_seam_length='30 mm'"
            )
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        out.setdefault(role, {})[name] = value
    return out


def resolve_stages(
    pm,
    roles: tuple[str, ...],
    profile: Path | None = None,
    overrides: dict[str, dict[str, Any]] | None = None,
) -> dict[str, tuple[Any, Any]]:
    """``{role: (StageSpec, settings)}`` for the scan-and-plan stage ``roles``.

    The plugin of each role is the job's default, or the one ``profile``'s ``[stages.<role>]`` picks;
    its settings are the profile's, updated by ``overrides`` (``{role: {key: value}}``).
    """
    reg = pm.registry
    job = reg.get("job", JOB)
    slots = {r.role: r for r in job.stages}
    overrides = dict(overrides or {})
    unknown = sorted(set(overrides) - set(roles))
    if unknown:
        raise UsageError(
            f"no stage role {', '.join(map(repr, unknown))} in this command",
            f"its stage roles are: {', '.join(roles)}",
        )
    entries: dict[str, Any] = {}
    where = "defaults"
    if profile is not None:
        from weldcell.sdk.profile import load_profile

        loaded = load_profile(profile)
        entries = loaded.profile.stages
        where = str(profile)
    out = {}
    for role in roles:
        slot = slots[role]
        entry = entries.get(role)
        name = (entry.plugin if entry is not None and entry.plugin else None) or slot.default
        spec = reg.get("stage", name, kind=slot.kind)
        spec.check_available()
        values = {**(entry.settings if entry is not None else {}), **overrides.get(role, {})}
        try:
            settings = spec.settings.model_validate(values)
        except ValidationError as e:
            from weldcell.sdk.profile import pydantic_problems

            problems = "; ".join(f"{role}.{'.'.join(k)}: {m}" for k, m in pydantic_problems(e))
            fields = ", ".join(spec.settings.model_fields)
            raise UsageError(
                f"settings of stage '{name}' ({where} + options) are invalid: {problems}",
                f"its settings are: {fields}",
            ) from None
        out[role] = (spec, settings)
    return out


def parse_floats(text: str, n: int, dims: tuple[str, ...], what: str) -> np.ndarray:
    """``"a,b,c"`` with optional units per value (``"0,-60mm,40 mm"``) → SI floats."""
    parts = [p for p in text.split(",")]
    if len(parts) != n:
        raise UsageError(
            f"{what} needs {n} comma-separated values, got {len(parts)}: {text!r}",
            f"write e.g. {','.join(['0'] * n)}",
        )
    try:
        return np.array([parse_quantity(p.strip(), d) for p, d in zip(parts, dims, strict=True)])
    except ValueError as e:
        raise UsageError(
            f"{what}: {e}", "numbers in metres/radians, or with units like '60 mm', '90 deg'"
        ) from None


# ------------------------------------------------------------------------------------------------ seams
def write_seam_report(
    out_dir: Path, source: Path, cloud: PointCloud, path: WeldPath, summary: list[str], outputs: list[Path]
) -> list[Path]:
    """The scan-and-plan job's report for one cloud: ``report.html`` (self-contained: verdict, seam table,
    3-D view, cross-sections), ``report.md``, the PNGs and ``summary.txt`` in ``out_dir``; ``outputs``
    are the files the command wrote besides. Returns the report's files."""
    from weldcell.plugins.scan_plan.report import ReportPage, verdict_of, write_pages
    from weldcell.plugins.scan_plan.report_figures import seam_measures

    measures = seam_measures(path, None)
    v = verdict_of({}, None, path, None, measures)
    text = "\n".join(summary) + "\n"
    files = [[str(source), "the cloud read"]] + [[str(f), "written by this command"] for f in outputs]
    page = ReportPage(
        out_dir,
        f"Seams: {source.name}",
        f"weldcell seam {source} · {len(cloud)} points processed",
        files=files,
        cloud_label="cloud",
        md_title=f"Seam report: {source.name}",
    )
    written = write_pages(page, v, text, None, np.asarray(cloud.points, dtype=float), path, None, measures)
    return [*written, write_text(out_dir / "summary.txt", text)]


def seam_table(path: WeldPath) -> list[str]:
    lines = []
    for s in path.seams:
        a, b = s.points[0] * 1000, s.points[-1] * 1000
        lines.append(
            f"  {s.id:>4}  {s.joint:<8} {s.length * 1000:7.1f} mm  {len(s.poses):4d} torch poses  "
            f"from ({a[0]:.1f}, {a[1]:.1f}, {a[2]:.1f}) to ({b[0]:.1f}, {b[1]:.1f}, {b[2]:.1f}) mm"
            + ("  closed" if s.closed else "")
        )
    return lines


def _pm():
    from weldcell.sdk.plugins import get_plugin_manager

    return get_plugin_manager()


@click.command("seam")
@click.argument("cloud", type=click.Path(path_type=Path))
@click.option(
    "-o", "--output", required=True, type=click.Path(path_type=Path), help="Weld-path JSON to write."
)
@click.option(
    "--units",
    type=click.Choice(["m", "mm"]),
    default="m",
    show_default=True,
    help="Units of the cloud's coordinates.",
)
@click.option("--frame", default="base", show_default=True, help="Frame the cloud is in (the robot base).")
@click.option("--t", "t", type=float, help="Edge threshold on Tr(H)^3/Det(H) (eq. 16) of the seam stage.")
@click.option("--standoff", help="Torch standoff, e.g. '15 mm' (default: the path stage's).")
@click.option(
    "--export",
    "exports",
    multiple=True,
    help="Also write a robot program: urscript, abb-rapid, csv (or any exporter name). Repeatable.",
)
@click.option("--no-denoise", is_flag=True, help="Skip the bilateral filter (the cloud is already clean).")
@click.option("--viewpoint", help="Where the camera was, x,y,z in the base frame (orients the normals).")
@click.option(
    "--report",
    "report_dir",
    type=click.Path(path_type=Path),
    help="Write report.html (self-contained: open it in a browser), report.md, the pictures and "
    "summary.txt into this folder.",
)
@click.option(
    "--profile",
    type=click.Path(path_type=Path),
    help="Take the stage plugins and settings from this profile's [stages].",
)
@click.option(
    "--set",
    "sets",
    multiple=True,
    metavar="ROLE.KEY=VALUE",
    help="Set a stage setting, e.g. seam.min_seam_length='30 mm'. Repeatable.",
)
# one parameter per click option (click passes them by name); the body calls named steps and plan_on_cloud
def seam_command(
    cloud: Path,
    output: Path,
    units: str,
    frame: str,
    t: float | None,
    standoff: str | None,
    exports: tuple[str, ...],
    no_denoise: bool,
    viewpoint: str | None,
    report_dir: Path | None,
    profile: Path | None,
    sets: tuple[str, ...],
) -> None:
    """Find the weld seams of CLOUD (PLY/PCD, robot base frame) and plan 6-DOF torch paths.

    Writes a weldcell/weld-path@1 JSON (metres, quaternions [x, y, z, w]).
    """
    pm = _pm()
    overrides = parse_sets(sets)
    if t is not None:
        overrides.setdefault("seam", {})["t"] = t
    if standoff is not None:
        overrides.setdefault("path", {})["standoff"] = standoff
    roles = ("seam", "path") if no_denoise else ("denoise", "seam", "path")
    stages = resolve_stages(pm, roles, profile, overrides)
    exporters = [pm.registry.get("exporter", EXPORT_ALIASES.get(e, e)) for e in exports]
    for spec in exporters:
        spec.check_available()
    t0 = time.perf_counter()
    pc, dropped = _read_seam_cloud(cloud, units, frame, viewpoint)
    t_read = time.perf_counter() - t0
    result = plan_on_cloud(
        pc, lambda role: stages[role][0].factory(stages[role][1]), frame=frame, denoise=not no_denoise
    )
    path = result.path
    if path is None or not path.seams:
        raise DataError(
            f"no weld seam was found on {cloud} ({len(result.cloud)} points)",
            "check the cloud shows the joint; lower --t, or --set seam.min_seam_length='10 mm'",
        )
    path.metrics = _seam_metrics(cloud, pc, dropped, result, stages, t_read)
    path.write(output)
    written = [output, *_write_exports(path, output, exporters)]
    summary = _echo_seams(cloud, pc, result, stages, t_read)
    if report_dir is not None:
        written += write_seam_report(report_dir, cloud, result.cloud, path, summary, list(written))
    click.echo("written         " + ", ".join(str(f) for f in written))


def _read_seam_cloud(cloud: Path, units: str, frame: str, viewpoint: str | None) -> tuple[PointCloud, int]:
    """The cloud in metres without invalid points, and how many were dropped; ``--viewpoint`` replaces
    the viewpoints the file stored (:func:`weldcell.sdk.cloud.write_cloud` keeps them in its header)."""
    pc, dropped = read_input_cloud(cloud, units, frame)
    if viewpoint is not None:
        pc = pc.with_viewpoints([parse_floats(viewpoint, 3, ("length",) * 3, "--viewpoint")])
    click.echo(
        f"cloud           {cloud}: {len(pc)} points, extent "
        f"{' x '.join(f'{v * 1000:.0f}' for v in np.ptp(pc.points, axis=0))} mm"
    )
    if dropped:
        click.echo(f"                dropped {dropped} invalid points (NaN, inf or at the origin)")
    if pc.viewpoints is not None:
        where = "--viewpoint" if viewpoint else "stored in the file"
        click.echo(f"viewpoints      {len(pc.viewpoints)} ({where})")
    return pc, dropped


def _seam_metrics(
    cloud: Path, pc: PointCloud, dropped: int, result: SeamRun, stages: dict, t_read: float
) -> dict[str, Any]:
    """The weld path's ``metrics`` of one ``weldcell seam`` run: input, counts, timings, stages."""
    path = result.path
    runtime = t_read + sum(result.timings.values())
    length = sum(s.length for s in path.seams)
    return {
        "source": str(cloud),
        "points": len(pc),
        "points_processed": len(result.cloud),
        "dropped_invalid": dropped,
        "seams_found": len(path.seams),
        "seam_length_m": round(length, 6),
        "runtime_s": round(runtime, 4),
        "mm_per_s": round(length * 1000 / runtime, 2),
        "timings_s": {k: round(v, 4) for k, v in result.timings.items()},
        "stages": {
            r: {"plugin": sp.name, "settings": st.model_dump(mode="json")} for r, (sp, st) in stages.items()
        },
    }


def _write_exports(path: WeldPath, output: Path, exporters: list) -> list[Path]:
    """The robot programs of ``exporters`` next to ``output``; returns the files written."""
    written = []
    doc = path.to_json()
    for spec in exporters:
        f = output.with_name(output.stem + spec.suffix)
        if f == output:
            f = output.with_name(output.stem + "_export" + spec.suffix)
        write_text(f, spec.export(doc, spec.settings()))
        written.append(f)
    return written


def _echo_seams(cloud: Path, pc: PointCloud, result: SeamRun, stages: dict, t_read: float) -> list[str]:
    """Print what was found (seam table, timings); returns the lines of the report's summary."""
    path = result.path
    if "denoise" in stages:
        click.echo(f"denoised        {len(result.cloud)} points ({stages['denoise'][0].name})")
    click.echo(
        f"seams found     {len(path.seams)} ({stages['seam'][0].name}, paths: {stages['path'][0].name})"
    )
    table = seam_table(path)
    for line in table:
        click.echo(line)
    runtime = t_read + sum(result.timings.values())
    length = sum(s.length for s in path.seams)
    timing = ", ".join(f"{k} {v:.2f}s" for k, v in result.timings.items())
    click.echo(
        f"timings         read {t_read:.2f}s, {timing}  ({length * 1000 / runtime:.0f} mm of seam per s)"
    )
    return [
        f"weldcell seam {cloud}",
        f"points {len(pc)}, processed {len(result.cloud)}",
        f"seams {len(path.seams)}",
        *table,
        f"timings read {t_read:.2f}s, {timing}",
    ]


# ------------------------------------------------------------------------------------------------ reconstruct
def hand_eye_option(
    hand_eye: Path | None, mount: str | None, stored: np.ndarray | None
) -> tuple[np.ndarray, str]:
    """``T_flange_camera`` from --hand-eye, --mount, or what the scans folder stored."""
    if hand_eye is not None and mount is not None:
        raise UsageError("give either --hand-eye or --mount, not both", "drop one of them")
    if hand_eye is not None:
        from weldcell.plugins.scan_plan.job import read_hand_eye

        return check_mount(read_hand_eye(hand_eye), hand_eye), str(hand_eye)
    if mount is not None:
        v = parse_floats(mount, 6, ("length",) * 3 + ("angle",) * 3, "--mount")
        return T_from_rpy(v[3:], v[:3]), "--mount"
    if stored is not None:
        return stored, "stored with the scans"
    raise UsageError(
        "no hand-eye transform: the scans do not store one",
        "pass --hand-eye handeye.json (from `weldcell calibrate hand-eye`) or --mount x,y,z,r,p,y",
    )


@click.command("reconstruct")
@click.argument("scans_dir", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path), help="Model cloud to write.")
@click.option(
    "--hand-eye",
    "hand_eye",
    type=click.Path(path_type=Path),
    help="Hand-eye result (T_flange_camera), e.g. from `weldcell calibrate hand-eye`.",
)
@click.option(
    "--mount", help="Nominal camera mount on the flange: x,y,z,roll,pitch,yaw (m, rad, or with units)."
)
@click.option(
    "--roi-min",
    help="Keep only points above this corner x,y,z of the base frame (default: the run's region).",
)
@click.option(
    "--roi-max",
    help="Keep only points below this corner x,y,z of the base frame (default: the run's region).",
)
@click.option(
    "--profile",
    type=click.Path(path_type=Path),
    help="Take the reconstruct stage plugin and settings from this profile's [stages].",
)
@click.option(
    "--set",
    "sets",
    multiple=True,
    metavar="reconstruct.KEY=VALUE",
    help="Set a stage setting, e.g. reconstruct.voxel='2 mm'. Repeatable.",
)
@click.option(
    "--anchor",
    type=click.Choice(["mean", "first", "hand-eye"]),
    help="Model placement (same as --set reconstruct.anchor=...): 'hand-eye' also finds the hand-eye "
    "transform's error from the views and corrects it.",
)
# one parameter per click option (click passes them by name); the body calls named steps and the stage
def reconstruct_command(
    scans_dir: Path,
    output: Path,
    hand_eye: Path | None,
    mount: str | None,
    roi_min: str | None,
    roi_max: str | None,
    profile: Path | None,
    sets: tuple[str, ...],
    anchor: str | None,
) -> None:
    """Merge posed scans into one model in the robot base frame, refined by linear ICP.

    SCANS_DIR is a scan-and-plan run folder (state.json) or a folder with a scans.json
    (weldcell/posed-scans@1).
    """
    overrides = parse_sets(sets)
    if anchor is not None:
        overrides.setdefault("reconstruct", {})["anchor"] = anchor
    spec, settings = resolve_stages(_pm(), ("reconstruct",), profile, overrides)["reconstruct"]
    data = load_posed_scans(scans_dir)
    T_fc, source = hand_eye_option(hand_eye, mount, data.T_flange_camera)
    click.echo(f"scans           {len(data.scans)} from {scans_dir} ({data.layout}); hand-eye: {source}")
    views, names = _views_in_region(data, T_fc, roi_min, roi_max)
    t0 = time.perf_counter()
    rec = spec.factory(settings)(views, T_fc)
    dt = time.perf_counter() - t0
    write_cloud(output, rec.cloud)  # with the views' camera positions: `weldcell seam` reads them back
    _echo_views(rec, views, names)
    click.echo(f"model           {len(rec.cloud)} points -> {output}  ({dt:.2f} s, {spec.name})")
    he = getattr(rec, "hand_eye", None)
    if he is not None:
        click.echo(f"hand-eye        {he.describe()}")
    doc = {
        "schema": "weldcell/reconstruction@1",
        "model": output.name,
        "scans": str(scans_dir),
        "hand_eye": source,
        "T_flange_camera": T_fc.tolist(),
        "stage": {"plugin": spec.name, "settings": settings.model_dump(mode="json")},
        "views": _view_records(rec, names),
        "runtime_s": round(dt, 4),
    }
    if he is not None:
        doc["hand_eye_correction"] = he.summary()
        if he.applied:
            doc["T_flange_camera_corrected"] = (T_fc @ he.D).tolist()
    write_json(output.with_suffix(".json"), doc)


def _views_in_region(
    data: PosedScans, T_fc: np.ndarray, roi_min: str | None, roi_max: str | None
) -> tuple[list, list[str]]:
    """The views (cropped to --roi-min/--roi-max, else to the run's region) and their names."""
    lo = parse_floats(roi_min, 3, ("length",) * 3, "--roi-min") if roi_min else data.roi[0]
    hi = parse_floats(roi_max, 3, ("length",) * 3, "--roi-max") if roi_max else data.roi[1]
    if lo is None and hi is None:
        return data.scans, data.names
    from weldcell.plugins.scan_plan.job import crop_views

    cropped = crop_views(data.scans, T_fc, lo, hi)
    if not cropped:
        raise DataError(
            "no scan has points inside the region of interest",
            "check --roi-min / --roi-max (metres, robot base frame) against the part",
        )
    views, names = [v for _, v in cropped], [data.names[i] for i, _ in cropped]
    fmt = lambda c: "-" if c is None else "(" + ", ".join(f"{v * 1000:.0f}" for v in c) + ") mm"  # noqa: E731
    click.echo(
        f"region          {fmt(lo)} .. {fmt(hi)} (base frame); {len(views)} of {len(data.scans)} "
        "views have points in it"
    )
    return views, names


def _echo_views(rec: Any, views: list, names: list[str]) -> None:
    """One line per view: points, fitness before/after, the ICP correction, kept."""
    click.echo(
        f"{'view':>4}  {'file':<16} {'points':>7}  {'fitness before':>14}  {'after':>6}  "
        f"{'correction':>17}  kept"
    )
    for i, name in enumerate(names):
        C = rec.corrections[i]
        corr = f"{np.linalg.norm(C[:3, 3]) * 1000:6.2f} mm {np.degrees(rotation_angle(C[:3, :3])):5.2f} deg"
        click.echo(
            f"{i:>4}  {name:<16} {len(views[i].cloud):>7}  {rec.fitness_before[i]:>14.3f}  "
            f"{rec.fitness[i]:>6.3f}  {corr:>17}  {'yes' if rec.accepted[i] else 'no'}"
        )


def _view_records(rec: Any, names: list[str]) -> list[dict[str, Any]]:
    """The ``views`` of the ``weldcell/reconstruction@1`` file."""
    return [
        {
            "file": n,
            "fitness_before": rec.fitness_before[i],
            "fitness": rec.fitness[i],
            "accepted": bool(rec.accepted[i]),
            "T_base_camera": np.asarray(rec.T_base_camera[i]).tolist(),
        }
        for i, n in enumerate(names)
    ]
