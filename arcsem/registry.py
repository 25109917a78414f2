"""Plugin registries: entry points to discover, a decorator for in-memory classes, dataclasses to validate.

In-tree and third-party plugins take the same path: an entry point of the registry's group names the plugin.

* **Backbones** (group ``arcsem.backbones``): one entry point per backbone, naming a module that defines
  ``CONFIG``, the backbone's ``Config`` dataclass (importable without torch: :mod:`arcsem.schemas` stores every
  installed backbone's ``CONFIG`` as a Hydra schema at start-up) and ``BACKBONE``, the class (whose ``Config`` is
  ``CONFIG``; read only when the backbone is used, so make it a lazy attribute: :func:`arcsem.lazy.lazy_getattr`).
  That entry point is the backbone's only registration; its name is the backbone's name. Until arcsem 0.3 the old
  way still loads with a :class:`PluginDeprecationWarning`: a module that runs ``@BACKBONES.register(name)`` when
  imported, with its Config in the entry-point group ``arcsem.backbone_configs``.
* **Losses** (group ``arcsem.losses``): the entry point names a module that registers its classes with
  ``@LOSSES.register(name)`` when imported (one module may hold several losses).

``get(name)`` looks in memory first, then loads only the entry point of that name. ``register(name)`` also puts a
class in memory directly (test doubles, scripts).

Example::

    # my_plugin/__init__.py, declared as  [project.entry-points."arcsem.backbones"] my_backbone = "my_plugin"
    from arcsem.lazy import lazy_getattr

    __getattr__ = lazy_getattr(__name__, {"CONFIG": "config:MyConfig", "BACKBONE": "backbone:MyBackbone"})

    model = BACKBONES.build({"name": "my_backbone", "lr": 0.1}, scene=scene)
"""
from __future__ import annotations

import dataclasses
import math
import typing
import warnings
from collections.abc import Callable
from importlib import metadata
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from .errors import ConfigError, PluginError

__all__ = ["BACKBONES", "CONFIG_ATTR", "LEGACY_UNTIL", "LOSSES", "PluginDeprecationWarning", "Registry", "check_fields",
           "checked", "plain", "validate_config"]


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


LEGACY_UNTIL = "0.3"  # the release that stops reading backbones registered the old way
CONFIG_ATTR = "CONFIG"  # the module attribute that holds a backbone's Config dataclass


class PluginDeprecationWarning(DeprecationWarning):
    """A plugin registered the old way, read until arcsem :data:`LEGACY_UNTIL` (the arcsem CLI shows these)."""


class Registry:
    """Name -> class map for one plugin kind, backed by an entry-point group.

    ``class_attr``: entry points name modules that define the class as ``<class_attr>`` and its Config dataclass as
    ``CONFIG`` (backbones; see the module docstring); None: modules register with :meth:`register` when imported.
    ``legacy_config_group``: the old group of ``name = "module:ConfigClass"`` entry points, still read (warned)."""

    def __init__(self, kind: str, group: str, *, class_attr: str | None = None,
                 legacy_config_group: str | None = None):
        self.kind, self.group = kind, group
        self.class_attr, self.legacy_config_group = class_attr, legacy_config_group
        self._classes: dict[str, type] = {}
        self._origin: dict[str, str] = {}

    def register(self, name: str) -> Callable[[type], type]:
        """Class decorator putting a class in memory under ``name``; a second, different class under the same name
        raises. (Backbones declared as entry points do not use it: their entry point registers them.)"""

        def deco(cls: type) -> type:
            self._add(name, cls)
            self._origin.setdefault(name, f"{cls.__module__} (imported)")
            return cls

        return deco

    def _add(self, name: str, cls: type) -> None:
        old = self._classes.get(name)
        # the same class defined again (a module re-executed) is allowed; any other class is not
        if old is not None and (old.__module__, old.__qualname__) != (cls.__module__, cls.__qualname__):
            raise PluginError(f"{self.kind} '{name}' registered twice: {old} and {cls}")
        cls.name = name
        self._classes[name] = cls

    def _entry_points(self, group: str | None = None) -> dict[str, metadata.EntryPoint]:
        return {ep.name: ep for ep in metadata.entry_points(group=group or self.group)}

    def registered(self, name: str) -> type | None:
        """The class in memory under ``name`` (registered or already loaded), or None; loads nothing."""
        return self._classes.get(name)

    def names(self) -> list[str]:
        """Every known name: registered in memory or declared as an entry point."""
        return sorted(set(self._classes) | set(self._entry_points()))

    def declared(self) -> list[str]:
        """The names declared as entry points (the group's and, until :data:`LEGACY_UNTIL`, the old config group's)."""
        legacy = self._entry_points(self.legacy_config_group) if self.legacy_config_group else {}
        return sorted(set(self._entry_points()) | set(legacy))

    def _entry_point(self, name: str) -> metadata.EntryPoint:
        ep = self._entry_points().get(name)
        if ep is None:
            raise PluginError(f"unknown {self.kind} '{name}'; available: {', '.join(self.names()) or 'none'}")
        return ep

    def get(self, name: str) -> type:
        """The class registered as ``name``; loads only that entry point if needed."""
        if name in self._classes:
            return self._classes[name]
        ep = self._entry_point(name)
        module = self._module(ep)
        if name not in self._classes:
            if self.class_attr is None:
                raise PluginError(f"entry point {self.group}:{name} = {ep.value} did not register '{name}'")
            self._add(name, self._declared_class(ep, module))
        dist = getattr(ep, "dist", None)
        self._origin[name] = f"{ep.value} [{dist.name if dist else 'entry point'}]"
        return self._classes[name]

    def config(self, name: str) -> type:
        """The Config dataclass of plugin ``name``, read without importing its class where the plugin allows it
        (``CONFIG`` of its module; a Config declared in the old group warns)."""
        if name in self._classes:
            return self._classes[name].Config
        legacy = self._entry_points(self.legacy_config_group).get(name) if self.legacy_config_group else None
        if legacy is not None:
            warnings.warn(f"{self._label(legacy)} declares its Config in the entry-point group "
                          f"{self.legacy_config_group}, read only until arcsem {LEGACY_UNTIL}: define {CONFIG_ATTR} "
                          f"(and {self.class_attr}) in the module of its {self.group} entry point and remove the "
                          f"{self.legacy_config_group} entry point", PluginDeprecationWarning, stacklevel=2)
            return legacy.load()
        ep = self._entry_point(name)
        module = self._module(ep)
        if self.class_attr is None or name in self._classes:  # a module that registers its class when imported
            return self.get(name).Config
        try:
            config = getattr(module, CONFIG_ATTR, None)
        except Exception as exc:  # a lazy CONFIG whose module does not import
            raise PluginError(f"{self.kind} '{name}' ({ep.value}) failed to load: {exc!r}") from exc
        return config if config is not None else self.get(name).Config  # get names what is missing

    def _label(self, ep: metadata.EntryPoint) -> str:
        dist = getattr(ep, "dist", None)
        return f"{self.kind} plugin '{ep.name}' ({ep.value}{f' [{dist.name}]' if dist else ''})"

    def _module(self, ep: metadata.EntryPoint) -> Any:
        """Import the module of ``ep`` (a failure names the plugin); warn if it registered itself the old way."""
        try:
            module = ep.load()
        except Exception as exc:  # a broken plugin must not hide behind a vague message
            raise PluginError(f"{self.kind} '{ep.name}' ({ep.value}) failed to load: {exc!r}") from exc
        if self.class_attr and ep.name in self._classes:  # its import ran @register(name)
            warnings.warn(f"{self._label(ep)} registers its class with @register when imported, read only until "
                          f"arcsem {LEGACY_UNTIL}: let the module of its {self.group} entry point define "
                          f"{CONFIG_ATTR} (the Config dataclass) and {self.class_attr} (the class, e.g. lazily with "
                          f"arcsem.lazy.lazy_getattr) and remove the decorator", PluginDeprecationWarning,
                          stacklevel=3)
        return module

    def _declared_class(self, ep: metadata.EntryPoint, module: Any) -> type:
        """The module's ``<class_attr>``, checked: a ``CONFIG`` dataclass beside it, and its ``Config`` is ``CONFIG``."""
        try:
            cls, config = getattr(module, self.class_attr, None), getattr(module, CONFIG_ATTR, None)
        except Exception as exc:  # the lazy import of the class failed
            raise PluginError(f"{self.kind} '{ep.name}' ({ep.value}) failed to load: {exc!r}") from exc
        where = f"{self.kind} '{ep.name}' ({ep.value})"
        if cls is None and config is None:
            raise PluginError(f"{where}: the module defines neither {self.class_attr} (the class) nor "
                              f"{CONFIG_ATTR} (its Config dataclass)")
        if config is None or not dataclasses.is_dataclass(config):
            raise PluginError(f"{where}: the module has no Config: define {CONFIG_ATTR} = <its Config dataclass>")
        if cls is None:
            raise PluginError(f"{where}: the module has no {self.class_attr} (the class)")
        if getattr(cls, "Config", None) is not config:
            raise PluginError(f"{where}: {cls.__name__}.Config is not {CONFIG_ATTR} ({config.__name__})")
        return cls

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


BACKBONES = Registry("backbone", "arcsem.backbones", class_attr="BACKBONE",
                     legacy_config_group="arcsem.backbone_configs")
LOSSES = Registry("loss", "arcsem.losses")


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
