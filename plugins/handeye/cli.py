"""``weldcell calibrate hand-eye DATA_DIR -o handeye.json``: hand-eye calibration of recorded data.

DATA_DIR is a ``samples.json`` (``weldcell/handeye-samples@1``, e.g. a ``calibrate`` run folder) or
one of the ancorasir layouts read directly: ``calib_toolbox/data/<date>-sample`` (calib_data.json +
raw scans), ``paper_dda5a35/data/<robot>`` (point pairs) or ``Kinect_Result``. Raw scans are
segmented with the ``handeye.flange`` stage (plane peeling included); a scan without a flange is
skipped and listed. Exit codes are those of :mod:`weldcell.sdk.cli`.
"""

from __future__ import annotations

from pathlib import Path

import click
from weldcell.sdk.datafile import check_keys, expect_object, read_json_file, read_toml_file
from weldcell.sdk.errors import DataError, UsageError

from .cli_steps import measure_scans  # noqa: F401  (public here before the steps had their module)

LAYOUTS = (
    "auto",
    "weldcell",
    "ancorasir-sample",
    "ancorasir-pairs",
    "ancorasir-kinect",
    "ancorasir-aubo",
    "rwhe",
)


def detect_layout(path: Path) -> str:
    """The layout of a data folder (or a samples.json file); UsageError naming what was looked for."""
    if path.is_file() and path.suffix == ".json":
        return "weldcell"
    if not path.is_dir():
        raise UsageError(
            f"{path} is not a folder or a samples.json file", "give the folder of the recorded data"
        )
    if (path / "samples.json").is_file():
        return "weldcell"
    if (path / "calib_data.json").is_file():
        return "ancorasir-sample"
    if (path / "p_camera_mat.npy").is_file() and (path / "p_robot_mat.npy").is_file():
        return "ancorasir-pairs"
    if (path / "readRobot.txt").is_file() and (path / "measureRobot.txt").is_file():
        return "ancorasir-kinect"
    from weldcell.plugins.handeye.layouts import is_aubo_folder, is_rwhe_folder

    if is_aubo_folder(path):
        return "ancorasir-aubo"
    if is_rwhe_folder(path):
        return "rwhe"
    raise UsageError(
        f"{path}: no hand-eye data found (no samples.json, calib_data.json, p_camera_mat.npy, "
        "readRobot.txt, data.txt or RobotPosesVec.txt)",
        "point at a folder with samples.json (weldcell/handeye-samples@1) or an ancorasir layout; "
        "--layout forces one",
    )


def read_data(path: Path, layout: str = "auto", units: str | None = None, quaternion: str = "auto"):
    """Samples of any supported layout as a :class:`~weldcell.sdk.handeye_files.SampleSet`."""
    from weldcell.plugins.handeye import samples_io as io

    layout = detect_layout(path) if layout == "auto" else layout
    if layout == "weldcell":
        f = path if path.is_file() else path / "samples.json"
        if not f.is_file():
            raise UsageError(f"{f} not found", "give a folder with samples.json or the file itself")
        doc = read_json_file(f, "samples file")
        if units is not None and isinstance(doc, dict) and doc.get("units", "m") != units:
            ss = io.read_samples(f, units=units)
            ss.notes.append(f"lengths read as {units} (--units)")
            return ss
        return io.read_samples(f)
    if layout == "ancorasir-sample":
        return io.read_ancorasir_sample(path)
    if layout == "ancorasir-pairs":
        return io.read_ancorasir_point_pairs(path, units=units or "auto")
    if layout == "ancorasir-kinect":
        return io.read_ancorasir_kinect(path)
    if layout == "ancorasir-aubo":
        from weldcell.plugins.handeye.layouts import read_aubo_folder

        return read_aubo_folder(path, quaternion, units)
    if layout == "rwhe":
        from weldcell.plugins.handeye.layouts import read_rwhe_folder

        return read_rwhe_folder(path, units)
    raise UsageError(f"unknown layout '{layout}'", f"use one of {', '.join(LAYOUTS)}")


#: --settings keys used by the board methods (tsai, park, ...) besides the handeye.flange ones
BOARD_KEYS = ("board", "intrinsics", "calibrate_intrinsics")


def _stage_settings(settings_file: Path | None, overrides: dict):
    """(FlangeSettings, board settings) from ``--settings`` and the options; a key neither uses is an
    unknown-key error naming the file."""
    from weldcell.plugins.handeye.stages import FlangeSettings

    values: dict = {}
    where = "flange settings"
    if settings_file is not None:
        values, where = _read_settings_file(settings_file), str(settings_file)
        check_keys(values, [*FlangeSettings.model_fields, *BOARD_KEYS], f"{where}: hand-eye settings")
    board = {k: values.pop(k) for k in BOARD_KEYS if k in values}
    if "intrinsics" in board and settings_file is not None and isinstance(board["intrinsics"], str):
        board["intrinsics"] = str((settings_file.parent / board["intrinsics"]).resolve())
    values.update({k: v for k, v in overrides.items() if v is not None})
    from pydantic import ValidationError
    from weldcell.sdk.profile import pydantic_problems

    try:
        return FlangeSettings.model_validate(values), board
    except ValidationError as e:
        problems = pydantic_problems(e)
        key, msg = problems[0]
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise UsageError(
            f"{where}: {'.'.join(key)}: {msg}{more}",
            "fix the value (see docs/methods/hand-eye.md)",
        ) from None


def board_settings(
    method: str,
    given: dict,
    board: str | None,
    intrinsics: Path | None,
    calibrate: bool,
    layout_board: dict | None,
) -> dict:
    """The calibrate() settings for board photos from --board/--intrinsics/--calibrate-intrinsics and the
    settings file's board keys (the options win). Given to a flange method, they are a usage error."""
    from weldcell.plugins.handeye.board import BoardSpec, read_intrinsics

    asked = dict(given)
    if board:
        asked["board"] = board
    if intrinsics is not None:
        asked["intrinsics"] = str(intrinsics)
    if calibrate:
        asked["calibrate_intrinsics"] = True
    if not asked:
        return {}
    if method.startswith("flange"):
        raise UsageError(
            f"{', '.join(sorted(asked))}: used only by the board methods, not --method {method}",
            "pass --method park (or tsai, horaud, andreff, daniilidis, shah, li) for board photos, "
            "or drop them",
        )
    out: dict = {}
    b = asked.get("board")
    if isinstance(b, str):
        parts = b.split(":")
        if len(parts) == 2 and parts[0] == "chessboard" and (layout_board or {}).get("square"):
            b = f"{b}:{layout_board['square'] * 1e3:g}"  # the square the data folder gives
        spec = BoardSpec.parse(b)
    elif isinstance(b, dict):
        spec = BoardSpec.from_dict(b, "--settings board")
    elif b is None:
        raise UsageError(
            "board photos need the board", "pass --board, e.g. chessboard:9x6:25 (inner corners, mm)"
        )
    else:
        raise UsageError(
            f"--settings board is {type(b).__name__}", "give a table (kind, squares_x, ...) or a text"
        )
    out["board"] = spec
    if asked.get("intrinsics"):
        out["intrinsics"] = read_intrinsics(Path(asked["intrinsics"]))
    out["calibrate_intrinsics"] = bool(asked.get("calibrate_intrinsics"))
    return out


_PROFILE_KEYS = (
    "schema",
    "extends",
    "name",
    "job",
    "devices",
    "stages",
    "cell",
    "calibration",
    "sim",
    "output",
)


def _read_settings_file(path: Path) -> dict:
    """The handeye.flange settings of a ``--settings`` file: a flat TOML/JSON table of settings, a
    file with ``[stages.handeye.settings]``, or a profile (its ``extends`` chain counts)."""
    if path.suffix.lower() not in (".toml", ".json"):
        raise UsageError(f"--settings {path}: not a .toml or .json file", "give a TOML or JSON settings file")
    values = read_toml_file(path, "settings file") if path.suffix.lower() == ".toml" else None
    if values is None:
        values = expect_object(read_json_file(path, "settings file"), str(path), '{"flange_d1": 63}')
    if "extends" in values or "schema" in values:  # a profile: its extends chain counts
        from weldcell.sdk.profile import load_profile

        stage = load_profile(path).profile.stages.get("handeye")
        return dict(stage.settings) if stage else {}
    if "stages" in values or "job" in values:
        check_keys(values, _PROFILE_KEYS, str(path))
        stages = expect_object(values.get("stages", {}), f"{path}: stages")
        stage = expect_object(stages.get("handeye", {}), f"{path}: stages.handeye")
        check_keys(stage, ("plugin", "settings"), f"{path}: stages.handeye")
        return dict(expect_object(stage.get("settings", {}), f"{path}: stages.handeye.settings"))
    return values


@click.group("calibrate")
def calibrate_group() -> None:
    """Calibrate a cell from recorded data (hand-eye)."""


@calibrate_group.command("hand-eye")
@click.argument("data_dir", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    default=Path("handeye.json"),
    show_default=True,
    help="Where to write the weldcell/hand-eye@1 result.",
)
@click.option(
    "--method",
    default=None,
    type=click.Choice(
        [
            "flange",
            "flange-svd",
            "flange-iterative",
            "tsai",
            "park",
            "horaud",
            "andreff",
            "daniilidis",
            "shah",
            "li",
        ]
    ),
    help="Solver (flange* = paper 003; default: flange, or park for board photos).",
)
@click.option(
    "--config",
    "config",
    type=click.Choice(["eye-on-base", "eye-in-hand", "eye-on-arm", "co-manipulation"]),
    help="Hand-eye configuration (default: the data's).",
)
@click.option(
    "--units", type=click.Choice(["mm", "m"]), help="Units of the data's lengths (default: the file's)."
)
@click.option(
    "--layout", type=click.Choice(LAYOUTS), default="auto", show_default=True, help="Force a data layout."
)
@click.option(
    "--quaternion",
    type=click.Choice(["auto", "xyzw", "wxyz"]),
    default="auto",
    show_default=True,
    help="Quaternion order of a data.txt layout (auto: the one under which the flange faces the camera).",
)
@click.option(
    "--flange-model",
    type=click.Path(path_type=Path),
    help="Flange CAD (STL) or cloud (PCD/PLY) for the ICP metric; NaN points, units (mm/m) and its frame "
    "are cleaned, a model that cannot work is refused.",
)
@click.option(
    "--flange-d1",
    type=click.Choice(["31.5", "40", "50", "63", "80", "100"]),
    help="ISO 9409-1 flange size (pitch circle, mm); default 50.",
)
@click.option("--verifier", type=click.Choice(["consensus", "icp"]), help="Algorithm 1's error metric.")
@click.option(
    "--verify-sample",
    type=int,
    help="Sample whose scan is the ICP verification cloud (with "
    "--verifier icp; default the first with a scan). It is left out of the fit.",
)
@click.option("--feature", help="The circle centre in the flange frame: tcp, estimate, or x,y,z in mm.")
@click.option(
    "--feature-base",
    help="Camera on the robot (eye-in-hand): the fixed feature in the base frame: origin (the base "
    "mounting flange), estimate, or x,y,z in mm. Default: what samples.json says, else origin.",
)
@click.option("--inlier-threshold", type=float, help="Inlier residual in mm (default: robust).")
@click.option("--allow-coplanar", is_flag=True, help="Accept flange positions on one plane (warned).")
@click.option(
    "--settings",
    "settings_file",
    type=click.Path(path_type=Path),
    help="TOML/JSON with handeye.flange settings and, for board photos, board / intrinsics / "
    "calibrate_intrinsics (or a profile: its [stages.handeye.settings]); unknown keys are refused.",
)
@click.option(
    "--board",
    "board_spec",
    help="Board of the photos (lengths in mm): chessboard:9x6:25 (inner corners, square), "
    "charuco:5x7:40:20[:DICT_6X6_250] (squares, square, marker), aruco-grid:5x7:40:10[:DICT] (markers, "
    "marker, separation).",
)
@click.option(
    "--intrinsics",
    type=click.Path(path_type=Path),
    help="Camera intrinsics of the photos: OpenCV YAML/XML/JSON (camera_matrix, distortion_coefficients) "
    "or JSON with K (or fx, fy, cx, cy) and dist.",
)
@click.option(
    "--calibrate-intrinsics",
    is_flag=True,
    help="No intrinsics file: calibrate the camera from the same board photos (Zhang, cv2.calibrateCamera).",
)
@click.option("--report", "report_dir", type=click.Path(path_type=Path), help="Write summary and plots here.")
@click.option(
    "--remeasure",
    is_flag=True,
    help="Measure the flange centres from the scans even when the data stores them.",
)
@click.option("-q", "--quiet", is_flag=True, help="Print only the result file name.")
# one parameter per click option (click passes them by name); long because it reads every input
# form the offline command accepts (samples, boards, intrinsics) before calling calibrate()
def hand_eye(
    data_dir: Path,
    output: Path,
    method: str,
    config: str | None,
    units: str | None,
    layout: str,
    quaternion: str,
    flange_model: Path | None,
    flange_d1: str | None,
    verifier: str | None,
    verify_sample: int | None,
    feature: str | None,
    feature_base: str | None,
    inlier_threshold: float | None,
    allow_coplanar: bool,
    settings_file: Path | None,
    board_spec: str | None,
    intrinsics: Path | None,
    calibrate_intrinsics: bool,
    report_dir: Path | None,
    remeasure: bool,
    quiet: bool,
) -> None:
    """Hand-eye calibration of DATA_DIR; writes the transform to -o and prints a summary."""
    from weldcell.plugins.handeye import cli_steps as step
    from weldcell.plugins.handeye.stages import FlangeHandEye
    from weldcell.sdk.handeye_files import write_result

    step.check_flange_model(flange_model)
    s, board_given = _stage_settings(
        settings_file,
        step.flange_overrides(flange_model, flange_d1, verifier, inlier_threshold, allow_coplanar),
    )
    stage = FlangeHandEye(s)
    try:
        ss = read_data(data_dir, layout, units, quaternion)
    except DataError as e:
        raise step.cli_fix(e) from None
    notes = list(ss.notes)
    method = method or step.default_method(ss)
    board = step.BoardOptions(board_spec, intrinsics, calibrate_intrinsics)
    extra = step.board_extra(method, board_given, board, ss.board)
    if remeasure:
        notes.append(step.forget_measured_centres(ss, data_dir))
    asked = step.SolveOptions(method, config, verifier, verify_sample, feature, feature_base)
    result = step.solve(ss, stage, extra, asked, notes)
    step.record_source(result, ss, notes, data_dir, layout)
    write_result(output, result)
    step.print_summary(result, notes, report_dir, quiet, output)
