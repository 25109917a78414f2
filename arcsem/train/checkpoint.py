"""Atomic checkpoints that let an interrupted run continue exactly where it stopped.

A checkpoint holds the model (and ACT, unless it lives inside the model), every optimiser, the
sampler's generator and order, the global RNG states, the number of completed steps and the
flattened config it was trained with: tensors and plain data (numbers, strings, lists, dicts) only,
read back with ``torch.load(weights_only=True)``, so a crafted file cannot run code. Each file
carries ``format: FORMAT``; a file without it (an older arcsem, or not a checkpoint) gives a clear
error. Files are written to a temporary file in the same folder (unique per writer) and moved into
place with ``os.replace``, so a crash or a full disk mid-write leaves the previous checkpoint intact.

Models whose size changes during training (densified Gaussians, pruned voxel grids) load through
:func:`load_module_state`, which resizes parameters and buffers to the saved shapes first.
"""
from __future__ import annotations

import hashlib
import io
import json
import pickle
import random
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..errors import OutputError, TrainingError
from ..files import write_bytes_atomic

__all__ = [
    "FORMAT",
    "check_config",
    "config_diff",
    "config_hash",
    "flatten",
    "load_checkpoint",
    "load_module_state",
    "rng_state",
    "save_checkpoint",
    "set_rng_state",
]


def flatten(cfg: Any, prefix: str = "") -> dict[str, Any]:
    """Nested mappings -> ``{"a.b.c": value}`` (lists and tuples become lists; leaves kept as they are)."""
    if isinstance(cfg, Mapping):
        out: dict[str, Any] = {}
        for k, v in cfg.items():
            out.update(flatten(v, f"{prefix}{k}."))
        return out if out or not prefix else {prefix[:-1]: {}}
    if isinstance(cfg, tuple):
        cfg = list(cfg)
    return {prefix[:-1]: cfg}


def config_diff(saved: Mapping, current: Mapping) -> list[str]:
    """Dotted keys whose values differ, or that exist on one side only (sorted)."""
    a, b = flatten(saved), flatten(current)
    return sorted(k for k in set(a) | set(b) if a.get(k, "<missing>") != b.get(k, "<missing>"))


def config_hash(cfg: Mapping) -> str:
    """Short SHA-256 of the flattened config (order-independent)."""
    text = json.dumps(flatten(cfg), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def check_config(saved: Mapping, current: Mapping, path: str | Path) -> None:
    """Raise TrainingError listing the differing keys if a checkpoint's config is not ``current``."""
    diff = config_diff(saved, current)
    if diff:
        shown = ", ".join(f"{k} ({flatten(saved).get(k, '<missing>')!r} -> {flatten(current).get(k, '<missing>')!r})"
                          for k in diff[:12])
        more = f" and {len(diff) - 12} more" if len(diff) > 12 else ""
        raise TrainingError(f"cannot resume from {path}: the config differs in {shown}{more}; "
                            f"use another run directory or train.resume=never to start over")


FORMAT = "arcsem-checkpoint-2"
"""Written into every checkpoint; 2: plain data only (format 1 pickled NumPy objects)."""


def rng_state() -> dict:
    """The global RNG states as tensors and plain data (no NumPy objects: ``weights_only`` loads them)."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    numpy_state = {"kind": str(kind), "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64)), "pos": int(pos),
                   "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}
    state = {"torch": torch.get_rng_state(), "python": random.getstate(), "numpy": numpy_state}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"].cpu())  # RNG states are CPU byte tensors, whatever map_location did
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))
    n = state["numpy"]
    np.random.set_state((n["kind"], n["keys"].cpu().numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached_gaussian"]))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all([t.cpu() for t in state["cuda"]])


def save_checkpoint(path: str | Path, state: dict) -> Path:
    """Write ``state`` (plus ``format``) to ``path`` atomically: serialised in memory, written to a unique
    temporary file, fsynced, ``os.replace``d. OutputError (the old file intact) when it cannot be written."""
    path = Path(path)
    buf = io.BytesIO()
    torch.save({**state, "format": FORMAT}, buf)  # in memory: a failed write is an OSError with its errno
    try:
        write_bytes_atomic(path, buf.getbuffer())
    except OSError as exc:
        kept = "the previous checkpoint is intact" if path.is_file() else "no checkpoint is on disk"
        raise OutputError(f"cannot write checkpoint {path}: {exc.strerror or exc} ({kept})") from None
    return path


def remove_stale_temporaries(path: str | Path, older_than_s: float = 30.0) -> list[Path]:
    """Delete the temporaries a killed write of ``path`` left (``.<name>.*.tmp`` beside it, untouched for
    ``older_than_s``: a write in progress elsewhere keeps its own); returns what was removed."""
    path = Path(path)
    if not path.parent.is_dir():
        return []
    now, removed = time.time(), []
    for tmp in path.parent.glob(f".{path.name}.*.tmp"):
        try:
            if now - tmp.stat().st_mtime > older_than_s:
                tmp.unlink()
                removed.append(tmp)
        except OSError:  # gone meanwhile, or not ours to remove: leave it
            continue
    return removed


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict:
    """Read a checkpoint written by :func:`save_checkpoint` with ``weights_only=True`` (tensors and plain
    data; nothing in the file is executed). TrainingError if unreadable, foreign or of another format."""
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError:
        raise TrainingError(f"cannot read checkpoint {path}: it holds Python objects other than tensors and plain "
                            "data (an older arcsem checkpoint, or not an arcsem checkpoint); it was not loaded. "
                            "Retrain, or delete the file (train.resume=never ignores it)") from None
    except (OSError, RuntimeError, EOFError, ValueError) as exc:
        raise TrainingError(f"cannot read checkpoint {path}: {str(exc).splitlines()[0] if str(exc) else exc}") from None
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        found = state.get("format", "none") if isinstance(state, dict) else type(state).__name__
        raise TrainingError(f"{path} is not an arcsem checkpoint of format {FORMAT} (found: {found}); "
                            "retrain, or delete the file (train.resume=never ignores it)")
    return state


def load_module_state(module: nn.Module, state: Mapping[str, torch.Tensor]) -> None:
    """``module.load_state_dict(state)`` after resizing parameters/buffers whose saved shape differs."""
    tensors = dict(module.named_parameters())
    tensors.update(dict(module.named_buffers()))
    for name, value in state.items():
        t = tensors.get(name)
        if t is not None and t.shape != value.shape:
            with torch.no_grad():
                t.data = torch.empty(value.shape, dtype=t.dtype, device=t.device)
    module.load_state_dict(state)
