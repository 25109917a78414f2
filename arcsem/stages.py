"""The stages of an ``arcsem`` run: one registry, :data:`STAGES`, that every ``stage=`` value comes from.

A :class:`Stage` names what it runs and what it checks: ``plan`` (the stages whose checks a ``stage=`` value runs,
in order: ``all`` -> gray, color), ``check_config`` (checks of the config alone, before any data is read),
``check_scene`` (checks of the loaded scene; they return warnings) and ``run`` (what it does; ``None``: run each
stage of ``plan`` in turn). Checks and runners are functions or ``"module:function"`` names, imported when used.
:func:`check_config` and :func:`check_scene` run the checks of a plan, each check function once even where two
stages list it (the backbone's own checks: :meth:`arcsem.plugins.Backbone.check_config`).

Adding a stage: one :func:`register` entry here (or in a plugin), its module (checks and runner), its config.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import ConfigError, PluginError

__all__ = ["STAGES", "Stage", "StageRegistry", "check_config", "check_scene", "plan", "resolve"]

Check = Callable[..., Any] | str


@dataclass(frozen=True)
class Stage:
    """One ``stage=`` value.

    name: the value. plan: the stages whose checks it runs (itself included where it has checks), and, when ``run``
    is None, the stages it runs. check_config: functions ``(rc: RunConfig) -> None`` that raise ConfigError,
    DataError or PluginError naming the key. check_scene: functions ``(rc, scene, stage: str, run_dir: Path) ->
    list[str]`` (warnings) that raise the same. run: ``(rc, scene, run_dir) -> dict`` (written into
    ``metrics.json`` under ``stages.<name>``). needs_scene: whether the dataset is read first; where it is not,
    input_dirs ``(rc) -> list[str]``: the folders it reads instead (no file in them is written while it runs,
    :mod:`arcsem.guard`). summary: whether the
    run ends with the one-screen summary of a training run (:mod:`arcsem.run_summary`).
    """

    name: str
    plan: tuple[str, ...]
    check_config: tuple[Check, ...] = ()
    check_scene: tuple[Check, ...] = ()
    run: Check | None = None
    needs_scene: bool = True
    input_dirs: Check | None = None
    summary: bool = False

    def runs(self) -> tuple[str, ...]:
        """The stages this value runs, in order: itself, or (``run`` None) those of its plan."""
        return (self.name,) if self.run is not None else self.plan


def resolve(func: Check, stage: str) -> Callable[..., Any]:
    """A check or runner: the function itself, or ``"module:function"`` imported now (PluginError if absent)."""
    from .lazy import import_function

    return import_function(func, f"stage '{stage}'")


class StageRegistry:
    """Name -> :class:`Stage`, in registration order (the order ``stage:`` errors list them)."""

    def __init__(self) -> None:
        self._stages: dict[str, Stage] = {}

    def register(self, stage: Stage) -> Stage:
        """Add ``stage``; a second, different stage under a registered name raises PluginError."""
        old = self._stages.get(stage.name)
        if old is not None and old != stage:
            raise PluginError(f"stage '{stage.name}' registered twice")
        unknown = [p for p in stage.plan if p != stage.name and p not in self._stages]
        if unknown:
            raise PluginError(f"stage '{stage.name}': its plan names unknown stage(s) {', '.join(unknown)}")
        self._stages[stage.name] = stage
        return stage

    def unregister(self, name: str) -> None:
        self._stages.pop(name, None)

    def get(self, name: str) -> Stage:
        """The stage ``name``; ConfigError listing the stages where there is none."""
        if name not in self._stages:
            raise ConfigError(f"stage: unknown stage '{name}'; available: {', '.join(self._stages)}")
        return self._stages[name]

    def names(self) -> tuple[str, ...]:
        return tuple(self._stages)

    def __contains__(self, name: object) -> bool:
        return name in self._stages

    def __iter__(self) -> Iterator[str]:
        return iter(self._stages)


STAGES = StageRegistry()
"""Every stage ``arcsem stage=<name>`` can run."""

STAGES.register(Stage("gray", plan=("gray",), summary=True,
                      check_config=("arcsem.train.gray_stage:check_train_config", "arcsem.preflight:check_backbone",
                                    "arcsem.train.gray_stage:check_losses", "arcsem.mesh.extract:check_mesh_config"),
                      check_scene=("arcsem.train.gray_stage:check_scene", "arcsem.preflight:check_backbone_scene"),
                      run="arcsem.train.gray_stage:run_gray_stage"))
STAGES.register(Stage("color", plan=("color",), summary=True,
                      check_config=("arcsem.colorize.color_stage:check_colorize_config",
                                    "arcsem.preflight:check_backbone", "arcsem.colorize.color_stage:check_config",
                                    "arcsem.mesh.extract:check_mesh_config"),
                      check_scene=("arcsem.preflight:check_backbone_scene", "arcsem.colorize.color_stage:check_scene"),
                      run="arcsem.colorize:run_stage2"))
STAGES.register(Stage("all", plan=("gray", "color"), summary=True))
# stage 2's problems are warnings here: a dataset may be meant for stage 1 alone (colorize.color_stage.check_scene)
STAGES.register(Stage("check", plan=("gray", "color"), run="arcsem.check_summary:run_check_stage"))
STAGES.register(Stage("render", plan=("render",), check_config=("arcsem.export.render_check:check_config",),
                      run="arcsem.export.render:run_render_stage", needs_scene=False,
                      input_dirs="arcsem.export.render_check:input_dirs"))


def plan(stage: str) -> tuple[Stage, ...]:
    """The stages whose checks ``stage`` runs (ConfigError for an unknown one)."""
    return tuple(STAGES.get(name) for name in STAGES.get(stage).plan)


def _unique(stage: str, kind: str) -> list[Callable[..., Any]]:
    """The ``kind`` checks of ``stage``'s plan in order, each function once."""
    out: list[Callable[..., Any]] = []
    for s in plan(stage):
        for func in getattr(s, kind):
            func = resolve(func, s.name)
            if func not in out:
                out.append(func)
    return out


def check_config(cfg: Any, stage: str, overrides: list[str] | None = None) -> None:
    """Everything ``stage`` needs of the config, before any data is read: the command line's booleans
    (``overrides``), the stage name, the run-wide keys and dataset (:mod:`arcsem.preflight`), then the config checks
    of every stage it plans, each once. ``cfg``: the run's :class:`~arcsem.runconfig.RunConfig` (or a DictConfig)."""
    from .preflight import check_flag_overrides, check_run
    from .runconfig import run_config

    rc = run_config(cfg)
    check_flag_overrides(rc.cfg, overrides or [])
    check_run(rc, dataset=STAGES.get(stage).needs_scene)
    for check in _unique(stage, "check_config"):
        check(rc)


def check_scene(rc: Any, scene: Any, stage: str, run_dir: Path) -> list[str]:
    """The checks of the loaded scene: enough views, large enough (:func:`arcsem.preflight.check_scene_basics`),
    then those of every stage ``stage`` plans, each once; returns the warnings."""
    from .preflight import check_scene_basics

    warnings = check_scene_basics(scene)
    for check in _unique(stage, "check_scene"):
        warnings += check(rc, scene, stage, run_dir) or []
    return warnings
