"""Malformed hand-eye data (samples.json, the ancorasir layouts) and ``--settings`` files through
``weldcell calibrate hand-eye``: each refused with one line and a fix, exit 2, no traceback."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from weldcell.sdk.geometry import T_from_rpy, invert

from .conftest import assert_refused, run_cli

T_BASE_CAMERA = T_from_rpy(np.radians([-90.0, 0.5, 90.0]), [1.4, 0.0, 0.55])


def base_doc() -> dict:
    """Eight flange positions (metres) and the flange centre each put into the camera."""
    rng = np.random.default_rng(3)
    samples = []
    for i in range(8):
        T = T_from_rpy(
            rng.uniform(-0.4, 0.4, 3), [0.6 + 0.1 * (i % 2), 0.2 * ((i // 2) % 2) - 0.1, 0.4 + 0.05 * i]
        )
        p_cam = invert(T_BASE_CAMERA) @ np.append(T[:3, 3], 1.0)
        samples.append({"T_base_flange": T.tolist(), "p_cam": p_cam[:3].tolist()})
    return {"schema": "weldcell/handeye-samples@1", "config": "eye-on-base", "units": "m", "samples": samples}


def mutate(fn):
    def make():
        doc = copy.deepcopy(base_doc())
        out = fn(doc)
        return doc if out is None else out

    return make


def _set(path, value):
    def fn(doc):
        d = doc
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value

    return mutate(fn)


def _scaled_samples(doc, factor):
    for s in doc["samples"]:
        s["T_base_flange"] = (np.asarray(s["T_base_flange"]) * [[1, 1, 1, factor]] * 1).tolist()
        s["T_base_flange"][3] = [0, 0, 0, 1]
        s["p_cam"] = (np.asarray(s["p_cam"]) * factor).tolist()


def _units_mm_values_m(doc):
    doc["units"] = "mm"


def _units_m_values_mm(doc):
    _scaled_samples(doc, 1000.0)


def _mixed(doc):
    _scaled_samples(doc, 1.0)
    s = doc["samples"][2]
    s["p_cam"] = (np.asarray(s["p_cam"]) * 1000).tolist()


S0 = ("samples", 0)
# name -> (document maker or raw bytes, words the error must contain)
SAMPLE_CASES = {
    "not-json": (b'{"schema": ', "not valid JSON"),
    "invalid-utf8": (b'{"schema": "weldcell/handeye-samples@1", "x": "\xff\xfe"}', "not UTF-8"),
    "binary": (bytes(range(256)) * 4, "not UTF-8"),
    "empty-file": (b"", "not valid JSON"),
    "deep-nesting": (b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
    "a-list": (lambda: [base_doc()], "not a hand-eye samples file"),
    "a-number": (lambda: 42, "not a hand-eye samples file"),
    "wrong-schema": (_set(("schema",), "weldcell/hand-eye@1"), "schema"),
    "no-schema": (mutate(lambda d: d.pop("schema") and None), "schema"),
    "no-samples": (mutate(lambda d: d.pop("samples") and None), "no samples"),
    "samples-empty": (_set(("samples",), []), "no samples"),
    "samples-object": (_set(("samples",), {"0": {}}), "no samples"),
    "samples-numbers": (_set(("samples",), [1, 2, 3, 4]), "sample 0 is a number"),
    "samples-strings": (_set(("samples",), ["a", "b", "c", "d"]), "sample 0 is a string"),
    "sample-null": (_set(("samples", 3), None), "sample 3 is null"),
    "sample-list": (_set(("samples", 1), [[1, 0, 0, 0]]), "sample 1 is a list"),
    "pose-number": (_set((*S0, "T_base_flange"), 5), "T_base_flange is a number"),
    "pose-string": (_set((*S0, "T_base_flange"), "eye(4)"), "T_base_flange is a string"),
    "pose-ragged": (
        _set((*S0, "T_base_flange"), [[1, 0, 0, 0], [0, 1, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
        "rows of unequal length",
    ),
    "pose-3x4": (_set((*S0, "T_base_flange"), np.eye(4)[:3].tolist()), "is 3x4, not 4x4"),
    "pose-text-cell": (
        _set((*S0, "T_base_flange"), [[1, 0, 0, "x"], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
        "not numbers",
    ),
    "pose-nan": (
        _set((*S0, "T_base_flange"), [[1, 0, 0, float("nan")], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
        "NaN",
    ),
    "pose-scaled": (_set((*S0, "T_base_flange"), (np.diag([2.0, 2.0, 2.0, 1.0])).tolist()), "not a rigid"),
    "p-cam-2": (_set((*S0, "p_cam"), [0.1, 0.2]), "p_cam is 2, not 3"),
    "p-cam-text": (_set((*S0, "p_cam"), ["a", "b", "c"]), "not numbers"),
    "p-cam-object": (_set((*S0, "p_cam"), {"x": 1}), "p_cam is an object"),
    "cloud-number": (_set((*S0, "cloud"), 7), "cloud is a number"),
    "normal-zero": (_set((*S0, "normal"), [0, 0, 0]), "not all zero"),
    "normal-ragged": (_set((*S0, "normal"), [[0], [1, 2]]), "normal"),
    "cloud-units-bad": (_set((*S0, "cloud_units"), "inch"), "unknown units"),
    "units-feet": (_set(("units",), "feet"), "unknown units"),
    "units-list": (_set(("units",), ["m"]), "unknown units"),
    "config-unknown": (_set(("config",), "eye-on-elbow"), "unknown hand-eye configuration"),
    "config-number": (_set(("config",), 3), "config is a number"),
    "top-key-misspelt": (mutate(lambda d: d.update(sampels=d["samples"])), "unknown key 'sampels'"),
    "sample-key-misspelt": (
        mutate(lambda d: d["samples"][0].update(T_base_flang=1)),
        "unknown key 'T_base_flang'",
    ),
    "units-mm-values-m": (mutate(_units_mm_values_m), "look like metres"),
    "units-m-values-mm": (mutate(_units_m_values_mm), "millimetres"),
    "mixed-units": (mutate(_mixed), "mixed"),
    "feature-base-word": (_set(("feature_base",), "somewhere"), "feature_base"),
    "feature-base-ragged": (_set(("feature_base",), [[1], [2, 3]]), "feature_base"),
    "feature-base-nan": (_set(("feature_base",), [0, float("inf"), 0]), "feature_base"),
}


def write_case(folder, maker) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    data = maker if isinstance(maker, bytes) else json.dumps(maker()).encode()
    (folder / "samples.json").write_bytes(data)


def test_the_corpus_base_calibrates(tmp_path, capfd):
    write_case(tmp_path / "d", base_doc)
    code, output, native, _ = run_cli(
        capfd, "calibrate", "hand-eye", tmp_path / "d", "-o", tmp_path / "he.json"
    )
    assert code == 0, output
    T = np.asarray(json.loads((tmp_path / "he.json").read_text())["T"])
    assert np.allclose(T, T_BASE_CAMERA, atol=1e-6)


@pytest.mark.parametrize("case", sorted(SAMPLE_CASES))
def test_calibrate_refuses_malformed_samples(tmp_path, capfd, case):
    maker, words = SAMPLE_CASES[case]
    write_case(tmp_path / "d", maker)
    args = ["calibrate", "hand-eye", tmp_path / "d", "-o", tmp_path / "he.json"]
    assert_refused(capfd, args, 2, words)
    assert not (tmp_path / "he.json").exists()


def _calib_data(entries) -> bytes:
    return json.dumps(entries).encode()


GOOD_ENTRY = {
    "p_cam": [100.0, 20.0, 800.0],
    "p_robot": [0.5, 0.1, 0.3],
    "robot_pose": [0.5, 0.1, 0.3, 1, 0, 0, 0],
}
# ancorasir layouts: (file name -> bytes) and the words of the error
LAYOUT_CASES = {
    "calib-not-object": ({"calib_data.json": b"[1, 2, 3]"}, "is a list, not an object"),
    "calib-empty": ({"calib_data.json": b"{}"}, "lists no samples"),
    "calib-entry-number": ({"calib_data.json": _calib_data({"0": 5})}, "sample 0 is a number"),
    "calib-no-p-cam": ({"calib_data.json": _calib_data({"0": {"p_robot": [1, 2, 3]}})}, "has no 'p_cam'"),
    "calib-p-cam-text": ({"calib_data.json": _calib_data({"0": {**GOOD_ENTRY, "p_cam": "here"}})}, "p_cam"),
    "calib-pose-short": (
        {"calib_data.json": _calib_data({"0": {**GOOD_ENTRY, "robot_pose": [1, 2]}})},
        "robot_pose is 2, not 7",
    ),
    "calib-invalid-utf8": ({"calib_data.json": b'{"0": "\xff"}'}, "not UTF-8"),
    "npy-garbage": ({"p_camera_mat.npy": b"not numpy", "p_robot_mat.npy": b"no"}, "not a numeric .npy"),
    "npy-shape": ({"p_camera_mat.npy": "np:2x5", "p_robot_mat.npy": "np:2x5"}, "3 x N"),
    "npy-mismatch": ({"p_camera_mat.npy": "np:3x5", "p_robot_mat.npy": "np:3x6"}, "do not match"),
    "npy-nan": ({"p_camera_mat.npy": "np:nan", "p_robot_mat.npy": "np:3x5"}, "NaN"),
    "kinect-text": ({"readRobot.txt": b"a b c d e f\n", "measureRobot.txt": b"1 2 3\n"}, "cannot read"),
    "kinect-short": ({"readRobot.txt": b"1 2 3\n", "measureRobot.txt": b"1 2 3\n"}, "do not match"),
    "kinect-binary": ({"readRobot.txt": b"\xff\xfe\x00\x01", "measureRobot.txt": b"1 2 3\n"}, "cannot read"),
}


def _npy(spec: str) -> bytes:
    import io

    buf = io.BytesIO()
    if spec == "np:nan":
        arr = np.full((3, 5), np.nan)
    else:
        r, c = map(int, spec[3:].split("x"))
        arr = np.arange(r * c, dtype=float).reshape(r, c) + 100
    np.save(buf, arr)
    return buf.getvalue()


@pytest.mark.parametrize("case", sorted(LAYOUT_CASES))
def test_calibrate_refuses_malformed_ancorasir_layouts(tmp_path, capfd, case):
    files, words = LAYOUT_CASES[case]
    d = tmp_path / "d"
    d.mkdir()
    for name, data in files.items():
        (d / name).write_bytes(_npy(data) if isinstance(data, str) else data)
    assert_refused(capfd, ["calibrate", "hand-eye", d, "-o", tmp_path / "he.json"], 2, words)


# --settings files: (file name, bytes, exit code, words)
SETTINGS_CASES = {
    "toml-syntax": ("s.toml", b"flange_d1 = = 63\n", 2, "not valid TOML"),
    "json-syntax": ("s.json", b'{"flange_d1": 63,,}', 2, "not valid JSON"),
    "toml-invalid-utf8": ("s.toml", b'flange_model = "\xff\xfe"\n', 2, "not UTF-8"),
    "binary": ("s.toml", bytes(range(256)), 2, "not UTF-8"),
    "unknown-key": ("s.toml", b"flange_dl = 63\n", 2, "unknown key 'flange_dl'"),
    "unknown-key-json": ("s.json", b'{"voxle": 0.002}', 2, "unknown key 'voxle'"),
    "unknown-key-nested": ("s.toml", b"[stages.handeye.settings]\nvoxle = 0.002\n", 2, "unknown key 'voxle'"),
    "misspelt-settings-table": (
        "s.toml",
        b"[stages.handeye.setings]\nvoxel = 0.002\n",
        2,
        "unknown key 'setings'",
    ),
    "wrong-type": ("s.toml", b'voxel = "big"\n', 2, "voxel"),
    "negative": ("s.toml", b"voxel = -0.001\n", 2, "voxel"),
    "bad-literal": ("s.json", b'{"verifier": "magic"}', 2, "verifier"),
    "json-list": ("s.json", b"[1, 2]", 2, "is a list, not an object"),
    "yaml-suffix": ("s.yaml", b"voxel: 0.002\n", 2, "not a .toml or .json"),
    "stages-number": ("s.toml", b"stages = 3\n", 2, "stages is a number"),
    "settings-string": ("s.toml", b'[stages.handeye]\nsettings = "x"\n', 2, "settings is a string"),
    "profile-broken": (
        "s.toml",
        b'schema = "weldcell/profile@1"\nname = "x"\n[job]\nname = 5\n',
        3,
        "job.name",
    ),
}


@pytest.mark.parametrize("case", sorted(SETTINGS_CASES))
def test_calibrate_refuses_malformed_settings_files(tmp_path, capfd, case):
    name, data, code, words = SETTINGS_CASES[case]
    write_case(tmp_path / "d", base_doc)
    (tmp_path / name).write_bytes(data)
    args = [
        "calibrate",
        "hand-eye",
        tmp_path / "d",
        "-o",
        tmp_path / "he.json",
        "--settings",
        tmp_path / name,
    ]
    assert_refused(capfd, args, code, words)
    assert not (tmp_path / "he.json").exists()


def test_settings_file_errors_name_the_valid_keys(tmp_path, capfd):
    write_case(tmp_path / "d", base_doc)
    (tmp_path / "s.toml").write_bytes(b"flange_dl = 63\n")
    args = [
        "calibrate",
        "hand-eye",
        tmp_path / "d",
        "-o",
        tmp_path / "he.json",
        "--settings",
        tmp_path / "s.toml",
    ]
    text = assert_refused(capfd, args, 2, "did you mean 'flange_d1'")
    assert "valid keys:" in text and "voxel" in text and "e_d" in text
    assert_refused(capfd, [*args[:-1], tmp_path / "absent.toml"], 2, "not found")


def test_units_option_is_checked_against_the_values_too(tmp_path, capfd):
    """``--units mm`` on metre data is refused like a file that says so; the fix names the option."""
    write_case(tmp_path / "d", base_doc)
    args = ["calibrate", "hand-eye", tmp_path / "d", "-o", tmp_path / "he.json", "--units", "mm"]
    assert_refused(capfd, args, 2, "look like metres", "--units m")
    assert not (tmp_path / "he.json").exists()


def test_the_report_is_written_whole(tmp_path, capfd):
    """The offline report's files are moved into place atomically: all present, no temporaries."""
    write_case(tmp_path / "d", base_doc)
    rep = tmp_path / "rep"
    args = ["calibrate", "hand-eye", tmp_path / "d", "-o", tmp_path / "he.json", "--report", rep]
    code, output, _, _ = run_cli(capfd, *args)
    assert code == 0, output
    names = sorted(p.name for p in rep.iterdir())
    assert names == ["report.html", "report.md", "residuals.png", "summary.txt"]
    assert "T_base_camera" in (rep / "summary.txt").read_text()
    assert (rep / "residuals.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("case", ["cut-at-half", "random-bytes", "declares-50M-binary"])
def test_calibrate_refuses_a_malformed_flange_model(tmp_path, capfd, case):
    from .test_bad_clouds import PLY_CASES

    data, words = PLY_CASES[case]
    write_case(tmp_path / "d", base_doc)
    (tmp_path / "flange.ply").write_bytes(data)
    args = ["calibrate", "hand-eye", tmp_path / "d", "-o", tmp_path / "he.json", "--flange-model"]
    assert_refused(capfd, [*args, tmp_path / "flange.ply"], 2, "flange.ply", words)
