"""Secrets in cell profiles: ``${env:NAME}`` references, and redaction of everything weldcell outputs.

A profile names a secret by reference (``password = "${env:UR_PASSWORD}"``); the loader substitutes
the value for the device that needs it and registers ``value -> reference`` here. Everything weldcell
writes or prints (run folders, ``result.json`` provenance, ``state.json``, reports, error messages, the
command line, log records) passes through :func:`redact`, which puts the reference back in place of the
value, and hides credentials in URLs (``user:password@host``, ``?token=...``) and bearer tokens even
when they were written into the file itself. See docs/runs.md.
"""

from __future__ import annotations

import logging
import re
import threading
from typing import Any

ENV_REF = re.compile(r"\$\{env:([A-Za-z_][A-Za-z0-9_]*)\}")
MASK = "***"
_SHORT = 6  # values shorter than this are replaced only as whole words (never inside other words)

_lock = threading.Lock()
_known: dict[str, str] = {}  # secret value -> its reference, e.g. "Tok3n-..." -> "${env:UR_TOKEN}"
_patterns: list[tuple[re.Pattern[str], str]] = []

_URL_CRED = re.compile(
    r"(?P<scheme>\b[A-Za-z][A-Za-z0-9+.-]*://)(?P<user>[^/\s@:?#]*)(?::(?P<pw>[^/\s@?#]*))?@"
)
_QUERY = re.compile(
    r"(?P<key>[?&;](?:access_token|refresh_token|id_token|token|api[_-]?key|apikey|key|password|passwd|pwd|"
    r"secret|client_secret|auth|authorization|signature|sig|sas)=)(?P<value>[^&#\s'\"]*)",
    re.IGNORECASE,
)
_BEARER = re.compile(r"(?P<key>\b(?:Bearer|Basic|Token)\s+)(?P<value>[A-Za-z0-9._~+/=-]{8,})")


def register(value: str, reference: str) -> None:
    """Remember that ``value`` is the secret behind ``reference``: :func:`redact` replaces it from now on."""
    if not value or value == reference:
        return
    with _lock:
        if _known.get(value) == reference:
            return
        _known[value] = reference
        _rebuild()
    install_log_redaction()


def _rebuild() -> None:
    _patterns.clear()
    for value in sorted(_known, key=len, reverse=True):  # the longest first: a value inside another
        ref = _known[value].replace("\\", "\\\\")
        if len(value) < _SHORT:
            _patterns.append((re.compile(rf"(?<![A-Za-z0-9]){re.escape(value)}(?![A-Za-z0-9])"), ref))
        else:
            _patterns.append((re.compile(re.escape(value)), ref))


def forget_all() -> None:
    """Forget every registered secret (tests)."""
    with _lock:
        _known.clear()
        _patterns.clear()


def known_references() -> list[str]:
    """The references of the secrets registered so far (never their values)."""
    with _lock:
        return sorted(set(_known.values()))


_HELD = re.compile("\x00(\\d+)\x00")


def _is_reference(text: str | None) -> bool:
    return not text or text == MASK or bool(_HELD.fullmatch(text))


def redact(text: str) -> str:
    """``text`` with every registered secret replaced by its reference and credentials in URLs masked."""
    if not isinstance(text, str) or not text:
        return text
    with _lock:
        patterns = list(_patterns)
    for pat, ref in patterns:
        text = pat.sub(ref, text)
    refs: list[str] = []

    def hold(m: re.Match[str]) -> str:  # references are not credentials: keep them out of the masking
        refs.append(m.group(0))
        return f"\x00{len(refs) - 1}\x00"

    text = ENV_REF.sub(hold, text)

    def url(m: re.Match[str]) -> str:
        user, pw = m.group("user"), m.group("pw")
        if pw is None:  # https://TOKEN@host: the user part is the credential
            return m.group(0) if _is_reference(user) else f"{m.group('scheme')}{MASK}@"
        return f"{m.group('scheme')}{user}:{pw if _is_reference(pw) else MASK}@"

    def keep_key(m: re.Match[str]) -> str:
        v = m.group("value")
        return m.group(0) if _is_reference(v) else f"{m.group('key')}{MASK}"

    text = _URL_CRED.sub(url, text)
    text = _QUERY.sub(keep_key, text)
    text = _BEARER.sub(keep_key, text)
    return _HELD.sub(lambda m: refs[int(m.group(1))], text) if refs else text


def redact_obj(obj: Any) -> Any:
    """A copy of a JSON-like structure (dicts, lists, tuples, strings) with every string redacted."""
    if isinstance(obj, str):
        return redact(obj)
    if isinstance(obj, dict):
        return {k: redact_obj(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [redact_obj(v) for v in obj]
    return obj


def redact_error(err: Exception) -> Exception:
    """Redact a WeldcellError's message, fix and problem lines in place; returns it."""
    for attr in ("message", "fix"):
        v = getattr(err, attr, None)
        if isinstance(v, str):
            setattr(err, attr, redact(v))
    problems = getattr(err, "problems", None)
    if isinstance(problems, list):
        err.problems = [redact(p) if isinstance(p, str) else p for p in problems]  # type: ignore[attr-defined]
    if err.args and isinstance(err.args[0], str):
        err.args = (redact(err.args[0]), *err.args[1:])
    return err


_installed = False


def install_log_redaction() -> None:
    """Redact every log record created from now on (message and arguments), whatever its logger."""
    global _installed
    if _installed:
        return
    _installed = True
    previous = logging.getLogRecordFactory()

    def factory(*args: Any, **kwargs: Any) -> logging.LogRecord:
        record = previous(*args, **kwargs)
        try:
            message = record.getMessage()
        except Exception:  # a malformed record: leave it to logging's own error handling
            return record
        record.msg, record.args = redact(message), None
        return record

    logging.setLogRecordFactory(factory)
