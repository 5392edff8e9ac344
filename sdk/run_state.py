"""A run's resumable record, ``state.json``: its steps with their kinds and status, and its captures
with their sizes and SHA-256, saved atomically and durably after every change.

:class:`weldcell.sdk.jobs.RunContext` keeps one :class:`RunState` per run; a resumed run reads it back to
know which steps are done, which motion was interrupted and which captures are intact.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from weldcell.sdk import artifacts, secrets
from weldcell.sdk.errors import JobError, UsageError

STATE_SCHEMA = "weldcell/run-state@2"
STARTED = ("running", "failed", "interrupted")  # a step that began and did not finish


def utc_now() -> str:
    """The time now, UTC, ISO 8601 to the second."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def step_key(name: str) -> str:
    """The short name ``--redo`` accepts for a step: its words before any '(' (lower case)."""
    return name.split(" (")[0].strip().lower()


def step_label(name: str, plugins: list[str]) -> str:
    """How a finished step is shown: its name's words before any '(' with the stage plugins that ran in
    it (``denoise (denoise.bilateral)``), so the label never names a method that did not run; the name
    as given when no stage ran in it or it already names them all."""
    if not plugins or all(p in name for p in plugins):
        return name
    return f"{name.split(' (')[0].strip()} ({', '.join(plugins)})"


@dataclass
class RunState:
    """The resumable part of a run, saved to ``state.json`` (atomically, durably) after every change.

    ``steps``: name -> ``{"kind", "status", "attempts", "seconds", "error", ...}``; ``captures``: what
    the job captured, each with ``file``, ``bytes`` and ``sha256`` of that file; ``notes``: job data.
    """

    path: Path
    data: dict[str, Any] = field(
        default_factory=lambda: {"schema": STATE_SCHEMA, "steps": {}, "captures": [], "notes": {}}
    )

    @classmethod
    def load_or_new(cls, path: Path) -> RunState:
        if path.is_file():
            data = artifacts.read_json(path)
            if not isinstance(data, dict) or not isinstance(data.get("steps"), dict):
                raise JobError(
                    f"{path} is not a weldcell run state",
                    "give the folder of an earlier run, or start a new run",
                )
            data.setdefault("captures", [])
            data.setdefault("notes", {})
            return cls(path, data)
        state = cls(path)
        state.save()
        return state

    def save(self) -> None:
        artifacts.write_json(self.path, secrets.redact_obj(self.data))

    @property
    def run_dir(self) -> Path:
        return self.path.parent

    # -- steps -----------------------------------------------------------------------------------
    @property
    def steps(self) -> dict[str, dict[str, Any]]:
        return self.data["steps"]

    def status(self, name: str) -> str | None:
        """``running`` (or killed while running), ``failed``, ``interrupted``, ``done``, or None."""
        return self.steps.get(name, {}).get("status")

    def step_done(self, name: str) -> bool:
        return self.status(name) == "done"

    def set_step(self, name: str, **fields: Any) -> None:
        """Update a step's record and save at once."""
        self.steps.setdefault(name, {}).update(fields)
        self.save()

    def interrupted_motions(self) -> list[str]:
        """Motion steps that started and did not finish: the robot may have moved, or welded part way."""
        return [n for n, r in self.steps.items() if r.get("kind") == "motion" and r.get("status") in STARTED]

    def match_step(self, key: str) -> str:
        """The recorded step a ``--redo`` argument names: its full name or :func:`step_key`."""
        names = list(self.steps)
        k = " ".join(key.split()).lower()
        exact = (
            [n for n in names if n == key]
            or [n for n in names if step_key(n) == k]
            or [n for n in names if step_key(n).startswith(k + " ")]  # 'execute' for 'execute weld path'
        )
        if len(exact) != 1:
            known = ", ".join(f"'{step_key(n)}'" for n in names if not n.startswith("open ")) or "none"
            raise UsageError(
                f"--redo {key!r}: {'no' if not exact else 'more than one'} step of this run has that name",
                f"name one of the steps recorded in {self.path}: {known}",
            )
        return exact[0]

    # -- captures --------------------------------------------------------------------------------
    @property
    def captures(self) -> list[dict[str, Any]]:
        """Captures recorded so far (each a dict a job defines, e.g. file name + pose)."""
        return self.data["captures"]

    def add_capture(self, record: dict[str, Any]) -> None:
        """Record a capture and save at once, so an interruption never loses it.

        When the record names a ``file`` (relative to the run folder) that exists, its size (``bytes``)
        and ``sha256`` are recorded with it, for :meth:`check_capture` on resume.
        """
        record = dict(record)
        f = self.run_dir / record["file"] if isinstance(record.get("file"), str) else None
        if f is not None and f.is_file():
            record["bytes"] = f.stat().st_size
            record["sha256"] = artifacts.sha256_file(f)
        self.data["captures"].append(record)
        self.save()

    def check_capture(self, index: int) -> str | None:
        """What is wrong with capture ``index``'s file (missing, truncated, changed), or None if intact."""
        rec = self.captures[index]
        name = rec.get("file")
        if not isinstance(name, str):
            return None
        f = self.run_dir / name
        if not f.is_file():
            return f"capture {index} ({name}) is missing"
        size = f.stat().st_size
        if "bytes" in rec and size != rec["bytes"]:
            what = "truncated" if size < rec["bytes"] else "longer than recorded"
            return f"capture {index} ({name}) is damaged: {what} ({size} of {rec['bytes']} bytes)"
        if "sha256" in rec and artifacts.sha256_file(f) != rec["sha256"]:
            return f"capture {index} ({name}) is damaged: its checksum differs from the one recorded"
        return None

    def first_damaged_capture(self) -> tuple[int, str] | None:
        """(index, problem) of the first capture that fails :meth:`check_capture`, or None."""
        for i in range(len(self.captures)):
            problem = self.check_capture(i)
            if problem:
                return i, problem
        return None

    def discard_captures(self, start: int, reason: str, count: int | None = None) -> list[dict[str, Any]]:
        """Take captures ``start:`` (``count`` of them; all after ``start`` by default) out of the run, to be
        captured again. Nothing is deleted: their files are renamed ``<name>.discarded-<n>`` and their
        records kept under ``notes.discarded_captures``."""
        stop = len(self.captures) if count is None else start + count
        dropped = self.captures[start:stop]
        n = len(self.data["notes"].get("discarded_captures", [])) + 1
        for rec in dropped:
            f = self.run_dir / rec["file"] if isinstance(rec.get("file"), str) else None
            if f is not None and f.exists():
                f.replace(f.with_name(f"{f.name}.discarded-{n}"))
        artifacts.fsync_dir(self.run_dir)
        self.data["notes"].setdefault("discarded_captures", []).append(
            {"reason": reason, "time": utc_now(), "captures": dropped}
        )
        del self.data["captures"][start:stop]
        self.save()
        return dropped
