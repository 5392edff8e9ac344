"""Malformed scans.json files and hand-eye result files through ``weldcell reconstruct`` (and the
hand-eye result reader): each refused with one line and a fix, exit 2, no traceback."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from weldcell.plugins.handeye.samples_io import read_result
from weldcell.sdk.cloud import PointCloud, write_cloud
from weldcell.sdk.errors import DataError
from weldcell.sdk.geometry import T_from_rpy

from .conftest import assert_refused, run_cli

T_FLANGE_CAMERA = T_from_rpy((0.0, 0.0, 0.0), (0.0, -0.06, 0.04))


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    """Two small camera-frame views of a plate (metres)."""
    d = tmp_path_factory.mktemp("views")
    rng = np.random.default_rng(4)
    for i in range(2):
        pts = np.column_stack([rng.uniform(-0.08, 0.08, (3000, 2)), 0.4 + rng.normal(0, 2e-4, 3000)])
        write_cloud(d / f"{i:03d}.ply", PointCloud(pts, frame="camera"))
    return d


def base_doc() -> dict:
    scans = []
    for i in range(2):
        T = T_from_rpy((np.pi, 0.0, 0.0), (0.4 + 0.02 * i, 0.0, 0.45))
        scans.append({"cloud": f"{i:03d}.ply", "T_base_flange": T.tolist(), "stamp": float(i)})
    return {"schema": "weldcell/posed-scans@1", "units": "m", "scans": scans}


def _set(path, value):
    def make():
        doc = copy.deepcopy(base_doc())
        d = doc
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
        return doc

    return make


def _drop(path):
    def make():
        doc = copy.deepcopy(base_doc())
        d = doc
        for k in path[:-1]:
            d = d[k]
        del d[path[-1]]
        return doc

    return make


S1 = ("scans", 1)
SCANS_CASES = {
    "not-json": (b'{"schema": "weldcell/posed-scans@1", ', "not valid JSON"),
    "invalid-utf8": (b'{"schema": "\xff"}', "not UTF-8"),
    "binary": (bytes(range(256)), "not UTF-8"),
    "empty-file": (b"", "not valid JSON"),
    "a-list": (lambda: [base_doc()], "expected a JSON object"),
    "wrong-schema": (_set(("schema",), "weldcell/posed-scans@9"), "schema"),
    "top-key-misspelt": (_set(("T_flange_cam",), T_FLANGE_CAMERA.tolist()), "unknown key 'T_flange_cam'"),
    "units-inch": (_set(("units",), "inch"), "unknown units"),
    "units-number": (_set(("units",), 1000), "unknown units"),
    "scans-object": (_set(("scans",), {"0": {}}), "'scans' must be a list"),
    "scans-empty": (_set(("scans",), []), "lists no scans"),
    "scan-number": (_set(S1, 5), "scan 1 names no cloud file"),
    "scan-no-cloud": (_drop((*S1, "cloud")), "scan 1 names no cloud file"),
    "cloud-number": (_set((*S1, "cloud"), 12), "'cloud' is a number"),
    "scan-key-misspelt": (_set((*S1, "T_base_flang"), 1), "unknown key 'T_base_flang'"),
    "no-pose": (_drop((*S1, "T_base_flange")), "has no pose"),
    "pose-string": (_set((*S1, "T_base_flange"), "eye"), "not a finite 4x4"),
    "pose-ragged": (_set((*S1, "T_base_flange"), [[1, 0, 0], [0, 1, 0, 0]]), "not a finite 4x4"),
    "pose-nan": (_set((*S1, "T_base_flange"), [[float("nan")] * 4] * 4), "not a finite 4x4"),
    "pose-scaled": (_set((*S1, "T_base_flange"), np.diag([3.0, 3.0, 3.0, 1.0]).tolist()), "not a rigid"),
    "stamp-text": (_set((*S1, "stamp"), "12:00:01"), "stamp is a string"),
    "stamp-date": (_set((*S1, "stamp"), "2026-11-24T10:00:00Z"), "stamp is a string"),
    "stamp-text-first": (_set(("scans", 0, "stamp"), "t0"), "stamp is a string"),
    "stamp-null": (_set((*S1, "stamp"), None), "stamp is null"),
    "stamp-nan": (_set((*S1, "stamp"), float("nan")), "not a finite number"),
    "stamp-list": (_set((*S1, "stamp"), [1]), "stamp is a list"),
    "cloud-missing": (_set((*S1, "cloud"), "absent.ply"), "not found"),
    "roi-ragged": (_set(("roi_min",), [0, [1]]), "roi_min"),
    "roi-text": (_set(("roi_max",), "high"), "roi_max"),
    "hand-eye-bad": (_set(("T_flange_camera",), [[1, 0]]), "hand-eye"),
    "units-mm-clouds-m": (_set(("units",), "mm"), "looks like m"),
}


def write_case(folder, clouds, maker) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(2):
        (folder / f"{i:03d}.ply").write_bytes((clouds / f"{i:03d}.ply").read_bytes())
    data = maker if isinstance(maker, bytes) else json.dumps(maker()).encode()
    (folder / "scans.json").write_bytes(data)


def test_the_corpus_base_reconstructs(tmp_path, capfd, clouds):
    write_case(tmp_path / "d", clouds, base_doc)
    args = ["reconstruct", tmp_path / "d", "-o", tmp_path / "m.ply", "--mount", "0,-60mm,40mm,0,0,0"]
    code, output, native, _ = run_cli(capfd, *args)
    assert code == 0, output
    assert (tmp_path / "m.ply").is_file() and native.strip() == ""


@pytest.mark.parametrize("case", sorted(SCANS_CASES))
def test_reconstruct_refuses_a_malformed_scans_json(tmp_path, capfd, clouds, case):
    maker, words = SCANS_CASES[case]
    write_case(tmp_path / "d", clouds, maker)
    args = ["reconstruct", tmp_path / "d", "-o", tmp_path / "m.ply", "--mount", "0,-60mm,40mm,0,0,0"]
    assert_refused(capfd, args, 2, words)
    assert not (tmp_path / "m.ply").exists()


def _he(**kw) -> dict:
    doc = {
        "schema": "weldcell/hand-eye@1",
        "transform": "T_flange_camera",
        "config": "eye-in-hand",
        "method": "flange",
        "T": T_FLANGE_CAMERA.tolist(),
        "units": "m",
    }
    doc.update(kw)
    return doc


def _T(scale: float) -> list:
    T = T_FLANGE_CAMERA.copy()
    T[:3, 3] *= scale
    return T.tolist()


HAND_EYE_CASES = {
    "not-json": (b'{"T": [[1, 0', "not valid JSON"),
    "invalid-utf8": (b'{"T": "\xff"}', "UTF-8"),
    "a-list": (b"[[1, 0, 0, 0]]", "not a hand-eye file"),
    "no-T": (json.dumps({"transform": "T_flange_camera"}).encode(), "no rigid 4x4 'T'"),
    "T-ragged": (json.dumps(_he(T=[[1, 0, 0], [0, 1]])).encode(), "no rigid 4x4 'T'"),
    "T-text": (json.dumps(_he(T="identity")).encode(), "no rigid 4x4 'T'"),
    "T-scaled": (json.dumps(_he(T=np.diag([2.0, 2, 2, 1]).tolist())).encode(), "no rigid 4x4 'T'"),
    "eye-on-base": (json.dumps(_he(transform="T_base_camera")).encode(), "not T_flange_camera"),
    "units-unknown": (json.dumps(_he(units="yards")).encode(), "unknown units"),
    "units-mm-values-m": (json.dumps(_he(units="mm")).encode(), "look like metres"),
    "units-m-values-mm": (json.dumps(_he(T=_T(1000.0))).encode(), "look like millimetres"),
}


@pytest.mark.parametrize("case", sorted(HAND_EYE_CASES))
def test_reconstruct_refuses_a_malformed_hand_eye_file(tmp_path, capfd, clouds, case):
    data, words = HAND_EYE_CASES[case]
    write_case(tmp_path / "d", clouds, base_doc)
    (tmp_path / "he.json").write_bytes(data)
    args = ["reconstruct", tmp_path / "d", "-o", tmp_path / "m.ply", "--hand-eye", tmp_path / "he.json"]
    assert_refused(capfd, args, 2, words)
    assert not (tmp_path / "m.ply").exists()


RESULT_CASES = {
    "a-number": (b"3", "not an object"),
    "wrong-schema": (json.dumps(_he(schema="x")).encode(), "not a hand-eye result"),
    "no-method": (json.dumps({k: v for k, v in _he().items() if k != "method"}).encode(), "no 'method'"),
    "transform-number": (json.dumps(_he(transform=4)).encode(), "'transform' is a number"),
    "T-ragged": (json.dumps(_he(T=[[1], [2, 3]])).encode(), "rows of unequal length"),
    "T-not-rigid": (json.dumps(_he(T=np.diag([1.0, 1, 2, 1]).tolist())).encode(), "not a rigid"),
    "units-mm": (json.dumps(_he(units="mm")).encode(), "in metres"),
    "T-in-mm": (json.dumps(_he(T=_T(1000.0))).encode(), "millimetres"),
    "metrics-list": (json.dumps(_he(metrics=[1])).encode(), "metrics is a list"),
    "residuals-text": (json.dumps(_he(residuals_m=["a"], inliers=[True])).encode(), "residuals_m"),
    "inliers-mismatch": (json.dumps(_he(residuals_m=[0.1, 0.2], inliers=[True])).encode(), "one value per"),
    "invalid-utf8": (b'{"schema": "\xff"}', "not UTF-8"),
}


@pytest.mark.parametrize("case", sorted(RESULT_CASES))
def test_hand_eye_result_reader_refuses_malformed_files(tmp_path, case):
    data, words = RESULT_CASES[case]
    f = tmp_path / "handeye.json"
    f.write_bytes(data)
    with pytest.raises(DataError) as e:
        read_result(f)
    assert words in e.value.message and e.value.fix and "\n" not in e.value.message


def test_hand_eye_result_reader_reads_what_calibrate_writes(tmp_path):
    f = tmp_path / "handeye.json"
    f.write_text(json.dumps(_he(residuals_m=[1e-4, None], inliers=[True, False])))
    res = read_result(f)
    assert np.allclose(res.T, T_FLANGE_CAMERA) and res.outliers == [1]
