"""``weldcell batch`` on a real two-worker LocalCluster over loopback TCP: mixed good and bad inputs with
results identical to the command run one input at a time, and resume after an interruption (a worker
killed mid-batch and a task past its time limit: test_worker_faults.py)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from weldcell.sdk.scale.batch import expand_inputs, run_batch
from weldcell.sdk.scale.cluster import compare_environments, environment

from .conftest import options

sys_path_tests = str(Path(__file__).resolve().parents[1])
if sys_path_tests not in sys.path:  # the groove cloud of the scan-plan tests
    sys.path.insert(0, sys_path_tests)

TIMING_KEYS = {"runtime_s", "mm_per_s", "timings_s", "source"}


def _probe_inputs(folder: Path, texts: dict[str, str]) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for name, text in texts.items():
        f = folder / f"{name}.txt"
        f.write_text(text)
        out[name] = f
    return out


def _runs(f: Path) -> int:
    r = Path(f"{f}.runs")
    return len(r.read_text().splitlines()) if r.is_file() else 0


def _by_name(summary) -> dict[str, dict]:
    return {Path(k).stem: v for k, v in summary.index["items"].items()}


def test_mixed_good_and_bad_inputs_match_the_command_run_one_at_a_time(cluster, plugins, tmp_path):
    from scan_plan.test_scan_plan_cli import groove_cloud
    from weldcell.sdk.cli import main
    from weldcell.sdk.cloud import write_cloud

    clouds = tmp_path / "clouds"
    clouds.mkdir()
    write_cloud(clouds / "groove1.ply", groove_cloud(10_000, seed=1))  # one seam run per good input: ~2 s
    (clouds / "cut.ply").write_text("ply\nformat ascii 1.0\nelement vertex 10\n")  # header cut short
    (clouds / "notes.md").write_text("not a cloud: the folder expands to *.ply and *.pcd only")
    out = tmp_path / "out"

    summary = run_batch("seam", [str(clouds), str(tmp_path / "missing.ply")], out, options(cluster))

    items = _by_name(summary)
    assert set(items) == {"groove1", "cut", "missing"}
    assert summary.counts["ok"] == 1 and summary.counts["failed"] == 2
    assert "end_header" in items["cut"]["error"]["line"] and items["cut"]["error"]["exit_code"] == 2
    assert "not found" in items["missing"]["error"]["line"]
    index = json.loads((out / "batch.json").read_text())
    assert index["schema"] == "weldcell/batch@1" and index["counts"]["failed"] == 2
    csv = (out / "summary.csv").read_text()
    assert csv.count("\n") == 4 and "seams_found" in csv.splitlines()[0]
    page = (out / "index.html").read_text()
    assert "end_header" in page and "<img" in page  # failures with their error line, metric plots
    assert (out / "failed" / items["cut"]["key"] / "batch-result.json").is_file()

    for name in ("groove1",):  # the same as `weldcell seam` one input at a time
        alone = tmp_path / f"{name}.json"
        res = CliRunner().invoke(main, ["seam", str(clouds / f"{name}.ply"), "-o", str(alone)])
        assert res.exit_code == 0, res.output
        a = json.loads(alone.read_text())
        b = json.loads((out / "results" / items[name]["key"] / "path.json").read_text())
        assert a["seams"] == b["seams"] and a["seams"]
        assert {k: v for k, v in a["metrics"].items() if k not in TIMING_KEYS} == {
            k: v for k, v in b["metrics"].items() if k not in TIMING_KEYS
        }
        assert items[name]["metrics"]["seams_found"] == len(a["seams"])


class _InterruptAfter:
    """A progress sink that presses Ctrl-C after ``n`` finished inputs."""

    def __init__(self, n: int) -> None:
        self.n, self.seen = n, 0

    def start(self, total, title):
        pass

    def advance(self, ok, resumed=False, name="", error=""):
        self.seen += 1
        if self.seen == self.n:
            raise KeyboardInterrupt

    def stop(self):
        pass


def test_resume_after_an_interruption_skips_valid_results_and_redoes_damaged_ones(cluster, plugins, tmp_path):
    files = _probe_inputs(tmp_path / "in", {f"p{i}": f"ok {i}" for i in range(6)})
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        run_batch("probe", [str(tmp_path / "in")], out, options(cluster), progress=_InterruptAfter(3))
    first = json.loads((out / "batch.json").read_text())  # written although interrupted
    done = [r for r in first["items"].values() if r["status"] == "ok"]
    assert len(done) >= 3 and first["counts"]["ok"] == len(done)
    damaged = Path(done[0]["input"])
    (out / "results" / done[0]["key"] / "probe.json").write_text('{"metrics": {"value": -1}}')

    summary = run_batch("probe", [str(tmp_path / "in")], out, options(cluster))

    items = _by_name(summary)
    assert summary.counts["ok"] == 6 and summary.counts["failed"] == 0
    assert not items[damaged.stem].get("resumed") and items[damaged.stem]["metrics"]["value"] == int(
        damaged.stem[1]
    )
    recorded = {Path(r["input"]) for r in done}
    for name, f in files.items():  # nothing finished before the interruption ran again
        if f in recorded:
            assert _runs(f) == (2 if f == damaged else 1), name
        else:  # one still running when the batch was interrupted may run again: it was not complete
            assert 1 <= _runs(f) <= 2, name
    results = sorted(p.name for p in (out / "results").iterdir())
    assert results == sorted(r["key"] for r in items.values())  # each result once
    assert summary.counts["resumed"] >= 2


def test_folders_expand_by_the_command_declaration(tmp_path):
    from weldcell.sdk.descriptors import BatchSpec

    (tmp_path / "a.ply").write_text("x")
    (tmp_path / "b.pcd").write_text("x")
    (tmp_path / "c.txt").write_text("x")
    run = tmp_path / "run1"
    run.mkdir()
    (run / "state.json").write_text("{}")
    seam = BatchSpec(output="path.json", patterns=("*.ply", "*.pcd"))
    assert [p.name for p in expand_inputs([str(tmp_path)], seam)] == ["a.ply", "b.pcd"]
    rec = BatchSpec(output="model.ply", inputs="dir", markers=("scans.json", "state.json"))
    assert [p.name for p in expand_inputs([str(tmp_path)], rec)] == ["run1"]
    assert [p.name for p in expand_inputs([str(run)], rec)] == ["run1"]
    assert [p.name for p in expand_inputs([str(tmp_path / "*.p*")], seam)] == ["a.ply", "b.pcd"]


def test_a_worker_without_a_plugin_is_named_with_what_it_lacks():
    here = environment()
    assert "scan_plan" in here["plugins"]
    worker = json.loads(json.dumps(here))
    worker["plugins"] = {k: tuple(v) for k, v in worker["plugins"].items() if k != "localize"}
    worker["failed"] = {"localize": "ModuleNotFoundError: No module named 'ezdxf'"}
    worker["plugins"]["scan_plan"] = ("weldcell", "0.0.1")
    problems = compare_environments(here, {"tcp://10.0.0.7:4001": worker, "tcp://10.0.0.8:4001": here})
    assert len(problems) == 1
    assert problems[0].startswith("worker tcp://10.0.0.7:4001 lacks")
    assert "plugin 'localize' (it failed to load: ModuleNotFoundError" in problems[0]
    assert "plugin 'scan_plan'" in problems[0] and "it has 0.0.1" in problems[0]


def test_an_unreachable_scheduler_is_one_clear_error(plugins, tmp_path):
    from weldcell.sdk.errors import DeviceError
    from weldcell.sdk.scale.cluster import ClusterOptions

    (tmp_path / "a.txt").write_text("ok 1")
    opts = ClusterOptions(scheduler="tcp://127.0.0.1:1", connect_timeout=1)
    with pytest.raises(DeviceError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:1") as e:
        run_batch("probe", [str(tmp_path / "a.txt")], tmp_path / "out", opts)
    assert e.value.exit_code == 5 and "dask worker" in e.value.fix
    assert not (tmp_path / "out" / "results").exists()
