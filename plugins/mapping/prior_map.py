"""The prior map of a visit on a real robot (paper 004 §II-E): ``revisit.prior_map``.

On hardware there is no simulated second drive: the robot maps the site in one run, and a later run,
with ``revisit = { enabled = true, prior_map = ... }``, is the second visit. After its own map is made it
is relocalized against the prior map and the prior map is updated (``RUN/map_versions``), as the
simulated second visit does. ``prior_map`` is either

* a map folder written by the ``map`` job (``RUN/map``: ``manifest.json`` of ``weldcell/map-segments@1``
  and, for the map update's free-space evidence and the priors, the key-frame store ``keyframes.json``),
  a run folder holding one (``RUN``), or a folder fetched with ``weldcell map fetch`` (local maps only:
  relocalized against, and only removals are detected, see docs/methods/map-segmentation.md); or
* the address of a map server (``tcp://HOST:PORT``, ``weldcell map serve``): fetched into
  ``RUN/prior_map`` with the ``map-transfer`` stage's client at the start of the relocalization.

A relative folder is relative to the profile that sets it, as every path in a profile. An absolute folder
is checked when the profile is loaded (:func:`check_prior_map`, one clear error naming what is wrong), a
relative one when the job starts, before the robot drives (:func:`check_at_start`); the files
themselves are read with their documented formats (docs/file-formats.md), not with
the transfer plugin's code.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator

ADDRESS = re.compile(r"tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):\d{1,5}")
SEGMENTS_SCHEMA = "weldcell/map-segments@1"


def is_address(value: str) -> bool:
    return value.startswith("tcp://")


def map_folder(value: str | Path, base: Path | None = None) -> Path:
    """The map folder a ``prior_map`` path names (a run folder means its ``map``); a relative path is
    relative to ``base`` (the folder of the profile that sets it), as every path in a profile."""
    p = Path(value).expanduser()
    if base is not None and not p.is_absolute():
        p = base / p
    return p / "map" if not (p / "manifest.json").exists() and (p / "map" / "manifest.json").exists() else p


def prior_map_problem(folder: Path) -> str | None:
    """Why ``folder`` is not a usable prior map (message with the fix), or None."""
    fix = "give RUN/map of an earlier `weldcell run` of the map job, or a folder from `weldcell map fetch`"
    if not folder.is_dir():
        return f"prior map {folder} does not exist; {fix}"
    m = folder / "manifest.json"
    if not m.is_file():
        return f"prior map {folder} has no manifest.json (not a segmented map folder); {fix}"
    try:
        doc = json.loads(m.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        return f"prior map {m} is not readable JSON ({e}); {fix}"
    if not isinstance(doc, dict) or doc.get("schema") != SEGMENTS_SCHEMA:
        got = doc.get("schema") if isinstance(doc, dict) else None
        return f"prior map {m} is not {SEGMENTS_SCHEMA} (schema {got!r}); {fix}"
    segs = doc.get("segments") or []
    if not segs:
        return f"prior map {folder} has no local maps; map the site first (job map)"
    if not doc.get("complete"):
        return f"prior map {folder} is not complete (its run or fetch stopped early); finish or fetch it"
    for e in segs:
        f = folder / str(e.get("file", ""))
        if not f.is_file() or f.stat().st_size != e.get("bytes"):
            return (
                f"prior map {folder}: local map {e.get('id')} ({f.name}) is missing or has the wrong size; "
                "fetch or copy the map folder again"
            )
    return None


def check_prior_map(value: str | None) -> str | None:
    """Validator of ``revisit.prior_map``: a usable map folder, or a well-formed ``tcp://HOST:PORT``."""
    if value is None:
        return None
    value = str(value).strip()
    if is_address(value):
        if not ADDRESS.fullmatch(value):
            raise ValueError(f"prior map server address {value!r} is not tcp://HOST:PORT")
        return value
    if not Path(value).expanduser().is_absolute():
        return value  # relative to the profile, which is not known here: checked when the job starts
    problem = prior_map_problem(map_folder(value))
    if problem:
        raise ValueError(problem)
    return value


def resolve_prior_map(ctx) -> Path:
    """The prior map folder of this run: the configured folder, or the server's map fetched into
    ``RUN/prior_map`` (the checks of :func:`prior_map_problem` apply to the fetched folder too)."""
    from weldcell.sdk.errors import DataError

    value = ctx.settings.revisit.prior_map
    if is_address(value):
        out = ctx.path("prior_map") / ""
        ctx.stage("transfer").fetch(value, out)
        folder = out
    else:
        folder = configured_folder(ctx)
    problem = prior_map_problem(folder)
    if problem:
        raise DataError(problem, "check revisit.prior_map in the profile")
    return folder


def configured_folder(ctx) -> Path:
    """The folder ``revisit.prior_map`` names, a relative path taken from the profile that sets it."""
    loaded = getattr(ctx, "loaded", None)
    base = loaded.source_of(("job", "settings", "revisit", "prior_map")).parent if loaded else None
    return map_folder(ctx.settings.revisit.prior_map, base)


def check_at_start(ctx) -> None:
    """Refuse a prior map folder that is not usable before the robot drives (an address is fetched, and
    checked, when the relocalization starts)."""
    from weldcell.sdk.errors import DataError

    value = ctx.settings.revisit.prior_map
    if value is None or is_address(value):
        return
    problem = prior_map_problem(configured_folder(ctx))
    if problem:
        raise DataError(problem, "check revisit.prior_map in the profile")


PriorMapRef = Annotated[str | None, AfterValidator(check_prior_map)]
"""The type of ``revisit.prior_map``: checked when the profile is loaded (a relative folder when the job
starts, :func:`check_at_start`)."""
