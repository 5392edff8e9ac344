"""The errors weldcell raises on purpose.

Every error carries a one-line ``message`` (what is wrong) and a ``fix`` (what to do about it).
The CLI prints ``error: <message>`` and ``  fix: <fix>`` and exits with the class's ``exit_code``;
``--debug`` adds the traceback. Scripts can rely on the exit codes (docs/cli.md).
"""

from __future__ import annotations


class WeldcellError(Exception):
    """Base of all deliberate weldcell errors."""

    exit_code = 1

    def __init__(self, message: str, fix: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.fix = fix

    def __str__(self) -> str:
        return self.message if not self.fix else f"{self.message}\n  fix: {self.fix}"


class UsageError(WeldcellError):
    """A command was called with wrong arguments or unreadable input files."""

    exit_code = 2


class DataError(WeldcellError):
    """Input data is unusable: empty or NaN clouds, wrong units, a scan without a pose, ..."""

    exit_code = 2


class ProfileError(WeldcellError):
    """A cell profile is invalid. ``problems`` lists every problem found, each with file and key path."""

    exit_code = 3

    def __init__(self, message: str, fix: str | None = None, problems: list[str] | None = None) -> None:
        super().__init__(message, fix)
        self.problems = problems or []

    def __str__(self) -> str:
        if not self.problems:
            return super().__str__()
        return "\n".join([self.message, *(f"  - {p}" for p in self.problems)])


class PluginError(WeldcellError):
    """A plugin failed to load or register, or two plugins claim the same name."""

    exit_code = 4


class UnknownPluginError(PluginError):
    """A name was asked for that no loaded plugin provides."""


class MissingExtraError(PluginError):
    """A plugin needs an optional dependency that is not installed."""

    def __init__(self, what: str, module: str, extra: str, distribution: str = "weldcell") -> None:
        super().__init__(
            f"{what} needs the Python package '{module}', which is not installed",
            f"pip install '{distribution}[{extra}]'",
        )
        self.module = module
        self.extra = extra


class DeviceError(WeldcellError):
    """A device is unreachable, disconnected, or in its error state."""

    exit_code = 5


class SafetyError(WeldcellError):
    """A motion command failed the cell's safety gate; it was not sent to the robot."""

    exit_code = 6


class JobError(WeldcellError):
    """A job could not complete; artifacts captured so far are kept in the run folder."""

    exit_code = 1


class JobWarning(JobError):
    """The job finished and wrote everything, but its result needs a person before it is used
    (a seam found over only part of its length). ``result.json`` says ``"status": "warning"``."""

    exit_code = 7
    warning = True
