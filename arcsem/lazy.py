"""Lazy package attributes (PEP 562): ``import arcsem.backbones.gs2d`` imports nothing heavy until a name is used."""
from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

__all__ = ["lazy_getattr"]


def lazy_getattr(package: str, where: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package`` that imports ``name`` on first use from the submodule ``where[name]``,
    or, for ``where[name] = "submodule:attr"``, imports ``attr`` of that submodule (``{"CONFIG": "config:MyConfig"}``)."""

    def __getattr__(name: str) -> Any:
        if name in where:
            module, _, attr = where[name].partition(":")
            return getattr(importlib.import_module(f".{module}", package), attr or name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
