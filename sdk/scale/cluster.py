"""Where the work runs: an embedded Dask ``LocalCluster``, an existing cluster, or this process.

* default: a ``LocalCluster`` on loopback sized to this machine (one single-threaded worker process per
  core: the methods are numpy/GIL-bound, and a worker that must be stopped stops one task only);
* ``scheduler="tcp://host:8786"`` (or the environment variable ``DASK_SCHEDULER_ADDRESS``): an existing
  cluster (``dask scheduler`` / ``dask worker``, dask-jobqueue, Kubernetes; docs/scale-out.md);
* ``workers=0``: every task in this process, one after the other (for debugging: breakpoints work).

At start every worker is checked: it must have weldcell and the same plugins (names and versions) as
this machine; a worker that lacks something is named with what it lacks, before any task is sent.
Dask is imported lazily: without the ``scale`` extra only these commands fail, with the extra to install.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.metadata as md
import os
import platform
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import Field
from weldcell.sdk.errors import DeviceError, MissingExtraError, PluginError, UsageError
from weldcell.sdk.settings import Settings

ENV_SCHEDULER = "DASK_SCHEDULER_ADDRESS"


class ClusterOptions(Settings):
    """Where ``weldcell batch`` and ``weldcell study`` run their tasks."""

    scheduler: str | None = Field(
        None,
        description=f"address of an existing Dask scheduler (else ${ENV_SCHEDULER}, else a local cluster)",
    )
    workers: int | None = Field(
        None, ge=0, description="local worker processes (default: one per core; 0: in this process)"
    )
    threads_per_worker: int = Field(1, ge=1, description="threads per local worker process")
    memory_limit: str = Field("auto", description="memory per local worker ('auto': machine / workers)")
    retries: int = Field(2, ge=0, description="re-runs of a task whose worker died or that ran out of time")
    time_limit: float | None = Field(
        None, gt=0, description="seconds one task may run before its worker is stopped (None: no limit)"
    )
    plugin_modules: tuple[str, ...] = Field(
        (), description="plugin modules registered in every worker besides the installed entry points"
    )
    connect_timeout: float = Field(10.0, gt=0, description="seconds to wait for an existing scheduler")
    python_path: tuple[str, ...] = Field(
        (), description="folders put on every worker's sys.path (a study's --function module is found there)"
    )

    def scheduler_address(self) -> str | None:
        """The scheduler to use: the option, else ``$DASK_SCHEDULER_ADDRESS``, else None (local)."""
        return self.scheduler or os.environ.get(ENV_SCHEDULER) or None


def require_dask() -> None:
    """Raise :class:`MissingExtraError` naming the ``scale`` extra when dask.distributed is missing."""
    for module in ("dask", "distributed"):
        try:
            importlib.import_module(module)
        except ModuleNotFoundError:
            raise MissingExtraError("weldcell batch / study on Dask", module, "scale") from None


# ---------------------------------------------------------------------------------------------- plugins
def register_plugin_modules(modules: Sequence[str]) -> None:
    """Import ``modules`` and register each in this process's plugin manager under its module name
    (idempotent). Workers run this at start (and again when a worker is restarted)."""
    from weldcell.sdk.plugins import get_plugin_manager

    pm = get_plugin_manager()
    for name in modules:
        if name not in pm.plugin_names():
            pm.register(importlib.import_module(name), name=name)


def add_python_path(folders: Sequence[str]) -> None:
    """Put ``folders`` at the front of this process's ``sys.path`` (idempotent)."""
    import sys

    for f in reversed(tuple(folders)):
        if f not in sys.path:
            sys.path.insert(0, f)


def environment(plugin_modules: Sequence[str] = ()) -> dict[str, Any]:
    """What this process has: weldcell's version, Python's, and every plugin with its version
    (entry-point plugins and ``plugin_modules``), plus the plugins that failed to load and why."""
    from weldcell.sdk.plugins import get_plugin_manager

    register_plugin_modules(plugin_modules)
    pm = get_plugin_manager()
    try:
        version = md.version("weldcell")
    except md.PackageNotFoundError:
        version = "unknown"
    plugins = {
        name: (p.distribution or "", p.version or "")
        for name, p in pm.providers.items()
        if p.entry_point is not None or name in plugin_modules
    }
    failed = {f.provider.plugin: f.error for f in pm.load_failures}
    return {
        "weldcell": version,
        "python": platform.python_version(),
        "plugins": plugins,
        "failed": failed,
        "pid": os.getpid(),
    }


def compare_environments(local: dict[str, Any], workers: dict[str, Any]) -> list[str]:
    """One line per worker that lacks weldcell or a plugin this machine has, or has another version."""
    problems: list[str] = []
    for addr, env in sorted(workers.items()):
        if isinstance(env, BaseException):
            problems.append(f"worker {addr} cannot run weldcell: {type(env).__name__}: {env}")
            continue
        lacks: list[str] = []
        if env["weldcell"] != local["weldcell"]:
            lacks.append(f"weldcell {local['weldcell']} (it has {env['weldcell']})")
        for name, (dist, version) in sorted(local["plugins"].items()):
            have = env["plugins"].get(name)
            why = env["failed"].get(name)
            if have is None:
                lacks.append(f"plugin '{name}'" + (f" (it failed to load: {why})" if why else ""))
            elif have[1] != version:
                lacks.append(f"plugin '{name}' {dist} {version} (it has {have[1] or 'no version'})")
        if lacks:
            problems.append(f"worker {addr} lacks " + ", ".join(lacks))
    return problems


# ---------------------------------------------------------------------------------------------- runners
@dataclass
class Outcome:
    """What a task gave back: its ``value``, or the ``error`` it (or its worker) raised."""

    item: Any
    value: Any = None
    error: BaseException | None = None


class InProcessRunner:
    """Runs the tasks here, one after the other (``--workers 0``)."""

    workers = 0
    description = "in this process"
    in_process = True

    def map_unordered(
        self, fn: Callable[[Any], Any], items: Sequence[Any], keys: Sequence[str]
    ) -> Iterator[Outcome]:
        """``fn(item)`` for each item; exceptions are returned, not raised (except an interrupt)."""
        for item in items:
            try:
                yield Outcome(item, fn(item))
            except Exception as e:  # noqa: BLE001 - one bad input never stops the batch
                yield Outcome(item, error=e)


class DaskRunner:
    """Runs the tasks on a Dask cluster through ``client``; results come back as they complete."""

    in_process = False

    def __init__(self, client: Any, description: str) -> None:
        self.client = client
        self.description = description

    @property
    def workers(self) -> int:
        return len(self.client.scheduler_info(n_workers=-1)["workers"])

    def map_unordered(
        self, fn: Callable[[Any], Any], items: Sequence[Any], keys: Sequence[str]
    ) -> Iterator[Outcome]:
        """Submit ``fn(item)`` per item (task key ``keys[i]``), yield outcomes in completion order.

        A task is sent as its small description only: inputs are read by the worker. On an interrupt
        the tasks not finished are cancelled."""
        from distributed import as_completed

        futures = {}
        for item, key in zip(items, keys, strict=True):
            futures[self.client.submit(fn, item, key=key, pure=False)] = item
        try:
            for fut in as_completed(list(futures)):
                try:
                    yield Outcome(futures[fut], fut.result())
                except Exception as e:  # noqa: BLE001 - KilledWorker, a task's own error, ...
                    yield Outcome(futures[fut], error=e)
                fut.release()
        finally:
            pending = [f for f in futures if not f.done()]
            if pending:
                self.client.cancel(pending)


def _local_cluster(options: ClusterOptions):
    import dask
    from distributed import LocalCluster

    n = options.workers if options.workers is not None else (os.cpu_count() or 1)
    # the scheduler re-runs a task whose worker died; our own attempt count (weldcell.sdk.scale.tasks)
    # bounds it to ``retries``, the scheduler's limit only backs it up
    with dask.config.set({"distributed.scheduler.allowed-failures": options.retries + 1}):
        return LocalCluster(
            n_workers=n,
            threads_per_worker=options.threads_per_worker,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            memory_limit=options.memory_limit,
        )


@contextlib.contextmanager
def open_runner(options: ClusterOptions, check: bool = True) -> Iterator[InProcessRunner | DaskRunner]:
    """The runner ``options`` ask for; workers are checked (``check``) before it is handed out.

    Raises :class:`DeviceError` when an existing scheduler cannot be reached, :class:`PluginError` when a
    worker lacks weldcell or a plugin (naming the worker and what it lacks).
    """
    if options.workers == 0 and options.scheduler is None:  # --workers 0 wins over $DASK_SCHEDULER_ADDRESS
        add_python_path(options.python_path)
        register_plugin_modules(options.plugin_modules)
        yield InProcessRunner()
        return
    require_dask()
    from distributed import Client

    address = options.scheduler_address()
    with contextlib.ExitStack() as stack:
        if address is not None:
            if options.workers is not None:
                raise UsageError(
                    f"--workers {options.workers} with an existing cluster ({address})",
                    "size the cluster where it runs (dask worker / the cluster manager); drop --workers",
                )
            try:
                client = stack.enter_context(Client(address, timeout=options.connect_timeout))
            except (OSError, TimeoutError) as e:
                raise DeviceError(
                    f"cannot reach the Dask scheduler at {address}: {e}",
                    f"start it (`dask scheduler`) and its workers (`dask worker {address}`), or check the "
                    f"address (--scheduler or ${ENV_SCHEDULER}); without one a local cluster is used",
                ) from None
            description = f"cluster {address}"
        else:
            cluster = stack.enter_context(_local_cluster(options))
            client = stack.enter_context(Client(cluster))
            description = f"local cluster ({len(cluster.workers)} worker processes)"
        if options.plugin_modules or options.python_path:
            from weldcell.sdk.scale._dask_plugins import PluginModules

            register_plugin_modules(options.plugin_modules)
            client.register_plugin(PluginModules(options.plugin_modules, options.python_path))
        if check:
            check_workers(client, options.plugin_modules)
        yield DaskRunner(client, description)


def check_workers(client: Any, plugin_modules: Sequence[str] = ()) -> None:
    """Every worker has weldcell and this machine's plugins, or a :class:`PluginError` naming who lacks
    what. A cluster with no worker yet is an error too (nothing would run)."""
    n = len(client.scheduler_info(n_workers=-1)["workers"])
    if n == 0:
        try:
            client.wait_for_workers(1, timeout=30)
        except TimeoutError:
            raise DeviceError(
                "the Dask cluster has no worker",
                "start workers with `dask worker <scheduler address>` on each machine (docs/scale-out.md)",
            ) from None
    has = client.run(md.version, "weldcell", on_error="return")
    missing = {a: v for a, v in has.items() if isinstance(v, BaseException)}
    envs: dict[str, Any] = {a: ModuleNotFoundError("weldcell is not installed") for a in missing}
    ok = [a for a in has if a not in missing]
    if ok:
        envs.update(client.run(environment, tuple(plugin_modules), workers=ok, on_error="return"))
    problems = compare_environments(environment(plugin_modules), envs)
    if problems:
        raise PluginError(
            "workers differ from this machine: " + "; ".join(problems),
            "install the same weldcell and plugins on every worker (pip install weldcell[scale] plus your "
            "plugin packages, same versions; docs/scale-out.md)",
        )
