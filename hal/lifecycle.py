"""Device lifecycle, modelled on ros2_control's hardware interface.

States::

    UNCONFIGURED --configure--> INACTIVE --activate--> ACTIVE
         ^                        |  ^                    |
         |                        |  +----deactivate------+
         +------- recover --- ERROR <-- (any failure) ----+
    close() from any state -> FINALIZED

Subclasses implement ``on_configure`` (connect, read parameters), ``on_activate`` (start
streaming / enable motion), ``on_deactivate``, ``on_close`` and optionally ``on_recover``.
A hook that raises puts the device into ERROR with the reason kept in ``health()``; ``recover()``
tries ``on_recover`` and returns to UNCONFIGURED. ``with device:`` configures and activates,
and always deactivates and closes on exit.
"""

from __future__ import annotations

import enum
import threading
import time
from dataclasses import dataclass

from weldcell.sdk.errors import DeviceError, WeldcellError


class State(enum.Enum):
    UNCONFIGURED = "unconfigured"
    INACTIVE = "inactive"
    ACTIVE = "active"
    ERROR = "error"
    FINALIZED = "finalized"


@dataclass(frozen=True)
class Health:
    """What ``Device.health()`` reports."""

    ok: bool
    state: State
    message: str = ""
    last_reading_age: float | None = None
    """Seconds since the last reading, or None when nothing was read yet."""


class Device:
    """Base of every HAL device: lifecycle, health, a name and a frame."""

    kind = "device"

    def __init__(self, name: str = "device", frame: str | None = None) -> None:
        self.name = name
        self.frame = frame or name
        self._state = State.UNCONFIGURED
        self._error = ""
        self._last_reading: float | None = None
        self._lock = threading.RLock()

    # -- hooks for adapters ----------------------------------------------------------------------
    def on_configure(self) -> None:
        """Connect and read device parameters (no streaming or motion yet)."""

    def on_activate(self) -> None:
        """Start streaming / enable commands."""

    def on_deactivate(self) -> None:
        """Stop streaming / motion; stay connected."""

    def on_close(self) -> None:
        """Release the connection. Must not raise for an already-broken connection."""

    def on_recover(self) -> None:
        """Clear a fault (reconnect, acknowledge a protective stop). Default: close and start again."""
        self.on_close()

    # -- transitions -----------------------------------------------------------------------------
    @property
    def lifecycle(self) -> State:
        """The lifecycle state (named so that robots can offer ``state()`` for their joint state)."""
        return self._state

    def _transition(self, allowed: tuple[State, ...], hook, target: State, verb: str) -> None:
        with self._lock:
            if self._state not in allowed:
                raise DeviceError(
                    f"{self.kind} '{self.name}' cannot {verb} while {self._state.value}",
                    self._hint(),
                )
            try:
                hook()
            except WeldcellError as e:
                self._fail(f"{verb} failed: {e.message}")
                raise
            except Exception as e:
                self._fail(f"{verb} failed: {type(e).__name__}: {e}")
                raise DeviceError(f"{self.kind} '{self.name}': {verb} failed: {e}", self._hint()) from e
            self._state = target

    def _hint(self) -> str:
        if self._state is State.ERROR:
            return "call recover() (or reconnect the device) and configure again"
        if self._state is State.FINALIZED:
            return "this device was closed; create a new one"
        return "follow configure() -> activate() -> deactivate() -> close()"

    def _fail(self, message: str) -> None:
        self._state = State.ERROR
        self._error = message

    def configure(self) -> None:
        self._transition((State.UNCONFIGURED,), self.on_configure, State.INACTIVE, "configure")

    def activate(self) -> None:
        self._transition((State.INACTIVE,), self.on_activate, State.ACTIVE, "activate")

    def deactivate(self) -> None:
        self._transition((State.ACTIVE,), self.on_deactivate, State.INACTIVE, "deactivate")

    def close(self) -> None:
        """Release the device from any state (idempotent)."""
        with self._lock:
            if self._state is State.FINALIZED:
                return
            try:
                if self._state is State.ACTIVE:
                    self.on_deactivate()
            finally:
                try:
                    self.on_close()
                finally:
                    self._state = State.FINALIZED

    def recover(self) -> None:
        """Leave the ERROR state: run ``on_recover`` and return to UNCONFIGURED."""
        with self._lock:
            if self._state is not State.ERROR:
                return
            try:
                self.on_recover()
            except Exception as e:
                self._error = f"recover failed: {e}"
                raise DeviceError(
                    f"{self.kind} '{self.name}': recover failed: {e}",
                    "check the device and its connection, then try again",
                ) from e
            self._state = State.UNCONFIGURED
            self._error = ""

    def fault(self, message: str) -> DeviceError:
        """Enter ERROR with ``message`` (for adapters that detect a fault); returns the error to raise."""
        self._fail(message)
        return DeviceError(f"{self.kind} '{self.name}': {message}", self._hint())

    def require_active(self) -> None:
        """Raise unless ACTIVE (call at the top of every reading or command)."""
        if self._state is not State.ACTIVE:
            msg = f"{self.kind} '{self.name}' is {self._state.value}, not active"
            if self._error:
                msg += f" ({self._error})"
            raise DeviceError(msg, self._hint())

    def mark_reading(self, stamp: float | None = None) -> float:
        """Record that a reading arrived now (or at ``stamp``); returns the stamp."""
        self._last_reading = time.time() if stamp is None else stamp
        return self._last_reading

    def health(self) -> Health:
        """State, the last error, and the age of the last reading."""
        age = None if self._last_reading is None else max(0.0, time.time() - self._last_reading)
        return Health(
            ok=self._state in (State.INACTIVE, State.ACTIVE),
            state=self._state,
            message=self._error,
            last_reading_age=age,
        )

    # -- context manager -------------------------------------------------------------------------
    def __enter__(self):
        try:
            if self._state is State.UNCONFIGURED:
                self.configure()
            if self._state is State.INACTIVE:
                self.activate()
        except BaseException:
            # __exit__ does not run when __enter__ raises: release what configure() opened here
            # (the reason stays in health().message); the original error propagates.
            try:
                self.close()
            except Exception:  # noqa: BLE001 - never mask the original error
                pass
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name!r} {self._state.value}>"
