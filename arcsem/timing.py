"""Wall time of a stage's phases, for ``metrics.json``'s ``timings`` (``gray.train_s``, ``color.evaluate_s``, ...):
where a job's time goes, on any machine, without a profiler."""
from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

__all__ = ["phase"]


@contextlib.contextmanager
def phase(timings: dict[str, float], name: str) -> Iterator[None]:
    """Add the block's wall seconds to ``timings[name + "_s"]`` (also when it raises)."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timings[f"{name}_s"] = timings.get(f"{name}_s", 0.0) + time.perf_counter() - t0
