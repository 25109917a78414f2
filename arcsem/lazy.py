"""Lazy imports: package attributes (PEP 562: ``import arcsem.backbones.gs2d`` imports nothing heavy until a name is
used) and functions named ``"module:function"`` (:func:`import_function`, the stages' checks and runners)."""
from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

__all__ = ["import_function", "lazy_getattr"]


def lazy_getattr(package: str, where: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package`` that imports ``name`` from the submodule ``where[name]`` on first use."""

    def __getattr__(name: str) -> Any:
        if name in where:
            return getattr(importlib.import_module(f".{where[name]}", package), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__


def import_function(ref: Callable[..., Any] | str, who: str) -> Callable[..., Any]:
    """``ref`` itself if callable, else the function ``"module:function"`` imported now; a PluginError saying that
    ``who`` (e.g. ``"stage 'gray'"``) needs it where it cannot be imported."""
    if callable(ref):
        return ref
    module, _, name = ref.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        from .errors import PluginError

        raise PluginError(f"{who} needs {module}.{name}, which is not available: {exc}") from None
