"""``weldcell batch COMMAND INPUTS… -o OUT_DIR``: an offline command over many inputs, one task each.

OUT_DIR holds::

    batch.json                index (weldcell/batch@1): every input, its status, metrics, error
    summary.csv, index.html   the table and the page a person reads (per-input metrics, failures)
    results/<key>/            one finished input: the command's output(s), log.txt, batch-result.json
    failed/<key>/             one failed input: whatever it wrote, log.txt, batch-result.json (error)
    .work/                    attempts and scratch folders (a crash leaves nothing half-published)

A task gets the input's path, never its bytes: the worker reads it (inputs and OUT_DIR must be on
storage every worker sees). The worker runs the command exactly as ``weldcell COMMAND … INPUT -o OUT``
would, so a result is the one a user gets running the command one input at a time. Re-running the same
batch skips every input whose result is complete and valid: the manifest's command and arguments match,
the input's SHA-256 is unchanged and every output file still has its recorded SHA-256.
"""

from __future__ import annotations

import glob
import hashlib
import json
import os
import re
import socket
import time
import uuid
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from weldcell.sdk import artifacts
from weldcell.sdk.descriptors import BatchSpec, CommandSpec
from weldcell.sdk.errors import UsageError
from weldcell.sdk.scale import tasks
from weldcell.sdk.scale.cluster import ClusterOptions, open_runner

INDEX_SCHEMA = "weldcell/batch@1"
RESULT_SCHEMA = "weldcell/batch-result@1"
MANIFEST = "batch-result.json"
_METRIC_SKIP = ("stages", "settings", "provenance", "covariance", "timings_s")


def batchable_commands(registry: Any) -> dict[str, tuple[CommandSpec, BatchSpec]]:
    """``{"seam": (CommandSpec, BatchSpec), "calibrate hand-eye": …}``: what ``weldcell batch`` can run."""
    out = {}
    for entry in registry.all("command"):
        spec = entry.descriptor
        for b in getattr(spec, "batch", ()) or ():
            out[f"{spec.name} {b.subcommand}".strip()] = (spec, b)
    return out


@dataclass(frozen=True)
class BatchTask:
    """One input of a batch: all a worker needs (paths, not data)."""

    command: str
    input: str
    key: str
    out_dir: str
    args: tuple[str, ...]
    fingerprint: str
    run_id: str
    retries: int = 2
    time_limit: float | None = None
    hard_limit: bool = True
    reports: bool = False
    """Also pass the command's report option (``--report <folder>``) when it has one."""


@dataclass
class BatchSummary:
    """What a batch did: the index written to ``batch.json`` and its counts."""

    out_dir: Path
    index: dict[str, Any]
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def failed(self) -> int:
        return self.counts.get("failed", 0)


# ------------------------------------------------------------------------------------------------ inputs
def input_key(path: Path) -> str:
    """A stable folder name for an input: its name and a hash of its absolute path."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", path.name)[:60] or "input"
    return f"{stem}-{hashlib.sha1(str(path).encode()).hexdigest()[:10]}"


def _has_marker(folder: Path, spec: BatchSpec) -> bool:
    return any((folder / m).exists() for m in spec.markers)


def _expand_folder(folder: Path, spec: BatchSpec) -> list[Path]:
    if spec.inputs == "dir" and (not spec.markers or _has_marker(folder, spec)):
        return [folder]
    if spec.inputs == "any" and spec.markers and _has_marker(folder, spec):
        return [folder]
    found: list[Path] = []
    if spec.inputs in ("file", "any"):
        patterns = spec.patterns or ("*",)
        found += sorted({f for p in patterns for f in folder.glob(p) if f.is_file()})
    if spec.markers:
        found += sorted(d for d in folder.iterdir() if d.is_dir() and _has_marker(d, spec))
    if spec.inputs == "dir" and not found:
        return [folder]  # no marker anywhere: the folder itself, and the command says what is wrong
    return found


def expand_inputs(given: list[str], spec: BatchSpec) -> list[Path]:
    """Absolute input paths from files, folders and glob patterns (sorted per argument, no duplicates).

    A folder expands as ``spec`` says (see :class:`~weldcell.sdk.descriptors.BatchSpec`). A path that
    does not exist stays: its task fails with the command's own error, the others run."""
    out: list[Path] = []
    for text in given:
        p = Path(text).expanduser()
        if not p.exists() and glob.has_magic(text):
            matches = sorted(Path(m) for m in glob.glob(os.path.expanduser(text), recursive=True))
            if not matches:
                raise UsageError(
                    f"no file matches {text!r}", "check the pattern (quote it to let weldcell expand it)"
                )
            for m in matches:
                out += _expand_folder(m.resolve(), spec) if m.is_dir() else [m.resolve()]
        elif p.is_dir():
            out += _expand_folder(p.resolve(), spec)
        else:
            out.append(p.resolve())
    return list(dict.fromkeys(out))


def absolute_args(args: tuple[str, ...]) -> tuple[str, ...]:
    """Command arguments with every existing path made absolute (workers have another working folder)."""
    return tuple(str(Path(a).resolve()) if not a.startswith("-") and Path(a).exists() else a for a in args)


def fingerprint(command: str, args: tuple[str, ...], reports: bool = False) -> str:
    """What makes two runs of an input the same: the command, its arguments, and whether it reports."""
    return hashlib.sha256(json.dumps([command, list(args), reports]).encode()).hexdigest()[:16]


# ------------------------------------------------------------------------------------------------ worker side
def _invoke(command: Any, argv: list[str], prog: str) -> None:
    """Run a click command as the CLI would; a non-zero exit becomes an exception."""
    import click

    try:
        rv = command.main(args=argv, prog_name=prog, standalone_mode=False)
    except SystemExit as e:
        rv = e.code
    except click.ClickException as e:
        from weldcell.sdk.errors import UsageError as WUsage

        raise WUsage(e.format_message(), f"see `{prog} --help`") from None
    if isinstance(rv, int) and rv != 0:
        raise CommandExit(rv)


class CommandExit(Exception):
    """The command ended with a non-zero exit code and no error of its own."""

    def __init__(self, code: int) -> None:
        super().__init__(f"exited with code {code}")
        self.code = code


def read_metrics(folder: Path, spec: BatchSpec) -> dict[str, float]:
    """Numeric figures of one result: the output JSON's ``metrics`` and top-level numbers (or those of
    the JSON written beside a non-JSON output, e.g. ``model.json`` beside ``model.ply``)."""
    out = folder / spec.output
    doc_path = out if out.suffix == ".json" else out.with_suffix(".json")
    if not doc_path.is_file():
        return {}
    try:
        doc = json.loads(doc_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    metrics = (
        tasks.flatten_numbers(doc.get("metrics", {}), skip=_METRIC_SKIP) if isinstance(doc, dict) else {}
    )
    top = {k: v for k, v in doc.items() if k != "metrics"} if isinstance(doc, dict) else {}
    return {**tasks.flatten_numbers(top, depth=1, skip=_METRIC_SKIP), **metrics}


def _valid_result(target: Path, task: BatchTask) -> dict[str, Any] | None:
    manifest = target / MANIFEST
    if not manifest.is_file():
        return None
    try:
        rec = json.loads(manifest.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if (
        rec.get("schema") != RESULT_SCHEMA
        or rec.get("status") != "ok"
        or rec.get("fingerprint") != task.fingerprint
    ):
        return None
    inp = Path(task.input)
    if not inp.exists() or tasks.sha256_path(inp) != rec.get("input_sha256"):
        return None
    return rec if tasks.outputs_intact(target, rec.get("outputs", {})) else None


def run_batch_task(task: BatchTask) -> dict[str, Any]:
    """Run one input (in a worker): skip it when its result is valid, else run the command and publish
    the result folder atomically. Returns the record that ``batch.json`` lists."""
    from weldcell.sdk.plugins import get_plugin_manager

    out = Path(task.out_dir)
    target, work = out / "results" / task.key, out / tasks.WORK / task.key
    done = _valid_result(target, task)
    if done is not None:
        return {**done, "resumed": True}
    if target.exists():  # stale (input or arguments changed) or damaged: set aside, never mixed in
        work.mkdir(parents=True, exist_ok=True)
        os.rename(target, work / f"stale-{task.run_id}-{uuid.uuid4().hex[:6]}")
    attempt = tasks.Attempt(work, task.run_id, task.retries, task.time_limit, task.hard_limit)
    rec: dict[str, Any] = {
        "schema": RESULT_SCHEMA,
        "command": task.command,
        "args": list(task.args),
        "input": task.input,
        "key": task.key,
        "fingerprint": task.fingerprint,
        "worker": f"{socket.gethostname()}:{os.getpid()}",
    }
    try:
        scratch = attempt.start()
    except tasks.GiveUp as e:
        return failure_record(task, str(e), rec)
    # the command is looked up (plugins loaded) before the time limit is armed: it limits the command only
    spec, bspec = batchable_commands(get_plugin_manager().registry)[task.command]
    attempt.arm()
    t0 = time.perf_counter()
    inp = Path(task.input)
    rec["input_sha256"] = tasks.sha256_path(inp) if inp.exists() else None
    try:
        argv = [*([bspec.subcommand] if bspec.subcommand else []), *task.args, task.input]
        argv += ["-o", str(scratch / bspec.output)]
        if bspec.report_option and task.reports:
            argv += [bspec.report_option, str(scratch / "report")]
        with tasks.captured_output(scratch / "log.txt"):
            _invoke(spec.command, argv, f"weldcell {spec.name}")
        rec.update(status="ok", metrics=read_metrics(scratch, bspec))
    except Exception as e:  # noqa: BLE001 - recorded as this input's failure
        log = scratch / "log.txt"
        tail = (
            [ln for ln in log.read_text(encoding="utf-8").splitlines() if ln.strip()] if log.is_file() else []
        )
        rec.update(status="failed", error=tasks.error_record(e, tail[-1] if tail else ""))
    rec.update(seconds=round(time.perf_counter() - t0, 4), attempts=attempt.n, finished=_now())
    rec["outputs"] = tasks.output_checksums(scratch, skip=(MANIFEST,))
    artifacts.write_json(scratch / MANIFEST, rec)
    attempt.end(rec["status"])
    if rec["status"] == "ok":
        if not tasks.publish(scratch, target):  # another attempt finished first: its result stands
            return {
                **json.loads((target / MANIFEST).read_text(encoding="utf-8")),
                "duplicate_discarded": True,
            }
        tasks.clear_folder(out / "failed" / task.key, work)  # an earlier run's failure, now superseded
    else:
        tasks.replace_folder(scratch, out / "failed" / task.key, work / f"old-failed-{task.run_id}")
    return rec


def failure_record(task: BatchTask, reason: str, rec: dict[str, Any] | None = None) -> dict[str, Any]:
    """Record an input that failed without the command failing (its worker died, its time ran out),
    in ``failed/<key>/`` like any failure."""
    rec = dict(
        rec
        or {
            "schema": RESULT_SCHEMA,
            "command": task.command,
            "args": list(task.args),
            "input": task.input,
            "key": task.key,
            "fingerprint": task.fingerprint,
        }
    )
    attempts = tasks.read_attempts(Path(task.out_dir) / tasks.WORK / task.key / "attempts.jsonl", task.run_id)
    reason = tasks.lost_reason(attempts) or reason
    rec.update(
        status="failed",
        attempts=len(attempts),
        finished=_now(),
        error={
            "type": "TaskLost",
            "message": reason,
            "fix": _lost_fix(reason, task),
            "exit_code": 1,
            "line": reason,
        },
    )
    failed = Path(task.out_dir) / "failed" / task.key
    artifacts.write_json(failed / MANIFEST, rec)
    return rec


def _lost_fix(reason: str, task: BatchTask) -> str:
    if "time limit" in reason:
        return "raise --time-limit, or check this input (it may be far larger than the others)"
    return "check the worker's memory (dask worker --memory-limit) and logs; re-run the batch to retry it"


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


# ------------------------------------------------------------------------------------------------ client side
def run_batch(
    command: str,
    inputs: list[str],
    out_dir: Path,
    options: ClusterOptions,
    args: tuple[str, ...] = (),
    progress: Any = None,
    reports: bool = False,
) -> BatchSummary:
    """Run ``command`` on every input on the cluster ``options`` name; write OUT_DIR (see module doc).

    ``progress`` (a :class:`~weldcell.sdk.scale.progress.TaskProgress` or None) shows done/failed,
    rate and ETA. Returns the summary; a failed input is in it, never raised."""
    from weldcell.sdk.plugins import get_plugin_manager
    from weldcell.sdk.scale.report import write_batch_report

    found = batchable_commands(get_plugin_manager().registry)
    if command not in found:
        raise UsageError(
            f"'{command}' is not a batchable command",
            f"batchable commands: {', '.join(sorted(found)) or '(none)'}; a plugin declares one with "
            "CommandSpec(batch=(BatchSpec(...),))",
        )
    _, bspec = found[command]
    paths = expand_inputs(list(inputs), bspec)
    if not paths:
        raise UsageError("no input to run", "give files, folders or glob patterns")
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    args = absolute_args(tuple(args))
    run_id = f"{datetime.now(UTC).strftime('%Y%m%d%H%M%S')}-{uuid.uuid4().hex[:6]}"
    fp = fingerprint(command, args, reports)
    index: dict[str, Any] = {
        "schema": INDEX_SCHEMA,
        "command": command,
        "args": list(args),
        "run": run_id,
        "started": _now(),
        "items": {str(p): {"input": str(p), "key": input_key(p), "status": "pending"} for p in paths},
    }
    with open_runner(options) as runner:
        index["runner"] = runner.description
        batch = [
            BatchTask(
                command,
                str(p),
                input_key(p),
                str(out_dir),
                args,
                fp,
                run_id,
                options.retries,
                options.time_limit,
                hard_limit=not runner.in_process,
                reports=reports,
            )
            for p in paths
        ]
        if progress is not None:
            progress.start(len(batch), f"{command} ({runner.description})")
        try:
            _collect(runner, batch, index, out_dir, run_id, progress)
        finally:
            if progress is not None:
                progress.stop()
            index["finished"] = _now()
            counts = _write_index(out_dir, index)
            write_batch_report(out_dir, index)
    _tidy_work(out_dir, index)
    return BatchSummary(out_dir, index, counts)


def _collect(
    runner, batch: list[BatchTask], index: dict[str, Any], out_dir: Path, run_id: str, progress
) -> None:
    """Each input's record into ``index["items"]`` as it finishes (a task the runner lost as a failure),
    the index rewritten at most once a second so an interrupted batch keeps what finished."""
    keys = [f"weldcell-batch-{run_id}-{t.key}" for t in batch]
    last_write = 0.0
    for outcome in runner.map_unordered(run_batch_task, batch, keys):
        task: BatchTask = outcome.item
        rec = outcome.value if outcome.error is None else failure_record(task, _lost(outcome.error))
        index["items"][task.input] = rec
        if progress is not None:
            progress.advance(
                rec["status"] == "ok",
                rec.get("resumed", False),
                task.input,
                (rec.get("error") or {}).get("line", ""),
            )
        if time.monotonic() - last_write > 1.0:
            _write_index(out_dir, index)
            last_write = time.monotonic()


def _tidy_work(out_dir: Path, index: dict[str, Any]) -> None:
    """After a batch that ran to its end: remove the scratch folders left by lost attempts of the inputs
    that finished (their attempt logs stay in ``.work/<key>/attempts.jsonl``)."""
    import shutil

    for rec in index["items"].values():
        work = out_dir / tasks.WORK / rec["key"]
        if rec["status"] == "ok" and work.is_dir():
            for d in work.iterdir():
                if d.is_dir():
                    shutil.rmtree(d, ignore_errors=True)


def _lost(error: BaseException) -> str:
    name = type(error).__name__
    if name == "KilledWorker":
        return "its worker process died while running it, more often than it may be retried"
    return f"{name}: {error}"


def _write_index(out_dir: Path, index: dict[str, Any]) -> dict[str, int]:
    counts: dict[str, int] = {"inputs": len(index["items"]), "ok": 0, "failed": 0, "pending": 0, "resumed": 0}
    for rec in index["items"].values():
        counts[rec["status"]] = counts.get(rec["status"], 0) + 1
        counts["resumed"] += bool(rec.get("resumed"))
    index["counts"] = counts
    index["updated"] = _now()
    artifacts.write_json(out_dir / "batch.json", index)
    return counts


def task_dict(task: BatchTask) -> dict[str, Any]:
    return asdict(task)
