"""Strict readers for the small JSON/TOML files users hand to weldcell (sample lists, scan lists,
calibration results, settings files), and the schema checks they share.

Every failure is a :class:`~weldcell.sdk.errors.DataError` with one line saying what is wrong, where
(file, key path, entry), and a fix: a file that is not UTF-8 text, not valid JSON/TOML, nested
absurdly deep, a document of the wrong shape, an unknown (misspelt) key, a value of the wrong type.
See docs/file-formats.md.
"""

from __future__ import annotations

import difflib
import json
import math
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from weldcell.sdk.errors import DataError

MAX_BYTES = 256 << 20  # a settings or index file larger than this is not one


def read_text_file(path: str | Path, what: str = "file") -> str:
    """The UTF-8 text of ``path``; DataError for a missing, unreadable, huge or non-UTF-8 file."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{what} not found: {path}", "check the path")
    try:
        if path.stat().st_size > MAX_BYTES:
            raise DataError(f"{path}: {path.stat().st_size} bytes is too large for a {what}", "check it")
        raw = path.read_bytes()
    except OSError as e:
        raise DataError(f"cannot read {path}: {e.strerror}", "check the file's permissions") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise DataError(
            f"{path}: not UTF-8 text (byte {e.start} is 0x{raw[e.start]:02x}); is it a binary file?",
            f"save the {what} as UTF-8 text",
        ) from None


def read_json_file(path: str | Path, what: str = "JSON file") -> Any:
    """Parsed JSON of ``path`` (see :func:`read_text_file`); DataError with line and column when it
    is not valid JSON."""
    path = Path(path)
    text = read_text_file(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise DataError(
            f"{path}: not valid JSON: {e.msg} at line {e.lineno} column {e.colno}",
            f"fix the {what} there (or write it again)",
        ) from None
    except RecursionError:
        raise DataError(f"{path}: JSON nested too deeply", f"the {what} is damaged; write it again") from None


def read_toml_file(path: str | Path, what: str = "TOML file") -> dict:
    """Parsed TOML of ``path`` (see :func:`read_text_file`); DataError with the position when it is
    not valid TOML."""
    path = Path(path)
    text = read_text_file(path, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"{path}: not valid TOML: {e}", "fix the TOML syntax at that line") from None
    except RecursionError:
        raise DataError(f"{path}: TOML nested too deeply", f"the {what} is damaged; write it again") from None


def expect_object(value: Any, where: str, example: str = "") -> dict:
    """``value`` when it is a JSON object (dict); DataError naming ``where`` otherwise."""
    if not isinstance(value, dict):
        hint = f" like {example}" if example else ""
        raise DataError(f"{where} is {kind_of(value)}, not an object", f"write it as an object{hint}")
    return value


def kind_of(value: Any) -> str:
    """A user-facing name of a JSON value's type: 'a number', 'a string', 'a list', ..."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true/false"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


def check_keys(doc: dict, allowed: Iterable[str], where: str) -> None:
    """Refuse keys of ``doc`` not in ``allowed``, naming the key, a close match and the valid keys."""
    allowed = list(allowed)
    unknown = [k for k in doc if k not in allowed]
    if not unknown:
        return
    k = unknown[0]
    close = difflib.get_close_matches(str(k), allowed, n=1)
    more = f" (and {len(unknown) - 1} more)" if len(unknown) > 1 else ""
    hint = f"did you mean '{close[0]}'? " if close else ""
    raise DataError(
        f"{where}: unknown key '{k}'{more}",
        f"{hint}valid keys: {', '.join(allowed)}",
    )


def as_number(value: Any, where: str, fix: str = "write a number") -> float:
    """A finite float from a JSON number; DataError naming ``where`` for text, null, NaN, inf."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise DataError(f"{where} is {kind_of(value)} ({short(value)}), not a number", fix)
    v = float(value)
    if not math.isfinite(v):
        raise DataError(f"{where} is {v}, not a finite number", fix)
    return v


def as_matrix(value: Any, shape: tuple[int, ...], where: str, fix: str):
    """A finite float array of ``shape`` from nested JSON lists; DataError naming ``where`` for text,
    ragged rows, a wrong shape or NaN/inf."""
    import numpy as np

    if not isinstance(value, list):
        raise DataError(f"{where} is {kind_of(value)} ({short(value)}), not a list of numbers", fix)
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"{where} has rows of unequal length or values that are not numbers", fix) from None
    if arr.shape != shape:
        want = "x".join(map(str, shape))
        got = "x".join(map(str, arr.shape)) or "a scalar"
        raise DataError(f"{where} is {got}, not {want}", fix)
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{where} has NaN or infinite values", fix)
    return arr


def short(value: Any, limit: int = 40) -> str:
    """``repr`` of a value, shortened for an error message."""
    r = repr(value)
    return r if len(r) <= limit else r[: limit - 3] + "..."
