"""``weldcell batch`` and ``weldcell study`` on the command line (in-process: ``--workers 0``)."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner
from weldcell.sdk.cli import main

from .probe_plugin import MODULE
from .test_study import PROFILE


@pytest.fixture
def cli(plugins, monkeypatch):
    import weldcell.plugins.scale_out as scale_out

    if "scale_out" not in plugins.providers:  # installed through its entry point, or not (yet)
        plugins.register(scale_out, name="scale_out")
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)

    def run(*args):
        return CliRunner().invoke(main, [str(a) for a in args])

    return run


def test_batch_command_runs_every_input_and_exits_1_when_one_failed(cli, tmp_path):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.txt").write_text("ok 2")
    (tmp_path / "in" / "b.txt").write_text("bad")
    res = cli(
        "batch",
        "probe",
        tmp_path / "in",
        "-o",
        tmp_path / "out",
        "--workers",
        "0",
        "--args",
        "--scale 3",
        "-q",
    )
    assert res.exit_code == 1, res.output
    assert "1 ok (0 from an earlier run), 1 failed, of 2 inputs" in res.output
    assert "1 of 2 inputs failed" in res.output
    index = json.loads((tmp_path / "out" / "batch.json").read_text())
    assert index["args"] == ["--scale", "3"]
    ok = [r for r in index["items"].values() if r["status"] == "ok"]
    assert ok[0]["metrics"]["value"] == 6.0  # --args reached the command


def test_batch_names_the_batchable_commands_for_an_unknown_one(cli, tmp_path):
    res = cli("batch", "plugins", tmp_path, "-o", tmp_path / "out", "--workers", "0")
    assert res.exit_code == 2
    assert (
        "not a batchable command" in res.output
        and "calibrate hand-eye" in res.output
        and "seam" in res.output
    )


def test_study_command_prints_the_distribution(cli, tmp_path):
    profile = tmp_path / "p.toml"
    profile.write_text(PROFILE)
    res = cli(
        "study",
        profile,
        "--trials",
        3,
        "--vary",
        "job.settings.offset=uniform(1 mm, 2 mm)",
        "-o",
        tmp_path / "out",
        "--workers",
        "0",
        "-q",
        "--seed",
        5,
    )
    assert res.exit_code == 0, res.output
    assert "3 ok, 0 failed (failure rate 0.0 %)" in res.output
    assert "offset_mm" in res.output and "mean 1." in res.output
    assert MODULE  # the probe job comes from the test plugin


def test_study_command_runs_a_trial_function_by_rows(cli, tmp_path):
    res = cli(
        "study",
        "--function",
        f"{MODULE}:probe_trial",
        "--trials",
        3,
        "--vary",
        "row=cycle(a, bad, c)",
        "--vary",
        "x=uniform(1 mm, 2 mm)",
        "--by",
        "row",
        "-o",
        tmp_path / "out",
        "--workers",
        "0",
        "-q",
    )
    assert res.exit_code == 0, res.output
    assert f"study {MODULE}:probe_trial: 2 ok, 1 failed (failure rate 33.3 %)" in res.output
    assert "row = a: 1 ok, 0 failed" in res.output and "row = bad: 0 ok, 1 failed" in res.output
    study = json.loads((tmp_path / "out" / "study.json").read_text())
    assert study["function"] == f"{MODULE}:probe_trial" and study["profile"] is None
    assert 1 < study["groups"]["c"]["statistics"]["value"]["mean"] < 2  # x drawn in metres, x 1000

    res = cli("study", "--trials", 2, "-o", tmp_path / "o2", "--workers", "0", "-q")
    assert res.exit_code == 2 and "one of the two" in res.output
