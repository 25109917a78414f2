"""Atomic checkpoints that let an interrupted run continue exactly where it stopped.

A checkpoint holds the model (and ACT, unless it lives inside the model), every optimiser, the
sampler's generator and order, the global RNG states, the number of completed steps and the
flattened config it was trained with. Files are written to ``<name>.tmp`` and moved into place with
``os.replace``, so a crash mid-write leaves the previous checkpoint intact.

Models whose size changes during training (densified Gaussians, pruned voxel grids) load through
:func:`load_module_state`, which resizes parameters and buffers to the saved shapes first.
"""
from __future__ import annotations

import hashlib
import json
import os
import pickle
import random
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from ..errors import TrainingError

__all__ = [
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


def rng_state() -> dict:
    state = {"torch": torch.get_rng_state(), "python": random.getstate(), "numpy": np.random.get_state()}
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def save_checkpoint(path: str | Path, state: dict) -> Path:
    """Write ``state`` to ``path`` atomically (tmp file, fsync, ``os.replace``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        torch.save(state, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    return path


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict:
    """Read a checkpoint written by :func:`save_checkpoint` (TrainingError if unreadable)."""
    try:
        return torch.load(path, map_location=map_location, weights_only=False)
    except (OSError, RuntimeError, EOFError, ValueError, pickle.UnpicklingError) as exc:
        raise TrainingError(f"cannot read checkpoint {path}: {exc}") from None


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
