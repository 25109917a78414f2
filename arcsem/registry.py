"""Plugin registries: a decorator to register, entry points to discover, dataclasses to validate.

In-tree and third-party plugins take the same path: a module declared under an entry-point group
(``arcsem.backbones`` / ``arcsem.losses``) registers its class with ``@REGISTRY.register(name)``
when imported. ``get(name)`` looks in memory first, then loads only the entry point of that name.

Example::

    @BACKBONES.register("my_backbone")
    class MyBackbone(Backbone):
        @dataclass
        class Config:
            lr: float = 1e-3
    model = BACKBONES.build({"name": "my_backbone", "lr": 0.1}, scene=scene)
"""
from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Callable
from importlib import metadata
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from .errors import ConfigError, PluginError

__all__ = ["Registry", "check_fields", "checked", "plain", "validate_config"]


def plain(cfg: Any) -> Any:
    """A DictConfig/ListConfig as plain dicts and lists, interpolations resolved where they can be (an unresolvable
    one, e.g. ``${hydra:...}`` outside a Hydra app, is kept as text); anything else as it is."""
    from omegaconf import ListConfig

    if isinstance(cfg, (DictConfig, ListConfig)):
        try:
            return OmegaConf.to_container(cfg, resolve=True)
        except (OmegaConfBaseException, ValueError):
            return OmegaConf.to_container(cfg, resolve=False)
    return cfg


class Registry:
    """Name -> class map for one plugin kind, backed by an entry-point group."""

    def __init__(self, kind: str, group: str):
        self.kind, self.group = kind, group
        self._classes: dict[str, type] = {}
        self._origin: dict[str, str] = {}

    def register(self, name: str) -> Callable[[type], type]:
        """Class decorator; a second, different class under the same name raises."""

        def deco(cls: type) -> type:
            old = self._classes.get(name)
            # the same class defined again (a module re-executed) is allowed; any other class is not
            if old is not None and (old.__module__, old.__qualname__) != (cls.__module__, cls.__qualname__):
                raise PluginError(f"{self.kind} '{name}' registered twice: {old} and {cls}")
            cls.name = name
            self._classes[name] = cls
            self._origin.setdefault(name, f"{cls.__module__} (imported)")
            return cls

        return deco

    def _entry_points(self) -> dict[str, metadata.EntryPoint]:
        return {ep.name: ep for ep in metadata.entry_points(group=self.group)}

    def names(self) -> list[str]:
        """Every known name: registered in memory or declared as an entry point."""
        return sorted(set(self._classes) | set(self._entry_points()))

    def get(self, name: str) -> type:
        """The class registered as ``name``; loads only that entry point if needed."""
        if name in self._classes:
            return self._classes[name]
        ep = self._entry_points().get(name)
        if ep is None:
            raise PluginError(f"unknown {self.kind} '{name}'; available: {', '.join(self.names()) or 'none'}")
        try:
            ep.load()
        except Exception as exc:  # a broken plugin must not hide behind a vague message
            raise PluginError(f"{self.kind} '{name}' ({ep.value}) failed to load: {exc!r}") from exc
        if name not in self._classes:
            raise PluginError(f"entry point {self.group}:{name} = {ep.value} did not register '{name}'")
        dist = getattr(ep, "dist", None)
        self._origin[name] = f"{ep.value} [{dist.name if dist else 'entry point'}]"
        return self._classes[name]

    def origin(self, name: str) -> str:
        self.get(name)
        return self._origin[name]

    def build(self, cfg: Any, **runtime: Any) -> Any:
        """Instantiate plugin ``cfg.name`` with its validated ``Config`` and runtime arguments."""
        cfg = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else dict(cfg)
        if "name" not in cfg:
            raise ConfigError(f"{self.kind} config has no 'name'; available: {', '.join(self.names())}")
        name = cfg.pop("name")
        cls = self.get(name)
        return cls(validate_config(cls.Config, cfg, where=f"{self.kind} '{name}'"), **runtime)


def checked(default: Any = dataclasses.MISSING, *, default_factory: Any = dataclasses.MISSING,
            ge: float | None = None, gt: float | None = None, le: float | None = None, lt: float | None = None,
            choices: tuple | None = None) -> Any:
    """A dataclass field whose value :func:`validate_config` checks: ``ge``/``gt``/``le``/``lt`` bounds (None
    passes), ``choices`` (the allowed values). Example: ``steps: int = checked(1500, ge=1)``."""
    rules = {k: v for k, v in (("ge", ge), ("gt", gt), ("le", le), ("lt", lt), ("choices", choices))
             if v is not None}
    if default_factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=default_factory, metadata={"checks": rules})
    return dataclasses.field(default=default, metadata={"checks": rules})


def _violation(value: Any, rules: dict) -> str | None:
    """What is wrong with ``value`` under ``rules`` (see :func:`checked`), or None."""
    if value is None:
        return None
    if "choices" in rules and value not in rules["choices"]:
        return f"must be one of {', '.join(map(str, rules['choices']))}"
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return None
    if math.isnan(value):
        return "must be a number, got NaN"
    for op, bad, text in (("ge", lambda v, b: v < b, ">="), ("gt", lambda v, b: v <= b, ">"),
                          ("le", lambda v, b: v > b, "<="), ("lt", lambda v, b: v >= b, "<")):
        if op in rules and bad(value, rules[op]):
            return f"must be {text} {rules[op]}"
    return None


def check_fields(obj: Any, where: str) -> None:
    """Raise ConfigError for the first field of dataclass ``obj`` (recursively) that breaks its :func:`checked` rules."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            check_fields(value, f"{where}.{f.name}")
            continue
        problem = _violation(value, f.metadata.get("checks", {}))
        if problem:
            raise ConfigError(f"{where}.{f.name}: {problem}, got {value!r}")


def _check_flags(schema: type, values: Any, where: str) -> None:
    """OmegaConf would read ``7`` as ``True``: a boolean field must be given a boolean (nested dataclasses too)."""
    if not isinstance(values, dict):
        return
    try:
        hints = typing.get_type_hints(schema)
    except Exception:  # noqa: BLE001 (unresolvable annotations: OmegaConf still checks the types)
        return
    for k, v in values.items():
        hint = hints.get(k)
        if hint is bool and not isinstance(v, bool) and v not in ("true", "false", "True", "False"):
            raise ConfigError(f"{where}.{k}: must be true or false, got {v!r}")
        if dataclasses.is_dataclass(hint):
            _check_flags(hint, v, f"{where}.{k}")


def validate_config(schema: type, values: dict, where: str) -> Any:
    """Return ``schema(**values)`` checked by OmegaConf and the fields' :func:`checked` rules: unknown keys,
    wrong types and out-of-range values raise ConfigError naming the key."""
    fields = [f.name for f in dataclasses.fields(schema)]
    unknown = [k for k in values if k not in fields]
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; valid keys: {', '.join(fields)}")
    _check_flags(schema, values, where)
    try:
        merged = OmegaConf.merge(OmegaConf.structured(schema), values)
    except OmegaConfBaseException as exc:
        key = getattr(exc, "full_key", None) or "?"
        msg = str(exc).splitlines()[0]
        raise ConfigError(f"{where}: bad value for key '{key}': {msg}") from None
    obj = OmegaConf.to_object(merged)
    check_fields(obj, where)
    return obj
