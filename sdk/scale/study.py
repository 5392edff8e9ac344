"""``weldcell study PROFILE --trials N --vary KEY=DIST … -o OUT_DIR``: Monte-Carlo runs of a simulated job.

Trial ``i`` draws its settings and its cell seed from ``numpy.random.SeedSequence(seed).spawn(...)[i]``:
the same ``--seed`` gives the same trials in any order, on any number of workers, and trial ``i`` does
not change when ``--trials`` grows. Each trial is a profile that ``extends`` PROFILE with the drawn
values and its seed (``trials/<i>/profile.toml``: run it alone with ``weldcell run``), and its job runs
through the ordinary job runner. Only profiles whose devices are all simulated are accepted.

Distributions (arguments may carry units; values are drawn and written in SI)::

    KEY=uniform(a, b)        e.g. job.settings.worker.placement_offset=uniform(5 mm, 25 mm)
    KEY=normal(mu, sigma)    e.g. devices.camera.settings.noise_scale=normal(1, 0.1)
    KEY=choice(v1, v2, …)    e.g. devices.robot.settings.model=choice(ur5, ur10e)
    KEY=cycle(v1, v2, …)     trial i takes v[i mod k] (the rows of a table; ``by=KEY`` groups statistics)

With ``function="MODULE:FUNCTION"`` instead of a profile, each trial calls that trial function with the
drawn values (plain keys): a protocol that is not a whole job (:mod:`~weldcell.sdk.scale.trial_function`).

OUT_DIR: ``study.json`` (weldcell/study@1: trials, statistics, failure rate), ``trials.csv``,
``statistics.csv``, ``index.html``, ``trials/<i>/`` (profile.toml, trial.json, the run folder).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import re
import shutil
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from weldcell.sdk import artifacts
from weldcell.sdk.errors import UsageError, WeldcellError
from weldcell.sdk.scale import tasks
from weldcell.sdk.scale.cluster import ClusterOptions, open_runner
from weldcell.sdk.units import SI, UNITS, parse_quantity

STUDY_SCHEMA = "weldcell/study@1"
TRIAL_SCHEMA = "weldcell/study-trial@1"
KINDS = ("uniform", "normal", "choice", "cycle")
_VARY = re.compile(r"^\s*([A-Za-z_][\w-]*(?:\.[A-Za-z_][\w-]*)*)\s*=\s*([a-z]+)\s*\((.*)\)\s*$")
_FUNCTION = re.compile(r"^[A-Za-z_][\w]*(?:\.[A-Za-z_][\w]*)*:[A-Za-z_][\w]*$")
_RESERVED = {("extends",), ("schema",), ("cell", "seed")}
_KEEP = ("result.json", "summary.txt", "report.md")


# ---------------------------------------------------------------------------------------------- distributions
def _unit_dimension(unit: str) -> str | None:
    return next((dim for dim, table in UNITS.items() if unit in table), None)


def _arg(text: str) -> tuple[Any, str | None]:
    """One argument: ``(value, SI unit or None)``; numbers with units become SI floats."""
    t = text.strip().strip("'\"")
    if t.lower() in ("true", "false"):
        return t.lower() == "true", None
    try:
        return (int(t) if re.fullmatch(r"[-+]?\d+", t) else float(t)), None
    except ValueError:
        pass
    m = re.fullmatch(r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S.*)", t)
    if m:
        dim = _unit_dimension(m.group(2).strip())
        if dim is not None:
            return parse_quantity(t, dim), SI[dim]
    return t, None


@dataclass(frozen=True)
class Distribution:
    """A setting's distribution; ``unit`` is the SI unit its values are written with (None: plain)."""

    kind: str
    params: tuple[Any, ...]
    unit: str | None
    text: str

    def draw(self, rng: np.random.Generator, trial: int = 0) -> Any:
        if self.kind == "cycle":  # trial i takes value i mod k: equal rows of a table, no draw
            return self.params[trial % len(self.params)]
        if self.kind == "uniform":
            return float(rng.uniform(self.params[0], self.params[1]))
        if self.kind == "normal":
            return float(rng.normal(self.params[0], self.params[1]))
        return self.params[int(rng.integers(len(self.params)))]


def parse_vary(text: str) -> tuple[str, Distribution]:
    """``"KEY=kind(args)"`` → (key, :class:`Distribution`); a clear :class:`UsageError` otherwise."""
    m = _VARY.match(text)
    fix = (
        "write KEY=uniform(a,b), KEY=normal(mu,sigma), KEY=choice(v1,v2,...) or KEY=cycle(v1,v2,...), e.g. "
        "job.settings.worker.placement_offset='uniform(5 mm, 25 mm)'"
    )
    if not m:
        raise UsageError(f"--vary {text!r} is not KEY=DISTRIBUTION", fix)
    key, kind, body = m.groups()
    if kind not in KINDS:
        raise UsageError(f"--vary {key}: unknown distribution {kind!r}", f"use one of {', '.join(KINDS)}")
    if tuple(key.split(".")) in _RESERVED:
        raise UsageError(
            f"--vary {key}: this key is set by the study", "each trial's cell seed comes from --seed"
        )
    args = [_arg(a) for a in body.split(",") if a.strip()]
    units = {u for _, u in args if u is not None}
    if len(units) > 1:
        raise UsageError(
            f"--vary {key}: arguments in different units ({', '.join(sorted(units))})",
            "give every argument in the same kind of unit",
        )
    unit = units.pop() if units else None
    values = tuple(v for v, _ in args)
    if kind in ("choice", "cycle"):
        if not values:
            raise UsageError(f"--vary {key}: {kind}() needs at least one value", fix)
        return key, Distribution(kind, values, unit, text)
    if len(values) != 2 or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        raise UsageError(f"--vary {key}: {kind}() takes two numbers, got {body!r}", fix)
    if unit is not None and any(u is None and v != 0 for v, u in args):
        raise UsageError(f"--vary {key}: give every argument a unit, or none", f"e.g. {kind}(0 mm, 2 mm)")
    a, b = float(values[0]), float(values[1])
    if kind == "uniform" and not a < b:
        raise UsageError(f"--vary {key}: uniform(a, b) needs a < b", fix)
    if kind == "normal" and b < 0:
        raise UsageError(f"--vary {key}: normal(mu, sigma) needs sigma >= 0", fix)
    return key, Distribution(kind, (a, b), unit, text)


def draw_trials(seed: int, n: int, vary: dict[str, Distribution]) -> list[tuple[int, dict[str, Any]]]:
    """``(cell seed, {key: value})`` of trials 0..n-1; trial i depends only on ``seed`` and ``i``."""
    out = []
    for i, child in enumerate(np.random.SeedSequence(seed).spawn(n)):
        cell_seed = int(child.generate_state(1, dtype=np.uint32)[0])
        rng = np.random.default_rng(child)
        out.append((cell_seed, {k: d.draw(rng, i) for k, d in vary.items()}))
    return out


def _toml_value(v: Any, unit: str | None) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float) and unit is not None:
        return json.dumps(f"{v!r} {unit}")
    if isinstance(v, int | float):
        return repr(v)
    return json.dumps(str(v))


def trial_profile(
    base: Path,
    trial: int,
    cell_seed: int,
    values: dict[str, Any],
    vary: dict[str, Distribution],
    report: bool,
) -> str:
    """The TOML of one trial: extends ``base`` (absolute) with the drawn values and the cell seed."""
    lines = [
        f"# weldcell study: trial {trial} of {base.name} (run it alone: weldcell run profile.toml)",
        f"extends = {json.dumps(str(base))}",
        f"cell.seed = {cell_seed}",
    ]
    if "output.report" not in values:
        lines.append(f"output.report = {'true' if report else 'false'}")
    for k, v in values.items():
        lines.append(f"{'.'.join(json.dumps(p) for p in k.split('.'))} = {_toml_value(v, vary[k].unit)}")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ worker side
@dataclass(frozen=True)
class TrialTask:
    """One trial: its profile text and where to put it (no data)."""

    trial: int
    seed: int
    values: dict[str, Any]
    profile: str
    out_dir: str
    fingerprint: str
    run_id: str
    retries: int = 2
    time_limit: float | None = None
    hard_limit: bool = True
    keep_runs: bool = False
    function: str | None = None
    """``MODULE:FUNCTION`` of a trial function (then ``profile`` is empty): see ``trial_function``."""


def _valid_trial(target: Path, task: TrialTask) -> dict[str, Any] | None:
    try:
        rec = json.loads((target / "trial.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if rec.get("schema") != TRIAL_SCHEMA or rec.get("fingerprint") != task.fingerprint:
        return None
    if rec.get("status") not in ("ok", "failed") or not tasks.outputs_intact(target, rec.get("outputs", {})):
        return None
    return rec


def run_trial(task: TrialTask) -> dict[str, Any]:
    """Run one trial's job (in a worker) unless a valid result exists; publish ``trials/<i>/`` atomically.

    A job that fails is a finished trial (status ``failed`` with its error): it counts in the failure
    rate. A trial whose worker died or ran out of time is retried, then reported lost."""
    out = Path(task.out_dir)
    name = f"{task.trial:05d}"
    target, work = out / "trials" / name, out / tasks.WORK / f"trial-{name}"
    done = _valid_trial(target, task)
    if done is not None:
        return {**done, "resumed": True}
    tasks.clear_folder(target, work)
    attempt = tasks.Attempt(work, task.run_id, task.retries, task.time_limit, task.hard_limit)
    rec: dict[str, Any] = {
        "schema": TRIAL_SCHEMA,
        "trial": task.trial,
        "seed": task.seed,
        "values": task.values,
        "fingerprint": task.fingerprint,
    }
    try:
        scratch = attempt.start()
    except tasks.GiveUp as e:
        return {**rec, "status": "lost", "error": {"type": "TaskLost", "message": str(e), "line": str(e)}}
    if task.function is not None:
        _run_function(task, scratch, attempt, rec)
    else:
        _run_profile(task, scratch, attempt, rec)
    rec["outputs"] = tasks.output_checksums(scratch, skip=("trial.json", "log.txt"))
    artifacts.write_json(scratch / "trial.json", rec)
    attempt.end(rec["status"])
    if not tasks.publish(scratch, target):
        return json.loads((target / "trial.json").read_text(encoding="utf-8"))
    return rec


def _run_function(task: TrialTask, scratch: Path, attempt: tasks.Attempt, rec: dict[str, Any]) -> None:
    from weldcell.sdk.scale import trial_function

    rec["function"] = task.function
    try:
        trial_function.resolve(task.function)  # imported before the time limit starts
    except UsageError:
        pass  # call() records it as the trial's error
    attempt.arm()
    t0 = time.perf_counter()
    rec.update(trial_function.call(task.function, task.values, task.seed, task.trial, scratch / "log.txt"))
    rec["seconds"] = round(time.perf_counter() - t0, 4)
    rec["run"] = None


def _run_profile(task: TrialTask, scratch: Path, attempt: tasks.Attempt, rec: dict[str, Any]) -> None:
    from weldcell.sdk.jobs import run_job
    from weldcell.sdk.plugins import get_plugin_manager

    profile = scratch / "profile.toml"
    artifacts.write_text(profile, task.profile)
    _ = get_plugin_manager().registry  # plugins loaded before the time limit starts: it limits the job only
    attempt.arm()
    t0 = time.perf_counter()
    try:
        with tasks.captured_output(scratch / "log.txt"):
            run_dir, result = run_job(profile, get_plugin_manager(), runs_dir=scratch / "run")
        rec.update(status="ok", figures=tasks.flatten_numbers(result.get("figures", {})))
    except WeldcellError as e:
        rec.update(status="failed", error=tasks.error_record(e), figures={})
    rec["seconds"] = round(time.perf_counter() - t0, 4)
    runs = sorted((scratch / "run").glob("*")) if (scratch / "run").is_dir() else []
    if runs and not task.keep_runs:  # the run's figures and report stay; its captures go
        for f in runs[0].iterdir():
            if f.name not in _KEEP:
                shutil.rmtree(f) if f.is_dir() else f.unlink()
    rec["run"] = str(runs[0].relative_to(scratch)) if runs else None


# ------------------------------------------------------------------------------------------------ client side
def check_profile(base: Path, text: str, pm: Any) -> str:
    """Validate a trial profile here before any task is sent (unknown keys, wrong units, missing
    plugins); refuse a profile with a device that is not simulated. Returns the job's name."""
    from weldcell.sdk.jobs import prepare
    from weldcell.sdk.profile import load_profile

    devices = pm.registry.entries["device"]
    with tempfile.TemporaryDirectory(prefix="weldcell-study-") as tmp:
        f = Path(tmp) / "profile.toml"
        f.write_text(text, encoding="utf-8")
        entries = load_profile(f).profile.devices  # before the full validation: no hardware is looked at
        real = [
            f"{role} ({e.plugin})"
            for role, e in entries.items()
            if e.plugin in devices and not devices[e.plugin].descriptor.simulated
        ]
        if real:
            raise UsageError(
                f"{base}: a study runs simulated cells only; these devices are hardware: {', '.join(real)}",
                "give a simulation profile (e.g. profiles/cell3-localize-sim.toml)",
            )
        loaded, _ = prepare(f, pm)
    return loaded.profile.job.name


def summarize(trials: list[dict[str, Any]], by: str | None = None) -> dict[str, Any]:
    """Statistics of every metric over the ok trials, and the failure rate over finished trials; with
    ``by`` (a varied key) also ``"groups"``: the same per value of that key (the rows of a table)."""
    from weldcell.sdk.scale.report import statistics

    if by is not None:
        values = list(dict.fromkeys(str((t.get("values") or {}).get(by)) for t in trials))
        groups = {
            v: summarize([t for t in trials if str((t.get("values") or {}).get(by)) == v]) for v in values
        }
        return {**summarize(trials), "by": by, "groups": groups}

    ok = [t for t in trials if t["status"] == "ok"]
    finished = [t for t in trials if t["status"] in ("ok", "failed")]
    names = sorted({k for t in ok for k in t.get("figures", {})})
    return {
        "statistics": {k: statistics([t["figures"][k] for t in ok if k in t["figures"]]) for k in names},
        "failure_rate": (len(finished) - len(ok)) / len(finished) if finished else 0.0,
        "counts": {
            "trials": len(trials),
            "ok": len(ok),
            "failed": len(finished) - len(ok),
            "lost": sum(t["status"] == "lost" for t in trials),
            "pending": sum(t["status"] == "pending" for t in trials),
            "resumed": sum(bool(t.get("resumed")) for t in trials),
        },
    }


def _prepare_function(function: str, parsed: dict[str, Distribution], seed: int, trials: int):
    """Function mode: (draws, per-trial fingerprint texts, job name, source hash, its search root)."""
    from weldcell.sdk.scale import trial_function

    if not _FUNCTION.match(function):
        raise UsageError(f"--function {function!r} is not MODULE:FUNCTION", "e.g. mypkg.protocols:trial")
    trial_function.resolve(function)
    draws = draw_trials(seed, trials, parsed)
    texts = [
        json.dumps({"function": function, "trial": i, "seed": s, "values": v}, sort_keys=True)
        for i, (s, v) in enumerate(draws)
    ]
    root = trial_function.search_root(function)
    return draws, texts, function, trial_function.fingerprint(function), (root,) if root else ()


# one parameter per `weldcell study` option (the command passes them by name); the body is the steps
# below, each taking only what it uses
def run_study(
    profile: Path | None,
    trials: int,
    vary: list[str],
    out_dir: Path,
    options: ClusterOptions,
    seed: int = 0,
    keep_runs: bool = False,
    reports: bool = False,
    progress: Any = None,
    function: str | None = None,
    by: str | None = None,
) -> dict[str, Any]:
    """Run ``trials`` seeded trials of ``profile``'s simulated job, or of the trial ``function``
    (``MODULE:FUNCTION``, see :mod:`~weldcell.sdk.scale.trial_function`); write OUT_DIR; return
    ``study.json``. ``by``: a varied key whose values group the statistics (``study["groups"]``)."""
    from weldcell.sdk.scale.report import write_study_report

    parsed = _check_request(profile, trials, vary, function, by)
    base: Path | None = None
    if function is not None:
        draws, texts, job, base_sha, roots = _prepare_function(function, parsed, seed, trials)
        options = options.model_copy(update={"python_path": (*options.python_path, *roots)})
    else:
        base = Path(profile).resolve()
        draws, texts, job, base_sha = _prepare_profile(base, parsed, seed, trials, reports)
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    run_id = f"{datetime.now(UTC).strftime('%Y%m%d%H%M%S')}-{np.random.default_rng().integers(1 << 24):06x}"
    study = _new_study(base, function, job, seed, trials, parsed, run_id, draws)
    with open_runner(options) as runner:
        study["runner"] = runner.description
        if function is not None and not runner.in_process:
            from weldcell.sdk.scale import trial_function

            trial_function.check_workers(runner.client, function, options.python_path)
        fingerprints = [hashlib.sha256((text + base_sha).encode()).hexdigest()[:16] for text in texts]
        batch = [
            TrialTask(
                i,
                s,
                v,
                texts[i] if function is None else "",
                str(out_dir),
                fingerprints[i],
                run_id,
                options.retries,
                options.time_limit,
                not runner.in_process,
                keep_runs,
                function,
            )
            for i, (s, v) in enumerate(draws)
        ]
        if progress is not None:
            progress.start(len(batch), f"{trials} trials of {job} on {runner.description}")
        try:
            _collect(runner, batch, study, out_dir, run_id, progress)
        finally:
            if progress is not None:
                progress.stop()
            study.update(
                summarize(list(study["trials"].values()), by), finished=datetime.now(UTC).isoformat()
            )
            artifacts.write_json(out_dir / "study.json", study)
            write_study_report(out_dir, study)
    return study


def _check_request(
    profile: Path | None, trials: int, vary: list[str], function: str | None, by: str | None
) -> dict[str, Distribution]:
    """The --vary distributions by key, once the request is one a study can run."""
    if trials < 1:
        raise UsageError(f"--trials {trials}: at least one trial", "give --trials N with N >= 1")
    if (profile is None) == (function is None):
        raise UsageError(
            "a study runs a PROFILE's job or a --function, one of the two",
            "give a simulation profile, or --function MODULE:FUNCTION without a profile",
        )
    parsed = dict(parse_vary(v) for v in vary)
    if by is not None and by not in parsed:
        raise UsageError(f"--by {by}: not a varied key", f"give one of: {', '.join(parsed) or '(none)'}")
    return parsed


def _new_study(
    base: Path | None,
    function: str | None,
    job: str,
    seed: int,
    trials: int,
    parsed: dict[str, Distribution],
    run_id: str,
    draws: list[tuple[int, dict[str, Any]]],
) -> dict[str, Any]:
    """``study.json`` before any trial ran: what was asked, and every trial pending."""
    return {
        "schema": STUDY_SCHEMA,
        "profile": str(base) if base is not None else None,
        "function": function,
        "job": job,
        "seed": seed,
        "trials_requested": trials,
        "vary": {k: d.text.split("=", 1)[1].strip() for k, d in parsed.items()},
        "units": {k: d.unit for k, d in parsed.items()},
        "run": run_id,
        "trials": {
            str(i): {"trial": i, "seed": s, "values": v, "status": "pending"}
            for i, (s, v) in enumerate(draws)
        },
    }


def _prepare_profile(base: Path, parsed: dict, seed: int, trials: int, reports: bool):
    """The seeded draws, each trial's profile text, the job's name and the hash of the base profile and
    every file it extends (a changed file is a new study)."""
    from weldcell.sdk.plugins import get_plugin_manager
    from weldcell.sdk.profile import load_profile

    files = load_profile(base).files
    draws = draw_trials(seed, trials, parsed)
    texts = [trial_profile(base, i, s, v, parsed, reports) for i, (s, v) in enumerate(draws)]
    job = check_profile(base, texts[0], get_plugin_manager())
    base_sha = tasks.sha256_path(base) + "".join(artifacts.sha256_file(f) for f in files)
    return draws, texts, job, base_sha


def _collect(runner, batch: list[TrialTask], study: dict, out_dir: Path, run_id: str, progress) -> None:
    """Each trial's record into ``study["trials"]`` as it finishes; a task the runner lost is recorded
    with the reason its attempts left (``status: lost``)."""
    for outcome in runner.map_unordered(
        run_trial, batch, [f"weldcell-trial-{run_id}-{t.trial}" for t in batch]
    ):
        t: TrialTask = outcome.item
        rec = outcome.value
        if outcome.error is not None:
            why = tasks.lost_reason(
                tasks.read_attempts(out_dir / tasks.WORK / f"trial-{t.trial:05d}" / "attempts.jsonl", run_id)
            )
            why = why or f"{type(outcome.error).__name__}: {outcome.error}"
            rec = {
                "trial": t.trial,
                "seed": t.seed,
                "values": t.values,
                "status": "lost",
                "error": {"type": "TaskLost", "message": why, "line": why},
            }
        study["trials"][str(t.trial)] = rec
        if progress is not None:
            progress.advance(
                rec["status"] == "ok",
                rec.get("resumed", False),
                f"trial {t.trial}",
                (rec.get("error") or {}).get("line", ""),
            )


@contextlib.contextmanager
def shared_cluster(options: ClusterOptions) -> Iterator[ClusterOptions]:
    """Options under which several studies share one cluster (e.g. one study per row of a table): when
    ``options`` ask for an embedded ``LocalCluster`` it is started once here and its address handed to
    each study; an existing scheduler or ``workers=0`` is passed on unchanged."""
    if options.scheduler_address() is not None or options.workers == 0:
        yield options
        return
    from weldcell.sdk.scale.cluster import _local_cluster, require_dask

    require_dask()
    with _local_cluster(options) as cluster:
        yield options.model_copy(update={"scheduler": cluster.scheduler_address, "workers": None})
