"""``metrics.json`` as strict JSON: a number that is not finite is written as ``null``, and ``nulls`` says why.

Python's ``json`` writes NaN and infinity as ``NaN`` / ``Infinity``, which no strict parser accepts (JavaScript's
``JSON.parse`` fails on the whole file). :func:`strict_metrics` replaces each by ``null`` and adds one top-level map
``"nulls": {"<dotted.path>": "<what it was>: <why>"}``, for example::

    "nulls": {"stage1.train.lpips": "NaN: LPIPS not computed (lpips_weights: skipped)",
              "stage1.test.psnr": "Infinity: the render equals the image (no error)"}

A reader that wants the floats back maps each path of ``nulls`` to NaN (``arcsem-report`` reads ``null`` as NaN).
"""
from __future__ import annotations

import math
from typing import Any

__all__ = ["strict_metrics"]


def _token(x: float) -> str:
    return "NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity")


def _reason(path: list[str], value: float, parents: list[dict]) -> str:
    """Why the number at ``path`` (its ``parents``, innermost last) is not finite."""
    leaf = path[-1]
    if leaf.startswith("lpips"):
        if any(p.get("lpips_splits") == "test" for p in parents) and "test" not in path:
            return "LPIPS scores the held-out views only (eval.lpips_splits=test)"
        weights = next((p["lpips_weights"] for p in reversed(parents) if isinstance(p.get("lpips_weights"), str)),
                       None)
        return f"LPIPS not computed (lpips_weights: {weights})" if weights else \
            "LPIPS not computed (train.eval.lpips=false, or its ImageNet weights are missing)"
    if leaf.startswith("psnr") and value > 0:
        return "the render equals the image (no error)"
    if math.isnan(value):
        return "no value: nothing to measure it on (no view, pixel, match or time)"
    return "out of the float range"


def _walk(obj: Any, path: list[str], parents: list[dict], nulls: dict[str, str]) -> Any:
    if isinstance(obj, dict):
        return {k: _walk(v, [*path, str(k)], [*parents, obj], nulls) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_walk(v, [*path, str(i)], parents, nulls) for i, v in enumerate(obj)]
    if isinstance(obj, float) and not math.isfinite(obj):
        nulls[".".join(path)] = f"{_token(obj)}: {_reason(path, obj, parents)}"
        return None
    return obj


def strict_metrics(metrics: dict) -> dict:
    """A copy of ``metrics`` (plain dicts, lists and numbers; see :func:`arcsem.files.jsonable`) with every
    non-finite float as None, plus ``"nulls"`` (see the module docstring) where there was any."""
    from .files import jsonable

    nulls: dict[str, str] = {}
    out = _walk(jsonable({k: v for k, v in metrics.items() if k != "nulls"}), [], [], nulls)
    if nulls:
        out["nulls"] = nulls
    return out
