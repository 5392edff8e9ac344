"""Worker faults on the shared two-worker LocalCluster: a worker killed mid-batch and a task past its time
limit. In their own module, which runs after the others (pytest runs the files in name order): each fault
ends a worker process, and its replacement's start-up (importing weldcell) then slows no other test."""

from __future__ import annotations

import json

from weldcell.sdk.scale.batch import run_batch

from .conftest import options
from .test_batch import _by_name, _probe_inputs, _runs


def test_a_killed_worker_is_recovered_and_nothing_is_lost_or_run_twice(cluster, plugins, tmp_path):
    texts = {f"ok{i}": f"ok {i}" for i in range(5)} | {"once": "kill-once", "bad": "bad"}
    files = _probe_inputs(tmp_path / "in", texts)
    out = tmp_path / "out"

    summary = run_batch("probe", [str(tmp_path / "in")], out, options(cluster, retries=1))

    items = _by_name(summary)
    assert summary.counts == {**summary.counts, "inputs": 7, "ok": 6, "failed": 1}
    for i in range(5):
        assert items[f"ok{i}"]["metrics"]["value"] == i and _runs(files[f"ok{i}"]) == 1
    # its worker process died (SIGKILL) in the first attempt; the second, on a live worker, finished
    assert items["once"]["status"] == "ok" and items["once"]["attempts"] == 2 and _runs(files["once"]) == 2
    assert items["once"]["metrics"]["value"] == 7
    work = out / ".work" / items["once"]["key"]  # the lost attempt's scratch folder is tidied away
    assert (work / "attempts.jsonl").is_file() and not [d for d in work.iterdir() if d.is_dir()]
    # the command's own error is not retried (it would fail again) and does not stop the others
    assert items["bad"]["error"]["type"] == "DataError" and _runs(files["bad"]) == 1
    results = sorted(p.name for p in (out / "results").iterdir())
    assert results == sorted(items[n]["key"] for n in items if n != "bad")
    for key in results:  # each result once, complete, with its checksums
        manifest = json.loads((out / "results" / key / "batch-result.json").read_text())
        assert manifest["status"] == "ok" and "probe.json" in manifest["outputs"]
    assert sorted(p.name for p in (out / "failed").iterdir()) == [items["bad"]["key"]]


def test_a_task_over_its_time_limit_is_stopped_and_recorded(cluster, plugins, tmp_path):
    files = _probe_inputs(tmp_path / "in", {"slow": "sleep", "fast": "ok 3"})
    summary = run_batch(
        "probe",
        [str(f) for f in files.values()],
        tmp_path / "out",
        options(cluster, retries=0, time_limit=1.0),
    )
    items = _by_name(summary)
    assert items["fast"]["status"] == "ok"
    # stopped at its limit, not retried (retries=0), recorded failed with the reason
    assert items["slow"]["status"] == "failed" and "time limit of 1 s" in items["slow"]["error"]["line"]
    assert _runs(files["slow"]) == 1
    assert "--time-limit" in items["slow"]["error"]["fix"]
