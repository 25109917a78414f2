"""Where a run's tensors live: the one reading of ``cfg.device``, and a walk that finds tensors left elsewhere.

Every stage builds its models and training-time objects (the backbone, ACT, the stage-2 targets with their
feature extractor and guidance) on the CPU and moves them with ``.to(run_device(cfg))``; an object that holds
tensors for training declares ``to(device)``. :func:`stray_tensors` is how tests check that nothing reachable
from such an object stayed behind (a module, a buffer, a tensor in a list or a dict), on a machine without a GPU
too: moved to the ``meta`` device, every tensor an object holds must say ``meta``.
"""
from __future__ import annotations

import dataclasses
import types
from collections.abc import Iterator, Mapping
from typing import Any

import torch
from torch import Tensor, nn

__all__ = ["held_tensors", "run_device", "stray_tensors"]


_CODE = (types.FunctionType, types.MethodType, types.BuiltinFunctionType, types.ModuleType, type)


def run_device(cfg: Mapping | Any) -> torch.device:
    """The run's device: ``cfg.device`` (``cpu``, ``cuda``, ``cuda:1``; default ``cpu``), checked by the preflight."""
    return torch.device(str((cfg or {}).get("device", "cpu") or "cpu"))


def held_tensors(obj: Any, path: str = "", depth: int = 6, seen: set[int] | None = None) -> Iterator[tuple[str, Tensor]]:
    """Every tensor reachable from ``obj``: a module's parameters and buffers, tensors in attributes, lists, tuples,
    dicts and dataclasses, to ``depth`` levels (functions, classes and modules of code are not entered)."""
    seen = set() if seen is None else seen
    if id(obj) in seen or depth < 0:
        return
    seen.add(id(obj))
    if isinstance(obj, Tensor):
        yield path or "tensor", obj
        return
    if isinstance(obj, nn.Module):
        for name, t in list(obj.named_parameters(recurse=True)) + list(obj.named_buffers(recurse=True)):
            if id(t) not in seen:
                seen.add(id(t))
                yield f"{path}.{name}" if path else name, t
    if isinstance(obj, Mapping):
        items = list(obj.items())
    elif isinstance(obj, (list, tuple, set, frozenset)):
        items = list(enumerate(obj))
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        items = [(f.name, getattr(obj, f.name)) for f in dataclasses.fields(obj)]
    elif hasattr(obj, "__dict__") and not isinstance(obj, type) and type(obj).__module__ != "builtins":
        items = [(k, v) for k, v in vars(obj).items() if not (isinstance(obj, nn.Module) and k.startswith("_"))]
        if isinstance(obj, nn.Module):
            items += list(obj.named_children())
    else:
        return
    for key, value in items:
        if isinstance(value, _CODE):
            continue
        yield from held_tensors(value, f"{path}.{key}" if path else str(key), depth - 1, seen)


def stray_tensors(obj: Any, device: str | torch.device) -> list[str]:
    """``path: device`` of every tensor reachable from ``obj`` (:func:`held_tensors`) that is not on ``device``."""
    want = torch.device(device)
    return [f"{path}: {t.device}" for path, t in held_tensors(obj)
            if t.device.type != want.type or (want.index is not None and t.device.index != want.index)]
