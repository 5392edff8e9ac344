"""What a worker does with one task: attempts, time limit, atomic publication of the result.

Shared by ``weldcell batch`` (one input through an offline command) and ``weldcell study`` (one trial of
a simulated job). A task works in ``OUT_DIR/.work/<key>/<run>-<attempt>/`` and publishes that folder
into place with one ``rename``: a reader (or a re-run) finds a complete result or none, and when two
attempts of the same task both finish (a worker presumed dead that was not), the first rename wins and
the second result is discarded: nothing is written twice.

Attempts are counted in ``OUT_DIR/.work/<key>/attempts.jsonl`` (one line when an attempt starts, one
when it ends). An attempt that started and never ended lost its worker (killed, out of memory) or was
stopped at its time limit; after ``retries`` such attempts the next one gives up and the task is
recorded as failed with that reason. An error raised by the command itself is not retried: it would
fail again the same way.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from weldcell.sdk import artifacts

WORK = ".work"
EXIT_TIME_LIMIT = 71


class GiveUp(Exception):
    """The task already lost its worker (or ran out of time) more often than it may be retried."""


def _append_line(path: Path, record: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a", encoding="utf-8") as f:
        f.write(json.dumps(record) + "\n")
        f.flush()
        os.fsync(f.fileno())


def read_attempts(path: Path, run_id: str) -> list[dict[str, Any]]:
    """Attempts of run ``run_id``: ``{"n", "pid", "host", "end"}`` (``end`` missing: never ended)."""
    if not path.is_file():
        return []
    out: dict[int, dict[str, Any]] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:  # a line cut by a crash
            continue
        if rec.get("run") != run_id:
            continue
        out.setdefault(rec["n"], {}).update(rec)
    return [out[n] for n in sorted(out)]


def lost_reason(attempts: list[dict[str, Any]]) -> str | None:
    """Why the task's attempts were lost (worker died, time limit), or None when none was."""
    lost = [a for a in attempts if a.get("end") in (None, "timeout")]
    if not lost:
        return None
    timeouts = [a for a in lost if a.get("end") == "timeout"]
    if timeouts:
        return f"ran past its time limit of {timeouts[-1]['limit']:g} s ({len(lost)} attempt(s) lost)"
    where = ", ".join(sorted({f"{a.get('host')}:{a.get('pid')}" for a in lost}))
    return f"its worker process died while running it {len(lost)} time(s) (killed or out of memory; {where})"


@dataclass
class Attempt:
    """One attempt at a task: counts itself, arms the time limit, gives up after ``retries`` lost ones."""

    work: Path
    run_id: str
    retries: int
    time_limit: float | None = None
    hard_limit: bool = True
    """Stop the worker process at the time limit (a thread cannot be stopped); False in-process."""
    n: int = 0
    _timer: threading.Timer | None = field(default=None, repr=False)

    @property
    def log(self) -> Path:
        return self.work / "attempts.jsonl"

    def start(self) -> Path:
        """Count this attempt; returns its scratch folder. Raises :class:`GiveUp` when too many were lost."""
        previous = read_attempts(self.log, self.run_id)
        lost = [a for a in previous if a.get("end") in (None, "timeout")]
        if len(lost) > self.retries:
            raise GiveUp(lost_reason(previous) or "too many attempts")
        self.n = (previous[-1]["n"] if previous else 0) + 1
        _append_line(
            self.log,
            {
                "run": self.run_id,
                "n": self.n,
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "t": time.time(),
            },
        )
        scratch = self.work / f"{self.run_id}-{self.n}"
        shutil.rmtree(scratch, ignore_errors=True)
        scratch.mkdir(parents=True)
        return scratch

    def arm(self) -> None:
        """Start the time limit (call when the work itself begins)."""
        if self.time_limit is not None and self.hard_limit:
            self._timer = threading.Timer(self.time_limit, self._expire)
            self._timer.daemon = True
            self._timer.start()

    def _expire(self) -> None:
        """The time limit passed: record it, then end this worker process (its nanny starts a new one
        and the scheduler re-runs or gives up the task)."""
        with contextlib.suppress(OSError):
            _append_line(
                self.log, {"run": self.run_id, "n": self.n, "end": "timeout", "limit": self.time_limit}
            )
        os._exit(EXIT_TIME_LIMIT)

    def end(self, status: str) -> None:
        """The attempt ended (``ok`` or ``failed``) without losing its worker."""
        if self._timer is not None:
            self._timer.cancel()
        _append_line(self.log, {"run": self.run_id, "n": self.n, "end": status})


def publish(scratch: Path, target: Path) -> bool:
    """Move the finished ``scratch`` folder to ``target`` in one rename. False (and ``scratch`` removed)
    when ``target`` already holds a result: the first finished attempt wins."""
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.rename(scratch, target)
    except OSError:
        if target.exists():
            shutil.rmtree(scratch, ignore_errors=True)
            return False
        raise
    artifacts.fsync_dir(target.parent)
    return True


def replace_folder(scratch: Path, target: Path, trash: Path) -> None:
    """Put ``scratch`` at ``target``, moving an older ``target`` into ``trash`` first."""
    if target.exists():
        shutil.rmtree(trash, ignore_errors=True)
        with contextlib.suppress(OSError):
            os.rename(target, trash)
    if not publish(scratch, target):  # another attempt replaced it meanwhile: keep theirs
        return
    shutil.rmtree(trash, ignore_errors=True)


def clear_folder(folder: Path, work: Path) -> None:
    """Remove ``folder``: renamed into ``work`` first (one step), then deleted."""
    if folder.exists():
        work.mkdir(parents=True, exist_ok=True)
        trash = work / f"removed-{os.getpid()}-{time.time_ns()}"
        with contextlib.suppress(OSError):
            os.rename(folder, trash)
        shutil.rmtree(trash, ignore_errors=True)


def sha256_path(path: Path) -> str:
    """SHA-256 of a file, or of a folder (every file's relative path and bytes, in sorted order)."""
    if path.is_file():
        return artifacts.sha256_file(path)
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(path)).encode() + b"\0")
        h.update(bytes.fromhex(artifacts.sha256_file(f)))
    return h.hexdigest()


def output_checksums(folder: Path, skip: tuple[str, ...] = ()) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``folder`` except ``skip``."""
    return {
        str(f.relative_to(folder)): artifacts.sha256_file(f)
        for f in sorted(folder.rglob("*"))
        if f.is_file() and str(f.relative_to(folder)) not in skip
    }


def outputs_intact(folder: Path, recorded: dict[str, str]) -> bool:
    """Every recorded output file is there with its recorded checksum."""
    for name, digest in recorded.items():
        f = folder / name
        if not f.is_file() or artifacts.sha256_file(f) != digest:
            return False
    return True


@contextlib.contextmanager
def captured_output(log: Path) -> Iterator[None]:
    """Send what the command prints (stdout and stderr) to ``log``."""
    import io

    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            yield
    finally:
        artifacts.write_text(log, buf.getvalue())


def flatten_numbers(
    data: Any, prefix: str = "", depth: int = 3, skip: tuple[str, ...] = ()
) -> dict[str, float]:
    """Numeric leaves of nested dicts as ``{"a.b": value}`` (bools as 0/1; lists and text left out)."""
    out: dict[str, float] = {}
    if not isinstance(data, dict) or depth < 0:
        return out
    for k, v in data.items():
        if k in skip:
            continue
        key = f"{prefix}{k}"
        if isinstance(v, bool):
            out[key] = float(v)
        elif isinstance(v, int | float) and v == v:  # NaN left out
            out[key] = float(v)
        elif isinstance(v, dict):
            out.update(flatten_numbers(v, key + ".", depth - 1, skip))
    return out


def error_record(e: BaseException, log_tail: str = "") -> dict[str, Any]:
    """``{"type", "message", "fix", "exit_code", "line"}`` of an exception (``line``: the one line a
    table shows)."""
    from weldcell.sdk.errors import WeldcellError

    if isinstance(e, WeldcellError):
        return {
            "type": type(e).__name__,
            "message": e.message,
            "fix": e.fix,
            "exit_code": e.exit_code,
            "line": e.message.splitlines()[0] if e.message else type(e).__name__,
        }
    message = str(e) or log_tail or type(e).__name__
    return {
        "type": type(e).__name__,
        "message": message,
        "fix": None,
        "exit_code": 1,
        "line": f"{type(e).__name__}: {message.splitlines()[0]}",
    }
