"""Issue 14: throughput of ``weldcell batch`` on 1 and 2 local Dask workers, and the per-task overhead.

Run:  .venv/bin/python benchmarks/scale_out.py [--tasks 8] [--seconds 1.0] [--noop 100]

* speed-up: ``--tasks`` inputs of a CPU-bound command that burns ``--seconds`` of CPU each (a pure-Python
  loop: it holds the GIL, as the methods' Python parts do), run by ``weldcell batch`` (the whole path:
  files, manifests, atomic publication, index, report) on a LocalCluster of 1 and of 2 worker processes;
  speed-up = wall(1 worker) / wall(2 workers). Target: >= 1.8x on 2 cores for tasks >= 1 s.
* overhead: ``--noop`` inputs of a command that does nothing, on 2 workers: (wall of the task loop) / N
  is what a task costs beyond its own work through ``weldcell batch``; raw Dask (``client.submit`` of
  a no-op, same cluster) beside it. Target: <= 50 ms per task.
* the machine's 1-minute load average before and after each measurement (the machine is shared).

The command comes from this file registered as a plugin (``plugin_modules=("scale_out",)``; the workers
import it from ``benchmarks/`` on their PYTHONPATH). Cluster start-up and the worker check are timed
apart. Prints markdown; nothing is asserted.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import click
from weldcell.sdk.descriptors import BatchSpec, CommandSpec
from weldcell.sdk.hookspecs import hookimpl

MODULE = "scale_out"


@click.command("burn")
@click.argument("source", type=click.Path(path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(path_type=Path))
def burn_command(source: Path, output: Path) -> None:
    """Burn the CPU seconds SOURCE holds, in pure Python."""
    seconds = float(source.read_text())
    t0 = time.process_time()
    n = 0
    while time.process_time() - t0 < seconds:
        for _ in range(10_000):
            n += 1
    output.write_text(f'{{"metrics": {{"loops": {n}}}}}\n')


@hookimpl
def weldcell_register_commands(register) -> None:
    register(
        CommandSpec(
            name="burn",
            command=burn_command,
            summary="benchmark load",
            batch=(BatchSpec(output="burn.json"),),
        )
    )


def _load() -> float:
    return os.getloadavg()[0]


def _inputs(folder: Path, n: int, seconds: float) -> list[str]:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        (folder / f"t{i:04d}.txt").write_text(str(seconds))
    return [str(folder)]


def timed_batch(cluster, inputs: list[str], out: Path) -> tuple[float, float, dict]:
    """(wall of the whole batch, wall of its task loop, counts) on ``cluster``."""
    from weldcell.sdk.scale import batch
    from weldcell.sdk.scale.cluster import ClusterOptions

    marks: dict[str, float] = {}

    class Marks:
        def start(self, total, title):
            marks["start"] = time.perf_counter()

        def advance(self, *a, **k):
            marks["last"] = time.perf_counter()

        def stop(self):
            pass

    t0 = time.perf_counter()
    s = batch.run_batch(
        "burn",
        inputs,
        out,
        ClusterOptions(scheduler=cluster.scheduler_address, plugin_modules=(MODULE,)),
        progress=Marks(),
    )
    return time.perf_counter() - t0, marks["last"] - marks["start"], s.counts


def local_cluster(n: int):
    from distributed import LocalCluster

    return LocalCluster(
        n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None
    )


def raw_dask_overhead(cluster, n: int) -> float:
    """Seconds per no-op task submitted with client.submit and gathered with as_completed."""
    from distributed import Client, as_completed

    with Client(cluster) as client:
        client.submit(int, 0).result()
        t0 = time.perf_counter()
        futs = [client.submit(int, i, pure=False) for i in range(n)]
        for _ in as_completed(futs):
            pass
        return (time.perf_counter() - t0) / n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=1.0)
    ap.add_argument("--noop", type=int, default=100)
    a = ap.parse_args()
    here = str(Path(__file__).resolve().parent)
    os.environ["PYTHONPATH"] = here + (
        os.pathsep + os.environ["PYTHONPATH"] if os.environ.get("PYTHONPATH") else ""
    )
    from weldcell.sdk.scale.cluster import register_plugin_modules

    register_plugin_modules((MODULE,))
    rows = []
    with tempfile.TemporaryDirectory(prefix="weldcell-bench-") as tmp:
        tmp = Path(tmp)
        burn = _inputs(tmp / "burn", a.tasks, a.seconds)
        walls = {}
        for n in (1, 2):
            load0 = _load()
            t0 = time.perf_counter()
            cluster = local_cluster(n)
            start = time.perf_counter() - t0
            # first batch warms the workers (imports, plugin discovery); the timed one runs on warm workers
            timed_batch(cluster, _inputs(tmp / f"warm{n}", n, 0.01), tmp / f"warm-out{n}")
            wall, loop, counts = timed_batch(cluster, burn, tmp / f"out{n}")
            walls[n] = loop
            rows.append(
                f"| {a.tasks} x {a.seconds:g} s CPU, {n} worker(s) | {loop:.2f} s | "
                f"{a.tasks / loop:.2f} tasks/s | {wall:.2f} s (cluster start {start:.1f} s) | "
                f"{counts['ok']}/{a.tasks} ok | {load0:.2f} / {_load():.2f} |"
            )
            if n == 2:
                load0 = _load()
                noop = _inputs(tmp / "noop", a.noop, 0.0)
                wall, loop, counts = timed_batch(cluster, noop, tmp / "noop-out")
                raw = raw_dask_overhead(cluster, 2 * a.noop)
                rows.append(
                    f"| {a.noop} no-op tasks, 2 workers | {loop:.2f} s | {a.noop / loop:.1f} tasks/s | "
                    f"**{loop / a.noop * 1000:.1f} ms per task** through weldcell batch; raw Dask submit "
                    f"{raw * 1000:.2f} ms | {counts['ok']}/{a.noop} ok | {load0:.2f} / {_load():.2f} |"
                )
            cluster.close()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores\n")
    print("| run | task loop wall | throughput | whole batch | done | load avg 1 min (before / after) |")
    print("|---|---|---|---|---|---|")
    print("\n".join(rows))
    print(f"\nspeed-up 2 workers vs 1: **{walls[1] / walls[2]:.2f}x** (target >= 1.8x for tasks >= 1 s)")


if __name__ == "__main__":
    main()
