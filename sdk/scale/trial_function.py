"""``weldcell study --function MODULE:FUNCTION``: Monte-Carlo trials of a Python function instead of a job.

Some protocols are not a whole job: the relocalization trials of paper 004's Table IV run against one
prepared prior map, the pose-accuracy protocol of paper 000's Table I scans a part from a fixed ring of
views. Such a protocol is a *trial function*::

    def trial(values: dict[str, Any], seed: int, trial: int) -> dict[str, Any]:
        '''One trial: ``values`` are the drawn --vary settings (plain keys, SI units), ``seed`` the
        trial's own seed (from the study's --seed), ``trial`` its index. Returns the trial's figures
        (numbers, possibly nested: flattened to "a.b"); raises a WeldcellError for a failed trial.'''

It runs like a trial of a profile: seeded and reproducible, one Dask task each, retried when its worker
dies, resumed when the study is run again (a trial is redone when its values, seed or the function's
source file changed). Any other exception than a WeldcellError is a failed trial too, with its traceback
in ``trials/<i>/log.txt``. The function's module must be importable on every worker: an installed
package (a plugin's public module), or a folder on storage every worker sees (the folder the module was
found in here is put on the workers' ``sys.path``); every worker is checked before a trial is sent.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from weldcell.sdk import artifacts
from weldcell.sdk.errors import PluginError, UsageError, WeldcellError
from weldcell.sdk.scale import tasks

TrialFunction = Callable[..., dict[str, Any]]
_FIX = (
    "give --function MODULE:FUNCTION with an importable module, e.g. weldcell.plugins.relocalize.table4:trial"
)


def resolve(spec: str) -> TrialFunction:
    """The callable named ``MODULE:FUNCTION``, or a :class:`UsageError` saying what is wrong."""
    module, _, name = spec.partition(":")
    if not module or not name:
        raise UsageError(f"--function {spec!r} is not MODULE:FUNCTION", _FIX)
    try:
        mod = importlib.import_module(module)
    except ImportError as e:
        raise UsageError(f"--function {spec}: cannot import {module}: {e}", _FIX) from None
    fn = getattr(mod, name, None)
    if not callable(fn):
        raise UsageError(f"--function {spec}: {module} has no function {name!r}", _FIX)
    return fn


def source(spec: str) -> Path | None:
    """The file that defines ``spec``'s module (None for a built-in one)."""
    found = importlib.util.find_spec(spec.partition(":")[0])
    return Path(found.origin) if found is not None and found.origin not in (None, "built-in") else None


def search_root(spec: str) -> str | None:
    """The ``sys.path`` folder ``spec``'s module was found in (put on the workers' path)."""
    f = source(spec)
    if f is None:
        return None
    depth = len(spec.partition(":")[0].split(".")) - (0 if f.name == "__init__.py" else 1)
    return str(f.parents[depth])


def fingerprint(spec: str) -> str:
    """SHA-256 of the Python files beside the function's module (its package): a changed function, or a
    changed module of its package, redoes its trials on resume. Code elsewhere is not covered: after
    changing it, give the study a new OUT_DIR."""
    f = source(spec)
    if f is None or not f.is_file():
        return spec
    h = hashlib.sha256()
    for g in sorted(f.parent.glob("*.py")):
        h.update(g.name.encode() + b"\0" + bytes.fromhex(artifacts.sha256_file(g)))
    return h.hexdigest()


def importable(spec: str, roots: tuple[str, ...] = ()) -> str:
    """Run on a worker: '' when ``spec`` resolves there, else why not."""
    for r in roots:
        if r not in sys.path:
            sys.path.insert(0, r)
    try:
        resolve(spec)
    except UsageError as e:
        return e.message
    return ""


def check_workers(client: Any, spec: str, roots: tuple[str, ...]) -> None:
    """Every worker can import the trial function, or a :class:`PluginError` naming who cannot."""
    answers = client.run(importable, spec, roots, on_error="return")
    bad = {
        a: (v if not isinstance(v, BaseException) else f"{type(v).__name__}: {v}") for a, v in answers.items()
    }
    bad = {a: v for a, v in bad.items() if v}
    if bad:
        raise PluginError(
            "workers cannot run the trial function: "
            + "; ".join(f"{a}: {v}" for a, v in sorted(bad.items())),
            f"install the module of {spec} on every worker, or put it on storage they all see "
            f"(its folder here: {roots[0] if roots else '?'})",
        )


def call(spec: str, values: dict[str, Any], seed: int, trial: int, log: Path) -> dict[str, Any]:
    """Run the trial function (in a worker): ``{"status", "figures"}`` or ``{"status", "error"}``."""
    try:
        fn = resolve(spec)
        with tasks.captured_output(log):
            try:
                result = fn(dict(values), seed=seed, trial=trial)
            except Exception:
                traceback.print_exc()
                raise
    except WeldcellError as e:
        return {"status": "failed", "error": tasks.error_record(e), "figures": {}}
    except Exception as e:  # noqa: BLE001 - a bug in one trial is that trial's failure, the study goes on
        return {"status": "failed", "error": tasks.error_record(e), "figures": {}}
    if not isinstance(result, dict):
        e = TypeError(f"{spec} returned {type(result).__name__}, not a dict of figures")
        return {"status": "failed", "error": tasks.error_record(e), "figures": {}}
    return {"status": "ok", "figures": tasks.flatten_numbers(result)}
