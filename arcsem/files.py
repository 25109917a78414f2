"""Atomic file writes, the one implementation: metrics, checkpoints, caches, tables, PLY files.

A file is written to a temporary file in its own folder (a unique name, so two writers never share it),
flushed to disk and moved over the target with ``os.replace``: a reader sees the old file or the new one,
never half of one, and a crash or a full disk leaves the old file intact.
"""
from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_open", "jsonable", "write_bytes_atomic", "write_json_atomic", "write_text_atomic"]


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb", **kwargs: Any) -> Iterator[IO]:
    """``with atomic_open(path, "w") as f: ...`` writes ``path`` atomically (see the module docstring).

    The folder is created; the file gets mode 0644 (results are meant to be shared); on an exception the
    temporary file is removed and ``path`` is left as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode, **kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: str | os.PathLike, data: bytes | memoryview) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as f:
        f.write(data)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_open(path, "w", encoding="utf-8") as f:
        f.write(text)


def jsonable(obj: Any) -> Any:
    """Tensors/arrays/numpy scalars -> lists/floats, paths -> strings; NaN/inf stay floats (NaN/Infinity in JSON)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "tolist"):  # torch / numpy
        return jsonable(obj.tolist())
    return obj


def write_json_atomic(path: str | os.PathLike, obj: Any, indent: int | None = 2, allow_nan: bool = True) -> None:
    """``json.dump`` of ``obj`` (tensors and arrays converted) to ``path``, atomically; ``allow_nan=False``: strict
    JSON (ValueError for a NaN or infinity, which plain ``json`` writes as ``NaN``/``Infinity``)."""
    write_text_atomic(path, json.dumps(jsonable(obj), indent=indent, default=str, allow_nan=allow_nan) + "\n")
