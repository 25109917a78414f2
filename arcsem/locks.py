"""File locks (through ``filelock``, portable): one run per run folder, one trainer per shared stage-1 model.

* :func:`run_folder_lock`: a run holds ``<run folder>/.arcsem.lock`` while it works; a second run in the
  same folder stops at once with an error naming the folder and the process that holds it (two runs in
  one folder would overwrite each other's checkpoints, renders and metrics).
* :func:`waiting_lock`: wait for a lock another job holds (the shared stage-1 cache), saying so on the
  console and in the log before waiting and when it is acquired.

A lock dies with its process (``flock``), so a killed run never leaves a folder locked.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import time
from collections.abc import Iterator
from pathlib import Path

from .errors import OutputError

__all__ = ["LOCK_NAME", "run_folder_lock", "waiting_lock"]

log = logging.getLogger(__name__)

LOCK_NAME = ".arcsem.lock"
_OWNER = ".arcsem.owner"


def _owner(folder: Path) -> str:
    try:
        info = json.loads((folder / _OWNER).read_text())
        return f"pid {info['pid']} on {info['host']}, since {info['since']}"
    except (OSError, ValueError, KeyError):
        return "another process"


def _write_owner(folder: Path) -> None:
    info = {"pid": os.getpid(), "host": os.uname().nodename, "since": time.strftime("%Y-%m-%d %H:%M:%S")}
    (folder / _OWNER).write_text(json.dumps(info))


@contextlib.contextmanager
def run_folder_lock(folder: str | os.PathLike) -> Iterator[Path]:
    """Hold ``folder``'s run lock for the block; OutputError at once if another run holds it."""
    from filelock import FileLock, Timeout

    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock = FileLock(str(folder / LOCK_NAME))
        lock.acquire(timeout=0)
    except Timeout:
        raise OutputError(f"run folder {folder} is in use by another arcsem run ({_owner(folder)}); wait for it "
                          "to finish or choose another folder (hydra.run.dir=...)") from None
    with _holding(folder, lock):
        yield folder


@contextlib.contextmanager
def waiting_lock(path: str | os.PathLike, what: str) -> Iterator[Path]:
    """Hold the lock of folder ``path`` (``path/.arcsem.lock``), announcing a wait for ``what`` if another job has it."""
    from filelock import FileLock, Timeout

    folder = Path(path)
    folder.mkdir(parents=True, exist_ok=True)
    lock = FileLock(str(folder / LOCK_NAME))
    try:
        lock.acquire(timeout=0)
    except Timeout:
        msg = f"waiting for {what} ({folder}, held by {_owner(folder)})"
        log.info(msg)
        t0 = time.perf_counter()
        lock.acquire()
        log.info("lock on %s acquired after %.0f s", folder, time.perf_counter() - t0)
    with _holding(folder, lock):
        yield folder


@contextlib.contextmanager
def _holding(folder: Path, lock) -> Iterator[None]:
    """While an acquired ``lock`` is held: an owner note in ``folder`` (named in other runs' messages); then release."""
    try:
        _write_owner(folder)
        yield
    finally:
        (folder / _OWNER).unlink(missing_ok=True)
        lock.release()
