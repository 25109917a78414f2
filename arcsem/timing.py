"""Where a job's time goes: the wall time of a stage's phases, for ``metrics.json``'s ``timings`` (``gray.train_s``,
``color.evaluate_s``, ...) on any machine without a profiler (:func:`phase`), and the named regions a profiler sees
inside a training step (:func:`region`; benchmarks/profile_step.py attributes time to them)."""
from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

import torch
from torch.profiler import record_function

__all__ = ["phase", "region"]


@contextlib.contextmanager
def phase(timings: dict[str, float], name: str) -> Iterator[None]:
    """Add the block's wall seconds to ``timings[name + "_s"]`` (also when it raises)."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timings[f"{name}_s"] = timings.get(f"{name}_s", 0.0) + time.perf_counter() - t0


def region(name: str) -> contextlib.AbstractContextManager:
    """A profiler region named ``name`` (``arcsem::render/sh``, ...) while a PyTorch profiler runs, else nothing.

    ``record_function`` dispatches two operators (enter, exit) whether or not a profiler listens: a stage-1 step
    has 19 regions, 38 operators a GPU's host would issue for nothing (benchmarks/gpu/op_count.py)."""
    if getattr(torch.autograd.profiler, "_is_profiler_enabled", True):  # (a private flag: if it goes, always a region)
        return record_function(name)
    return contextlib.nullcontext()
