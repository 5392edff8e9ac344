"""``weldcell study``: seeded trials that reproduce exactly (on the cluster and in-process), drawn values
with units, the failure rate, trial profiles that run alone, and the answers to bad ``--vary`` options."""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.sdk.errors import UsageError
from weldcell.sdk.scale.study import draw_trials, parse_vary, run_study

from .conftest import options

PROFILE = """schema = "weldcell/profile@1"
name = "probe-study"
[job]
name = "probe-job"
[job.settings]
gain = 0.5
"""
VARY = [
    "job.settings.offset=uniform(-5 mm, 5 mm)",
    "job.settings.gain=normal(1, 0.1)",
    "job.settings.mode=choice(ok, ok, ok, fail)",
]


def _trials(study: dict) -> list[dict]:
    keep = ("trial", "seed", "values", "status", "figures")
    return [{k: t.get(k) for k in keep} for t in study["trials"].values()]


def test_a_seeded_study_reproduces_exactly_on_the_cluster_and_in_process(cluster, plugins, tmp_path):
    from weldcell.sdk.jobs import run_job

    profile = tmp_path / "probe.toml"
    profile.write_text(PROFILE)
    a = run_study(profile, 8, VARY, tmp_path / "a", options(cluster), seed=42)
    b = run_study(profile, 8, VARY, tmp_path / "b", options(None), seed=42)  # --workers 0

    assert _trials(a) == _trials(b)
    assert a["statistics"] == b["statistics"]
    offsets = [t["values"]["job.settings.offset"] for t in a["trials"].values()]
    assert all(-0.005 <= o <= 0.005 for o in offsets) and len(set(offsets)) == 8  # drawn in metres
    failed = [t for t in a["trials"].values() if t["values"]["job.settings.mode"] == "fail"]
    assert 0 < len(failed) < 8 and all(t["status"] == "failed" for t in failed)
    assert a["failure_rate"] == pytest.approx(len(failed) / 8)
    ok = [t for t in a["trials"].values() if t["status"] == "ok"]
    errs = [t["figures"]["error_mm"] for t in ok]
    st = a["statistics"]["error_mm"]
    assert st["n"] == len(ok) and st["mean"] == pytest.approx(np.mean(errs))
    assert st["std"] == pytest.approx(np.std(errs, ddof=1)) and st["p95"] == pytest.approx(
        np.percentile(errs, 95)
    )
    for t in ok:  # the figures follow the drawn values: offset in mm, seed of the trial
        assert t["figures"]["offset_mm"] == pytest.approx(t["values"]["job.settings.offset"] * 1000)
        assert t["figures"]["seed"] == t["seed"]
    assert (tmp_path / "a" / "trials.csv").read_text().count("\n") == 9
    assert "error_mm" in (tmp_path / "a" / "statistics.csv").read_text()
    assert "failure rate" in (tmp_path / "a" / "index.html").read_text()

    # a trial's profile runs alone with the same result
    first = ok[0]
    _, alone = run_job(
        tmp_path / "a" / "trials" / f"{first['trial']:05d}" / "profile.toml",
        plugins,
        runs_dir=tmp_path / "alone",
    )
    assert alone["figures"]["error_mm"] == first["figures"]["error_mm"]

    c = run_study(profile, 8, VARY, tmp_path / "a", options(None), seed=42)  # again: nothing re-run
    assert c["counts"]["resumed"] == 8 and _trials(c) == _trials(a)


def test_trial_i_depends_on_the_seed_not_on_the_number_of_trials():
    vary = dict(parse_vary(v) for v in VARY)
    assert draw_trials(3, 4, vary) == draw_trials(3, 20, vary)[:4]
    assert draw_trials(3, 4, vary) != draw_trials(4, 4, vary)
    key, d = parse_vary("devices.robot.settings.model=choice(ur5, 'ur10e')")
    assert d.params == ("ur5", "ur10e") and d.unit is None
    key, d = parse_vary("job.settings.worker.placement_angle=normal(0 deg, 2 deg)")
    assert d.unit == "rad" and d.params[1] == pytest.approx(np.radians(2))


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("job.settings.offset", "not KEY=DISTRIBUTION"),
        ("job.settings.offset=gauss(0,1)", "unknown distribution"),
        ("job.settings.offset=uniform(5 mm, 1 mm)", "a < b"),
        ("job.settings.offset=uniform(1 mm, 2 deg)", "different units"),
        ("job.settings.offset=normal(0, -1)", "sigma >= 0"),
        ("job.settings.offset=uniform(1, 2 mm)", "a unit, or none"),
        ("cell.seed=uniform(1,2)", "set by the study"),
    ],
)
def test_bad_vary_options_are_refused_clearly(text, words):
    with pytest.raises(UsageError, match=words):
        parse_vary(text)


def test_a_study_refuses_unknown_keys_before_running_anything(plugins, tmp_path):
    from weldcell.sdk.errors import ProfileError

    profile = tmp_path / "probe.toml"
    profile.write_text(PROFILE)
    with pytest.raises(ProfileError, match="no_such_key"):
        run_study(profile, 3, ["job.settings.no_such_key=uniform(0,1)"], tmp_path / "o", options(None))
    assert not (tmp_path / "o" / "study.json").exists()


def test_a_study_refuses_a_hardware_profile(plugins, tmp_path):
    hw = tmp_path / "hw.toml"
    hw.write_text(PROFILE + '[devices.robot]\nplugin = "robot.ur-rtde"\nsettings = { host = "127.0.0.1" }\n')
    with pytest.raises(UsageError, match="simulated cells only"):
        run_study(hw, 2, [], tmp_path / "o", options(None))


PROTOCOL = """
import numpy as np
from weldcell.sdk.errors import DataError


def trial(values, seed, trial):
    if values["row"] == "bad":
        raise DataError("row 'bad' asked to fail", "use another row")
    if values["row"] == "bug":
        raise ZeroDivisionError("a bug in the protocol")
    noise = float(np.random.default_rng(seed).normal())
    return {"error_mm": values["x"] * 1000 + noise, "trial": trial, "parts": {"n": 2}}
"""


def test_a_trial_function_study_reproduces_and_groups_its_rows(cluster, plugins, tmp_path, monkeypatch):
    """``--function``: a protocol that is not a whole job. Its module lies in a folder only this process
    has on sys.path: the workers get it from the study; rows by cycle(), statistics per row (--by)."""
    import sys

    (tmp_path / "protos").mkdir()
    (tmp_path / "protos" / "study_protocol_probe.py").write_text(PROTOCOL)
    monkeypatch.setattr(sys, "path", [str(tmp_path / "protos"), *sys.path])
    vary = ["row=cycle(a, b, bad, bug)", "x=uniform(1 mm, 2 mm)"]
    fn = "study_protocol_probe:trial"
    a = run_study(None, 4, vary, tmp_path / "a", options(cluster), seed=7, function=fn, by="row")
    b = run_study(None, 4, vary, tmp_path / "b", options(None), seed=7, function=fn, by="row")

    assert _trials(a) == _trials(b) and a["statistics"] == b["statistics"]
    rows = [t["values"]["row"] for t in sorted(a["trials"].values(), key=lambda t: t["trial"])]
    assert rows == ["a", "b", "bad", "bug"]  # trial i takes value i mod 4
    assert draw_trials(7, 6, dict(parse_vary(v) for v in vary))[5][1]["row"] == "b"
    assert list(a["groups"]) == ["a", "b", "bad", "bug"]
    assert a["groups"]["a"]["counts"]["ok"] == 1 and a["groups"]["a"]["statistics"]["parts.n"]["mean"] == 2
    assert a["groups"]["bad"]["failure_rate"] == 1 and a["failure_rate"] == 0.5
    bad = [t for t in a["trials"].values() if t["values"]["row"] == "bad"]
    assert all(t["error"]["type"] == "DataError" and t["error"]["fix"] == "use another row" for t in bad)
    bug = next(t for t in a["trials"].values() if t["values"]["row"] == "bug")
    assert bug["status"] == "failed" and bug["error"]["type"] == "ZeroDivisionError"
    assert "Traceback" in (tmp_path / "a" / "trials" / f"{bug['trial']:05d}" / "log.txt").read_text()
    for t in a["trials"].values():
        if t["status"] == "ok":
            assert t["figures"]["trial"] == t["trial"]
            assert 1 < t["figures"]["error_mm"] - np.random.default_rng(t["seed"]).normal() < 2
    groups_csv = (tmp_path / "a" / "groups.csv").read_text()
    assert (
        groups_csv.startswith("row,metric,n,mean")
        and "a,error_mm,1," in groups_csv
        and "b,error_mm,1," in groups_csv
    )

    with pytest.raises(UsageError, match="cannot import"):
        run_study(None, 2, [], tmp_path / "c", options(None), function="no_such_module_xyz:trial")
    with pytest.raises(UsageError, match="one of the two"):
        run_study(None, 2, [], tmp_path / "c", options(None))
    with pytest.raises(UsageError, match="not a varied key"):
        run_study(None, 2, vary, tmp_path / "c", options(None), function=fn, by="y")
