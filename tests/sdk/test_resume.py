"""Interrupted runs resume exactly where they stopped (docs/runs.md).

One clean scan-and-plan run in the simulated cell is photographed at many instants: the run folder is
copied as it is on the disk at that moment (every write is atomic, so that copy is what a ``kill -9`` at
that instant leaves). Each copy is then resumed in a fresh run and must give the clean run's result (the
same captures, the weld path to numerical identity), while a spy on the simulated robot's driver shows
that no motion was sent twice: a resumed scan continues with the clean run's own motions after its last
capture, a finished weld execution is not repeated, and an interrupted one is refused until ``--redo``.
A real ``kill -9`` of ``weldcell run`` while it writes a capture leaves exactly such a folder; a robot
whose link drops mid-scan gets the resume command, and the resume ends like the clean run; the tactile
job never repeats its tracking.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from weldcell.hal.sim import devices as sim_devices
from weldcell.sdk import jobs
from weldcell.sdk.artifacts import atomic_path, read_json
from weldcell.sdk.cli import main
from weldcell.sdk.errors import DataError, DeviceError, JobError
from weldcell.sdk.jobs import run_job
from weldcell.sdk.plugins import get_plugin_manager

REPO = Path(__file__).resolve().parents[2]
SHIPPED = REPO / "profiles" / "cell1-scan-and-plan-sim.toml"
SCAN, EXECUTE = "scan (gesture-guided)", "execute weld path"
DRIVER = ("_move_linear", "_move_joint", "_follow_path", "_speed_linear")


def small_profile(folder: Path, execute: bool = True) -> Path:
    """The shipped cell-1 simulation, small: 4 views at 1/8 of the camera's resolution, a torch pose per
    seam point (no interpolated ones), no report pictures."""
    f = folder / "small.toml"
    f.write_text(f"""schema = "weldcell/profile@1"
name = "small"
extends = "{SHIPPED.as_posix()}"

[job.settings]
reconnect_delay = 0
max_captures = 4
execute = {str(execute).lower()}

[cell.safety]
path_check_step = "20 mm"

[devices.camera.settings]
decimation = 8

[stages.path.settings]
rho = 0

[output]
report = false
""")
    return f


class DriverSpy:
    """Every command that reaches the simulated robot's driver, in order: (method, rounded arguments)."""

    def __init__(self, mp: pytest.MonkeyPatch) -> None:
        self.log: list[tuple[str, tuple]] = []
        for name in DRIVER:
            orig = getattr(sim_devices.SimRobot, name)

            def spy(robot, *args, _orig=orig, _name=name, **kw):
                rounded = tuple(np.round(np.asarray(a, dtype=float), 9).tobytes() for a in args)
                self.log.append((_name, rounded))
                return _orig(robot, *args, **kw)

            mp.setattr(sim_devices.SimRobot, name, spy)

    def count(self, name: str, start: int = 0) -> int:
        return sum(1 for n, _ in self.log[start:] if n == name)


def weld_points(run_dir: Path) -> np.ndarray:
    doc = read_json(run_dir / "weld_path.json")
    return np.concatenate([np.asarray(s["poses"], dtype=float) for s in doc["seams"]])


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """A clean run, and copies of its run folder taken at many instants (with the spy log length)."""
    folder = tmp_path_factory.mktemp("resume")
    profile = small_profile(folder)
    snaps: dict[str, tuple[Path, int]] = {}
    with pytest.MonkeyPatch.context() as mp:
        spy = DriverSpy(mp)
        holder: dict[str, Path] = {}

        def snap(label: str) -> None:
            dst = folder / "snaps" / label
            if label not in snaps and "run" in holder:
                shutil.copytree(holder["run"], dst)
                snaps[label] = (dst, len(spy.log))

        init = jobs.RunContext.__init__

        def keep_ctx(self, *a, **kw):
            init(self, *a, **kw)
            holder["run"] = self.run_dir

        step = jobs.RunContext.step

        def step_hook(self, name, *a, **kw):
            snap(f"start {name.split(' (')[0]}")  # killed just before the step began
            return step(self, name, *a, **kw)

        add = jobs.RunState.add_capture

        def capture_hook(self, record):
            add(self, record)
            snap(f"capture {len(self.captures)}")  # killed right after a capture was recorded

        set_step = jobs.RunState.set_step

        def done_hook(self, name, **fields):
            set_step(self, name, **fields)
            if name == EXECUTE and fields.get("status") == "done":
                snap("after execute")  # killed once the weld was done, before the run finished

        follow = sim_devices.SimRobot._follow_path

        def weld_hook(robot, *a, **kw):
            snap("mid execute")  # killed while the torch is on the seam
            return follow(robot, *a, **kw)

        mp.setattr(jobs.RunContext, "__init__", keep_ctx)
        mp.setattr(jobs.RunContext, "step", step_hook)
        mp.setattr(jobs.RunState, "add_capture", capture_hook)
        mp.setattr(jobs.RunState, "set_step", done_hook)
        mp.setattr(sim_devices.SimRobot, "_follow_path", weld_hook)
        run_dir, result = run_job(profile, get_plugin_manager(), runs_dir=folder / "runs")
    assert result["status"] == "ok" and result["figures"]["execute"]["status"] == "done"
    return {"profile": profile, "run": run_dir, "result": result, "log": spy.log, "snaps": snaps}


def copy_of(clean, label: str, dst: Path) -> Path:
    """A copy of the run folder as it was at instant ``label`` (tests never change the originals)."""
    shutil.copytree(clean["snaps"][label][0], dst)
    return dst


def resume(clean, label: str, mp: pytest.MonkeyPatch, folder: Path):
    run_dir = copy_of(clean, label, folder / "run")
    spy = DriverSpy(mp)
    run_dir, result = run_job(clean["profile"], get_plugin_manager(), run_dir=run_dir)
    return run_dir, result, spy, clean["snaps"][label][1]


def assert_same_result(clean, run_dir: Path, result: dict) -> None:
    assert result["status"] == "ok"
    a, b = read_json(clean["run"] / "state.json")["captures"], read_json(run_dir / "state.json")["captures"]
    assert len(b) == len(a) == clean["result"]["figures"]["captures"]  # no view captured twice
    for ra, rb in zip(a, b, strict=True):
        assert rb["sha256"] == ra["sha256"] and rb["T_base_flange"] == ra["T_base_flange"]
    np.testing.assert_allclose(weld_points(run_dir), weld_points(clean["run"]), rtol=0, atol=1e-9)

    def program(d: Path) -> list[str]:  # the robot program, without its 'generated at' header line
        text = (d / "programs" / "weld_path.script").read_text()
        return [ln for ln in text.splitlines() if "UTC" not in ln]

    assert program(run_dir) == program(clean["run"])


@pytest.mark.parametrize("label", ["capture 2", "start seams", "after execute"])
def test_killed_at_any_step_resumes_to_the_clean_result_without_repeating_a_motion(
    clean, label, monkeypatch, tmp_path
):
    assert label in clean["snaps"], sorted(clean["snaps"])
    run_dir, result, spy, n_before = resume(clean, label, monkeypatch, tmp_path)
    assert_same_result(clean, run_dir, result)
    log = clean["log"]
    welds = clean["result"]["figures"]["seams"]
    # the weld itself ran exactly once over both attempts
    assert sum(1 for n, _ in log[:n_before] if n == "_follow_path") + spy.count("_follow_path") == welds
    state = read_json(run_dir / "state.json")
    assert all(r["status"] == "done" for r in state["steps"].values())
    if label == "capture 2":
        # the scan went on from its last capture: one joint move back to where it was taken, then the
        # clean run's own motions from that instant on, none of those before it again
        assert spy.log[0][0] == "_move_joint"
        assert spy.log[1:] == log[n_before:]
        assert result["figures"]["scan"]["resumed_captures"] == 2
    else:  # the scan is not touched again; the weld path runs once (not at all when it had run)
        assert spy.log == log[n_before:]
        assert spy.log == [] if label == "after execute" else spy.count("_follow_path") == welds
    assert result["attempt"] == 2


def test_interrupted_weld_is_refused_on_resume_until_redo(clean, monkeypatch, tmp_path):
    snap_dir = copy_of(clean, "mid execute", tmp_path / "run")
    assert read_json(snap_dir / "state.json")["steps"][EXECUTE]["status"] == "running"
    spy = DriverSpy(monkeypatch)
    with pytest.raises(JobError) as err:
        run_job(clean["profile"], get_plugin_manager(), run_dir=snap_dir)
    assert "interrupted after it started" in err.value.message and "0 of 1 seams welded" in err.value.message
    assert f"--resume {snap_dir} --redo 'execute weld path'" in err.value.fix
    assert spy.log == []  # refused before any device opened

    res = CliRunner().invoke(main, ["run", str(clean["profile"]), "--resume", str(snap_dir), "-q"])
    assert res.exit_code == 1 and "--redo" in res.output
    with pytest.raises(Exception, match="no step of this run"):
        run_job(clean["profile"], get_plugin_manager(), run_dir=snap_dir, redo=("welding",))

    run_dir, result = run_job(clean["profile"], get_plugin_manager(), run_dir=snap_dir, redo=("execute",))
    assert_same_result(clean, run_dir, result)
    assert spy.count("_follow_path") == clean["result"]["figures"]["seams"]  # welded again, as asked
    step = read_json(run_dir / "state.json")["steps"][EXECUTE]
    assert step["status"] == "done" and step["attempts"] == 2 and step["redone"]


def test_damaged_capture_is_reported_and_captured_again_or_stops_the_run(clean, monkeypatch, tmp_path):
    # mid-scan: capture 2 truncated on the disk -> taken out (file kept aside) and scanned again
    mid = copy_of(clean, "capture 3", tmp_path / "mid")
    f = mid / "scans" / "002.ply"
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    lines: list[str] = []

    class Lines(jobs.Reporter):
        def info(self, message: str) -> None:
            lines.append(message)

    run_dir, result = run_job(clean["profile"], get_plugin_manager(), run_dir=mid, reporter=Lines())
    assert any("capture 2 (scans/002.ply) is damaged: truncated" in m for m in lines), lines
    assert_same_result(clean, run_dir, result)
    assert (mid / "scans" / "002.ply.discarded-1").is_file()  # nothing captured is deleted
    assert len(read_json(mid / "state.json")["notes"]["discarded_captures"][0]["captures"]) == 1

    # after the scan finished: a changed capture stops the run with a clear error (exit 2)
    done = copy_of(clean, "after execute", tmp_path / "done")
    f = done / "scans" / "002.ply"
    data = bytearray(f.read_bytes())
    data[-5] ^= 0xFF
    f.write_bytes(bytes(data))
    with pytest.raises(DataError) as err:
        run_job(clean["profile"], get_plugin_manager(), run_dir=done)
    assert "capture 2 (scans/002.ply) is damaged: its checksum differs" in err.value.message
    assert "--redo scan" in err.value.fix and err.value.exit_code == 2


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="names fsync'ed files through /proc")
def test_atomic_writes_are_fsynced_and_leave_the_old_file_on_failure(tmp_path, monkeypatch):
    synced: list[str] = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: (synced.append(os.readlink(f"/proc/self/fd/{fd}")), real(fd)))
    target = tmp_path / "a.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]
    with atomic_path(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new"
    assert any(s.endswith(".tmp") for s in synced) and str(tmp_path) in synced  # file, then the folder


def test_robot_that_drops_mid_scan_gets_the_resume_command_and_the_resume_ends_like_a_clean_run(
    clean, monkeypatch, tmp_path
):
    """The same reconnect-or-resume path as the camera and the gesture sensor: a robot link that drops
    and stays away is retried, then the run stops with the command that resumes it (no API hint)."""
    run_dir = copy_of(clean, "capture 2", tmp_path / "dropped")
    moves = {"n": 0}
    move = sim_devices.SimRobot._move_linear

    def drop(robot, *a, **kw):
        moves["n"] += 1
        if moves["n"] >= 30:
            robot.connected = False
        return move(robot, *a, **kw)

    def still_down(robot):
        raise DeviceError("simulated controller still unreachable", "call recover() again")

    monkeypatch.setattr(sim_devices.SimRobot, "_move_linear", drop)
    monkeypatch.setattr(sim_devices.SimRobot, "on_recover", still_down)
    res = CliRunner().invoke(main, ["run", str(clean["profile"]), "--resume", str(run_dir)])
    flat = " ".join(res.output.split())
    assert res.exit_code == 1, flat[-3000:]
    assert "error: robot: " in flat and "still unreachable (after 3 reconnection attempts)" in flat
    assert "recover()" not in res.output
    assert "".join(f"weldcellrun{clean['profile']}--resume{run_dir}".split()) in "".join(res.output.split())
    state = read_json(run_dir / "state.json")
    assert state["steps"][SCAN]["status"] == "failed" and len(state["captures"]) >= 2

    monkeypatch.undo()  # the controller is back
    run_dir, result = run_job(clean["profile"], get_plugin_manager(), run_dir=run_dir)
    assert_same_result(clean, run_dir, result)


def test_kill_9_while_a_capture_is_written_leaves_a_consistent_run_folder(clean, tmp_path):
    """A real SIGKILL of ``weldcell run`` in the middle of writing the third capture's file."""
    code = f"""
import os, signal, sys
from weldcell.sdk import cloud
orig, n = cloud.write_cloud, [0]
def write_then_die(path, c, *a, **kw):
    n[0] += 1
    if n[0] == 3:  # half of the file in its temporary name, then the power goes
        tmp = path.parent / ("." + path.name + ".killed.tmp")
        tmp.write_bytes(b"ply\\nformat binary_little_endian 1.0\\n")
        os.kill(os.getpid(), signal.SIGKILL)
    return orig(path, c, *a, **kw)
cloud.write_cloud = write_then_die
import weldcell.plugins.scan_plan.job as job
job.write_cloud = write_then_die
from weldcell.sdk.cli import main
sys.exit(main(["run", {str(clean["profile"])!r}, "--runs-dir", {str(tmp_path / "runs")!r}, "-q"]))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    (run_dir,) = list((tmp_path / "runs").iterdir())
    state = json.loads((run_dir / "state.json").read_text())
    assert state["steps"][SCAN]["status"] == "running"
    assert not (run_dir / "result.json").exists() and not (run_dir / "scans" / "002.ply").exists()
    # what the real kill left is what the in-process instants above resume from: the same two captures,
    # intact, with the same checkpoints (the half-written third one only as a temporary file)
    snap = read_json(clean["snaps"]["capture 2"][0] / "state.json")
    assert [c["sha256"] for c in state["captures"]] == [c["sha256"] for c in snap["captures"]]
    assert [c["frames"] for c in state["captures"]] == [c["frames"] for c in snap["captures"]]
    assert all(jobs.RunState(run_dir / "state.json", state).check_capture(i) is None for i in range(2))


def test_tactile_tracking_is_never_repeated_by_a_resume(sim_pm, tmp_path, monkeypatch):
    """tactile-track: a resume after the tracking returns its recorded figures without moving; a
    tracking interrupted part way (the tool touched the part) stops the resume until ``--redo track``."""
    import importlib.util

    import weldcell.plugins.handeye as handeye_plugin
    import weldcell.plugins.scan_plan as scan_plan_plugin
    import weldcell.plugins.tactile as tactile_plugin

    cases_file = REPO / "tests" / "tactile" / "test_tactile_job.py"
    spec = importlib.util.spec_from_file_location("h2_tactile", cases_file)
    cases = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cases)  # its profile and planned path
    for mod in (scan_plan_plugin, handeye_plugin, tactile_plugin):
        sim_pm.register(mod, mod.__name__.rsplit(".", 1)[1], distribution="weldcell")
    profile = cases._write(tmp_path, cases._plan(), job_extra='max_time = "1.5 s"\nplots = false')
    run_dir, first = run_job(profile, sim_pm, runs_dir=tmp_path / "runs")
    assert first["status"] == "ok"

    spy = DriverSpy(monkeypatch)
    _, again = run_job(profile, sim_pm, run_dir=run_dir)  # e.g. killed after the tracking, while reporting
    assert spy.log == []
    assert json.dumps(again["figures"]["tactile"], sort_keys=True) == json.dumps(
        first["figures"]["tactile"], sort_keys=True
    )

    state = read_json(run_dir / "state.json")
    state["steps"]["track the seam (Algorithm 2)"]["status"] = "running"  # as a kill -9 leaves it
    (run_dir / "state.json").write_text(json.dumps(state))
    with pytest.raises(JobError) as err:
        run_job(profile, sim_pm, run_dir=run_dir)
    assert "interrupted after it started" in err.value.message
    assert "--redo 'track the seam'" in err.value.fix
    assert spy.log == []  # refused before any device opened (--redo is tested on the weld path above)
