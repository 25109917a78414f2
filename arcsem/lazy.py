"""Lazy imports: package attributes (PEP 562: ``import arcsem.backbones.gs2d`` imports nothing heavy until a name is
used), functions named ``"module:function"`` (:func:`import_function`, the stages' checks and runners), and names
that moved, importable from their old module for one release with a DeprecationWarning (:func:`moved_getattr`)."""
from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable
from typing import Any

__all__ = ["import_function", "lazy_getattr", "moved_getattr"]


def lazy_getattr(package: str, where: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package`` that imports ``name`` on first use from the submodule ``where[name]``,
    or, for ``where[name] = "submodule:attr"``, imports ``attr`` of that submodule (``{"CONFIG": "config:MyConfig"}``)."""

    def __getattr__(name: str) -> Any:
        if name in where:
            module, _, attr = where[name].partition(":")
            return getattr(importlib.import_module(f".{module}", package), attr or name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__


def moved_getattr(module: str, moved: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``module``'s names that moved to the module ``moved[name]``: each use of the
    old path warns (DeprecationWarning, naming the new one) and returns the object from its new home."""

    def __getattr__(name: str) -> Any:
        if name in moved:
            warnings.warn(f"{module}.{name} moved to {moved[name]}.{name}; import it from there (the old path goes "
                          "in the next release)", DeprecationWarning, stacklevel=2)
            return getattr(importlib.import_module(moved[name]), name)
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

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
