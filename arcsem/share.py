"""Stage-1 model sharing: one content-addressed cache folder per stage-1 configuration.

Several stage-2 jobs of a sweep (the ablations, the reference counts) need the same stage-1 model.
Each asks :func:`stage1_dir` for the folder keyed by a hash of the stage-1-relevant config
(``dataset``, ``backbone``, ``act``, ``train``, ``seed``, the package version, a digest of the installed
source code (:func:`source_digest`) and, for the built-in scene, its generator version), takes
:func:`stage1_lock` on it, trains only if the folder holds no finished model, and marks it done.
Parallel jobs (joblib, submitit) block on the lock instead of training twice::

    path = stage1_dir(cfg)
    with stage1_lock(path):
        if not is_done(path):
            train_stage1(cfg, out=path)      # writes the checkpoint into ``path``
            mark_done(path)
    model = load(path)

or, in one call, ``path, trained = ensure_stage1(cfg, lambda p: run_stage1(cfg, scene, p))``; a job
that reused the model gets the trainer's returned metrics from ``stage1_result(path)``.

Cache root: ``cfg.cache_dir`` if set, else ``$ARCSEM_CACHE``, else ``~/.cache/arcsem``. Delete
``<root>/stage1`` to reclaim space; a model trained by other code (an edit, another commit, the same version) is
never reused, because the key holds the source digest.
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.util
import json
import os
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from .files import write_json_atomic
from .registry import plain
from .runconfig import cache_root  # (re-exported: its callers above the checks layer import it from here)

__all__ = [
    "STAGE1_KEYS",
    "cache_root",
    "ensure_stage1",
    "is_done",
    "mark_done",
    "source_digest",
    "source_roots",
    "stage1_dir",
    "stage1_key",
    "stage1_lock",
    "stage1_result",
    "tree_digest",
]

STAGE1_KEYS = ("dataset", "backbone", "act", "train", "seed")
"""Top-level config keys that determine the stage-1 model (absent keys hash as ``None``)."""

TRAIN_IGNORED = ("resume", "eval_every", "log_every", "checkpoint_every", "progress")
"""``train`` keys that change neither the model nor its final metrics (left out of the key)."""
RESULT_FILE = "result.json"

DONE_FILE = "DONE"

SOURCE_PACKAGES = ("arcsem", "arcsem.backbones", "arcsem.losses")
"""The packages whose code trains a model: arcsem's core and the built-in plugins (folders of their own in a
checkout, installed as ``arcsem.backbones`` and ``arcsem.losses``)."""
SOURCE_SUFFIXES = (".py", ".cpp", ".h", ".cu")


def tree_digest(roots: list[Path]) -> str:
    """sha256 (16 hex) of every ``SOURCE_SUFFIXES`` file under ``roots``, by its path below its root and content."""
    h = hashlib.sha256()
    for i, root in enumerate(roots):
        files = sorted(p for p in Path(root).rglob("*") if p.suffix in SOURCE_SUFFIXES and p.is_file())
        for p in files:
            h.update(f"{i}:{p.relative_to(root).as_posix()}\0".encode())
            h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()[:16]


def source_roots() -> list[Path]:
    """The installed folders of :data:`SOURCE_PACKAGES`."""
    return [Path(next(iter(importlib.util.find_spec(name).submodule_search_locations))) for name in SOURCE_PACKAGES]


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """:func:`tree_digest` of :func:`source_roots` (once a process; ~400 files, milliseconds)."""
    return tree_digest(source_roots())


def stage1_key(cfg: Mapping) -> str:
    """Hex digest (16 chars) of the stage-1-relevant part of ``cfg`` (order of keys irrelevant)."""
    from arcsem import __version__

    values = plain(cfg)
    part = {k: values.get(k) for k in STAGE1_KEYS}
    if isinstance(part["train"], dict):
        part["train"] = {k: v for k, v in part["train"].items() if k not in TRAIN_IGNORED}
    part["arcsem_version"] = __version__
    part["source"] = source_digest()  # code changes do not reuse a model trained before them
    if isinstance(part["dataset"], dict) and part["dataset"].get("kind") == "synthetic":
        from arcsem.synthetic.write import GENERATOR_VERSION  # a regenerated scene needs a new model

        part["synthetic_generator"] = GENERATOR_VERSION
    text = json.dumps(part, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def stage1_dir(cfg: Mapping, create: bool = True) -> Path:
    """``<cache root>/stage1/<stage1_key(cfg)>/``; created with a ``key.json`` describing it."""
    path = cache_root(cfg) / "stage1" / stage1_key(cfg)
    if create:
        path.mkdir(parents=True, exist_ok=True)
        desc = path / "key.json"
        if not desc.exists():
            values = plain(cfg)
            write_json_atomic(desc, {**{k: values.get(k) for k in STAGE1_KEYS}, "source": source_digest()})
    return path


@contextlib.contextmanager
def stage1_lock(path: str | os.PathLike) -> Iterator[Path]:
    """The lock of a shared stage-1 folder (:func:`arcsem.locks.waiting_lock`): blocks until no other process
    holds it, saying so on the console and in the log; released when the block ends or the process dies."""
    from .locks import waiting_lock

    with waiting_lock(path, "the shared stage-1 model, which another job is training") as p:
        yield p


def is_done(path: str | os.PathLike) -> bool:
    """True when a finished stage-1 model was marked in ``path``."""
    return (Path(path) / DONE_FILE).exists()


def mark_done(path: str | os.PathLike, info: Mapping | None = None) -> None:
    """Mark ``path`` as holding a finished model (atomic write of ``DONE`` with optional info)."""
    write_json_atomic(Path(path) / DONE_FILE, dict(info or {}), indent=None)


def stage1_result(path: str | os.PathLike) -> dict | None:
    """What ``train_fn`` returned when the model in ``path`` was trained (e.g. its stage-1 metrics)."""
    try:
        return json.loads((Path(path) / RESULT_FILE).read_text())
    except FileNotFoundError:
        return None


def ensure_stage1(cfg: Mapping, train_fn: Callable[[Path], Any]) -> tuple[Path, bool]:
    """Train stage 1 into its shared folder unless done; returns ``(path, trained_here)``.

    ``train_fn(path)`` must write the model into ``path``; it runs at most once per key across all
    processes sharing the cache (others wait on the lock, then reuse). If it returns a dict (the
    stage-1 metrics), that is kept as ``result.json``: :func:`stage1_result` gives it to every job
    that reuses the model. A failed ``train_fn`` leaves the folder unmarked so the next job retries.
    """
    path = stage1_dir(cfg)
    with stage1_lock(path):
        if is_done(path):
            return path, False
        result = train_fn(path)
        if isinstance(result, dict):
            write_json_atomic(path / RESULT_FILE, result, indent=None)
        mark_done(path, {"pid": os.getpid()})
        return path, True
