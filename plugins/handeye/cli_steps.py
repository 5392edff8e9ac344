"""The steps of ``weldcell calibrate hand-eye`` (:mod:`weldcell.plugins.handeye.cli`): check the inputs,
read the samples, measure their scans, solve, record where the result came from, print and report.

The command's options reach the solver as two small typed objects, :class:`SolveOptions` and
:class:`BoardOptions`, so each step takes what it uses rather than the command's twenty-two options.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from weldcell.sdk.errors import DataError, UsageError


@dataclass(frozen=True)
class SolveOptions:
    """What the command line asks of the solver (None: the data's or the settings' choice)."""

    method: str
    config: str | None = None
    verifier: str | None = None  # --verifier as given; the settings' verifier when None
    verify_sample: int | None = None
    feature: str | None = None  # tcp, estimate or "x,y,z" in mm
    feature_base: str | None = None  # origin, estimate or "x,y,z" in mm


@dataclass(frozen=True)
class BoardOptions:
    """--board / --intrinsics / --calibrate-intrinsics (board photos only)."""

    board_spec: str | None = None
    intrinsics: Path | None = None
    calibrate_intrinsics: bool = False


def cli_fix(e: DataError) -> DataError:
    """The library's fixes speak Python; say the command-line option instead."""
    fix = (e.fix or "").replace("pass allow_coplanar=True", "pass --allow-coplanar")
    fix = fix.replace("declare units 'mm'", "pass --units mm")
    fix = fix.replace("declare units 'm'", "pass --units m")
    return DataError(e.message, fix)


def check_flange_model(flange_model: Path | None) -> None:
    """--flange-model exists and, for a cloud file, has a readable header and body (before any work)."""
    if flange_model is None:
        return
    if not flange_model.is_file():
        raise UsageError(f"flange model not found: {flange_model}", "give an STL/PCD/PLY file of the flange")
    if flange_model.suffix.lower() in (".ply", ".pcd"):
        from weldcell.sdk.cloudfile import check_cloud_file

        check_cloud_file(flange_model)  # header and body checked before anything is computed


def flange_overrides(
    flange_model: Path | None,
    flange_d1: str | None,
    verifier: str | None,
    inlier_threshold_mm: float | None,
    allow_coplanar: bool,
) -> dict:
    """The handeye.flange settings the options set (None: not given, the settings file's value stays)."""
    return {
        "flange_model": str(flange_model) if flange_model else None,
        "flange_d1": float(flange_d1) if flange_d1 else None,
        "verifier": verifier,
        "inlier_threshold": None if inlier_threshold_mm is None else inlier_threshold_mm * 1e-3,
        "allow_coplanar": allow_coplanar or None,
    }


def default_method(ss) -> str:
    """flange for scans and flange centres; park for board photos or board poses."""
    boards = any(x.image is not None or x.T_cam_target is not None for x in ss.samples)
    flange = any(x.cloud is not None or x.p_cam is not None for x in ss.samples)
    return "park" if boards and not flange else "flange"


def board_extra(method: str, given: dict, opts: BoardOptions, layout_board: dict | None) -> dict:
    """calibrate()'s board settings (:func:`~weldcell.plugins.handeye.cli.board_settings`), fixes in CLI
    words."""
    from weldcell.plugins.handeye.cli import board_settings

    try:
        return board_settings(
            method, given, opts.board_spec, opts.intrinsics, opts.calibrate_intrinsics, layout_board
        )
    except DataError as e:
        raise cli_fix(e) from None


def forget_measured_centres(ss, data_dir: Path) -> str:
    """--remeasure: drop the stored flange centres of every sample with a scan; the note to print."""
    n = sum(smp.cloud is not None for smp in ss.samples)
    if n == 0:
        raise UsageError(f"{data_dir}: --remeasure, but no sample has a scan", "drop --remeasure")
    for smp in ss.samples:
        if smp.cloud is not None:
            smp.p_cam = None
    return f"flange centres measured from {n} scans (--remeasure)"


def measure_scans(ss, stage, need_pose: bool) -> list[str]:
    """Flange centres (and poses) of samples that have a scan but no ``p_cam``; samples whose scan has
    no flange get ``p_cam = None`` and are dropped. Returns one note per dropped scan."""
    from weldcell.sdk.cloud import read_cloud

    notes, keep = [], []
    for i, smp in enumerate(ss.samples):
        needs = smp.cloud is not None and (smp.p_cam is None or (need_pose and smp.T_cam_target is None))
        if not needs:
            keep.append(smp)
            continue
        units = smp.meta.get("cloud_units", "m")
        name = Path(smp.cloud).name if isinstance(smp.cloud, str | Path) else f"#{i}"
        try:
            if isinstance(smp.cloud, str | Path):
                pts = read_cloud(smp.cloud, units=units, frame="camera").points
            else:
                pts = np.asarray(smp.cloud, float)
            m = stage.measure(pts, seed=i)
        except DataError as e:
            notes.append(f"scan {i} ({name}): {e.message}")
            continue
        smp.p_cam = m.p_cam
        smp.meta["flange"] = {"radius_mm": round(m.report["radius"] * 1e3, 3), "support": m.report["support"]}
        if need_pose:
            smp.T_cam_target = stage.measure_pose(m)
        keep.append(smp)
    if notes and len(keep) < 4:
        raise DataError(
            f"no flange found in {len(notes)} of {len(ss.samples)} scans ({notes[0]}); {len(keep)} usable, "
            "at least 4 needed",
            "check the scans show the flange face (and their units, --units), the flange size (--flange-d1) "
            "or the pass-through box (--settings)",
        )
    ss.samples = keep
    return notes


def solve(ss, stage, extra: dict, opts: SolveOptions, notes: list[str]):
    """Measure the scans, pick the verification scan (Algorithm 1 with eq. 13), add the features and run
    the stage's solver; appends to ``notes``. DataErrors come back with command-line fixes."""
    from weldcell.plugins.handeye.stages import FlangeHandEye

    method, s = opts.method, stage.s
    verification = None
    try:
        notes += measure_scans(ss, stage, need_pose=not method.startswith("flange"))
        if method == "flange-iterative" and opts.verifier is None and s.verifier == "icp":
            if not any(smp.cloud is not None and smp.T_base_flange is not None for smp in ss.samples):
                stage = FlangeHandEye(s.model_copy(update={"verifier": "consensus"}))
                s = stage.s
                notes.append("Algorithm 1 verifies by consensus (no scan with a robot pose for eq. 13)")
        if method == "flange-iterative" and s.verifier == "icp":
            verification = _verification_sample(ss, stage, opts.verify_sample)
            notes.append(f"sample {verification[2]} is the ICP verification scan (left out of the fit)")
            verification = verification[:2]
        f = _feature(opts.feature)
        if f is not None:
            extra["feature"] = f
        fb = _feature(opts.feature_base, "--feature-base", "origin") if opts.feature_base else ss.feature_base
        if fb is not None:
            extra["feature_base"] = fb
        result = stage.solve(
            ss.samples, opts.config or ss.config, verification=verification, method=method, **extra
        )
    except DataError as e:
        raise cli_fix(e) from None
    if verification is not None and s.flange_model:
        notes += _model_notes(stage.flange_model, result)
    return result


def record_source(result, ss, notes: list[str], data_dir: Path, layout: str) -> None:
    """Skipped scans as warnings; the samples used and where they came from in the result's metrics."""
    from weldcell.plugins.handeye.cli import detect_layout
    from weldcell.sdk.handeye_files import sample_id

    result.warnings += [f"skipped {n}" for n in notes if n.startswith("scan ")]
    result.metrics["sample_index"] = [int(smp.meta.get("index", i)) for i, smp in enumerate(ss.samples)]
    result.metrics["sample_ids"] = [sample_id(smp, i) for i, smp in enumerate(ss.samples)]
    result.metrics["source"] = {
        "data": str(data_dir),
        "layout": layout if layout != "auto" else detect_layout(data_dir),
        "notes": notes,
    }


def print_summary(result, notes: list[str], report_dir: Path | None, quiet: bool, output: Path) -> None:
    """The summary (and the report when asked), then the written file's name."""
    from weldcell.plugins.handeye.report import summary_lines, write_offline_report
    from weldcell.sdk.cli import out

    lines = summary_lines(result)
    lines += [f"note            {n}" for n in notes]
    if report_dir is not None:
        written = write_report(report_dir, result, lines, write_offline_report)
        lines.append(f"report          {report_dir}/ ({', '.join(written)})")
    if not quiet:
        out.print("\n".join(lines), markup=False)
    out.print(f"wrote {output}", markup=False)


def _feature(value: str | None, option: str = "--feature", named: str = "tcp"):
    """A feature option: ``named`` ("tcp" or "origin"), "estimate", or x,y,z in mm (returned in m)."""
    if value is None or value in (named, "estimate"):
        return value
    try:
        xyz = [float(v) * 1e-3 for v in value.split(",")]
    except ValueError:
        xyz = []
    if len(xyz) != 3:
        raise UsageError(
            f"{option} '{value}' is not {named}, estimate or x,y,z", f"e.g. {option} 0,0,12.5 (mm)"
        )
    return xyz


def _model_notes(fm, result) -> list[str]:
    """What cleaning the flange model did (notes), its warnings into the result, its report in metrics."""
    r = fm.report
    result.metrics["flange_model"] = r
    result.warnings += fm.warnings
    notes = [f"flange model read as {r['units']}: {r['diameter_mm']} mm across, {r['points_out']} points"]
    if r.get("nonfinite_dropped"):
        notes.append(f"flange model: {r['nonfinite_dropped']} NaN/inf points of {r['points_in']} dropped")
    if r.get("moved"):
        notes.append(r["moved"])
    return notes


def write_report(report_dir: Path, result, lines: list[str], writer) -> list[str]:
    """The offline report written into a scratch folder, then each file moved into ``report_dir``
    atomically and durably: a crash leaves the old or the new file, never half of one."""
    import shutil

    from weldcell.sdk.artifacts import write_bytes

    scratch = Path(tempfile.mkdtemp(prefix="weldcell-report-"))
    try:
        written = writer(scratch, result, lines)
        for name in written:
            write_bytes(report_dir / name, (scratch / name).read_bytes())
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return written


def _verification_sample(ss, stage, index: int | None):
    """(face cloud, T_base_flange, index) of the verification scan; it is removed from ``ss``."""
    from weldcell.sdk.cloud import read_cloud
    from weldcell.sdk.handeye_files import sample_id

    cands = [i for i, smp in enumerate(ss.samples) if smp.cloud is not None and smp.T_base_flange is not None]
    if index is None:
        if not cands:
            raise UsageError(
                "the ICP verifier needs a sample with a scan and a robot pose",
                "use --verifier consensus for point-pair data",
            )
        index = cands[0]
    if index not in cands:
        raise UsageError(f"--verify-sample {index} has no scan with a robot pose", f"use one of {cands}")
    smp = ss.samples.pop(index)
    pts = (
        smp.cloud
        if not isinstance(smp.cloud, str | Path)
        else read_cloud(smp.cloud, units=smp.meta.get("cloud_units", "m"), frame="camera").points
    )
    m = stage.measure(pts, seed=index)
    return m.face, smp.T_base_flange, sample_id(smp, index)
