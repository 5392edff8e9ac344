"""A progress bar for tasks that complete in any order: done / failed, rate, ETA.

It is driven by the client as results arrive (``distributed.as_completed``), so it shows the same thing
for a local cluster, a remote one, or tasks run in this process. Each failed input also gets one line
above the bar (input and error line), so a person sees a failure when it happens, not at the end.
"""

from __future__ import annotations

import sys
import time

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn


class TaskProgress:
    """``start(total, title)``, ``advance(ok, resumed, name, error)`` per finished task, ``stop()``."""

    def __init__(self, quiet: bool = False, console: Console | None = None) -> None:
        # the stream is bound now: a command running in this process (--workers 0) may redirect sys.stderr
        self.console = console or Console(file=sys.stderr, highlight=False)
        self.quiet = quiet
        self.done = self.failed = self.resumed = 0
        self.total = 0
        self._t0 = 0.0
        self._progress: Progress | None = None
        self._task = None

    def start(self, total: int, title: str) -> None:
        self.total, self._t0 = total, time.monotonic()
        if self.quiet:
            return
        self._progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[status]}"),
            TimeElapsedColumn(),
            console=self.console,
            transient=False,
        )
        self._progress.start()
        self._task = self._progress.add_task(title, total=total, status=self.status_text())

    def rate(self) -> float:
        """Tasks run per second so far (resumed ones, which cost nothing, left out)."""
        ran = self.done - self.resumed
        dt = time.monotonic() - self._t0
        return ran / dt if dt > 0 and ran > 0 else 0.0

    def eta(self) -> float | None:
        """Seconds left at the current rate (None before the first task ran)."""
        r = self.rate()
        return (self.total - self.done) / r if r > 0 else None

    def status_text(self) -> str:
        eta = self.eta()
        eta_txt = "--:--" if eta is None else f"{int(eta // 60):02d}:{int(eta % 60):02d}"
        failed = f"[red]{self.failed} failed[/red]" if self.failed else "0 failed"
        resumed = f", {self.resumed} already done" if self.resumed else ""
        return f"{failed}{resumed}  {self.rate():.2f} tasks/s  ETA {eta_txt}"

    def advance(self, ok: bool, resumed: bool = False, name: str = "", error: str = "") -> None:
        self.done += 1
        self.failed += not ok
        self.resumed += bool(resumed)
        if not ok and not self.quiet:
            self.console.print(f"  [red]✗[/red] {escape(name)}: {escape(error)}")
        if self._progress is not None:
            self._progress.update(self._task, completed=self.done, status=self.status_text())

    def stop(self) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None
