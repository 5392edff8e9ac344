"""Atomic file writes and JSON helpers for run folders: a reader never sees half a file."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` in one rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "model_dump"):
        return obj.model_dump(mode="json")
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")


def dumps(data: Any) -> str:
    """JSON text with numpy arrays and pydantic models converted."""
    return json.dumps(data, indent=2, default=_json_default)


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as JSON atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(dumps(data) + "\n")
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Write text atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path


def read_json(path: str | Path) -> Any:
    """Read a JSON file (DataError with the position when it is not valid JSON)."""
    from weldcell.sdk.errors import DataError

    path = Path(path)
    if not path.is_file():
        raise DataError(f"file not found: {path}", "check the path")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise DataError(f"{path}: not valid JSON ({e})", "fix the file or write it again") from None
