"""Optimisers and learning-rate schedules from config, one optimiser per parameter group.

Where the rates come from: ``train.optim.groups.<group>`` (a :class:`GroupSchedule` override from a preset
or the command line), else the backbone's declared :meth:`~arcsem.plugins.Backbone.learning_rates`; the
``act`` group (the ACT module's parameters) uses ``act.lr``, constant.

Optimiser type: ``train.optim.type`` if set; else the backbone's :meth:`~arcsem.plugins.Backbone.make_optimizers`
for the groups it returns (Plenoxels: RMSProp) and Adam for the rest. The result is ``{group: Optimizer}``: one
optimiser per group, so densification code replaces tensors in ``optimizers[group]`` and its ``state``
without touching the others.

Schedules are pure functions of the step (:func:`lr_at`, the one log-linear decay of the project), so a
resumed run sets exactly the same rates.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from ..configs import GroupSchedule, OptimConfig
from ..errors import ConfigError
from ..registry import validate_config

__all__ = [
    "GroupSchedule",
    "OptimConfig",
    "apply_schedules",
    "build_optimizers",
    "group_schedules",
    "lr_at",
    "make_optimizers",
]


def lr_at(s: Schedule, step: int, total_steps: int) -> float:
    """Learning rate at ``step``: ``exp(lerp(log lr, log lr_final, t))`` times the delay ramp.

    ``s`` may also be a callable ``step -> lr`` (a backbone's own schedule).
    """
    if callable(s):
        return s(step)
    lr = s.lr
    if s.lr_final is not None and s.lr_final != s.lr:
        if s.lr <= 0 or s.lr_final <= 0:
            raise ConfigError(f"log-linear decay needs positive rates, got lr={s.lr}, lr_final={s.lr_final}")
        n = s.decay_steps or total_steps
        t = min(max(step / max(n, 1), 0.0), 1.0)
        lr = math.exp((1 - t) * math.log(s.lr) + t * math.log(s.lr_final))
    if s.delay_steps > 0:
        ramp = math.sin(0.5 * math.pi * min(max(step / s.delay_steps, 0.0), 1.0))
        lr *= s.delay_mult + (1 - s.delay_mult) * ramp
    return lr


Schedule = GroupSchedule | Callable[[int], float]


def group_schedules(groups: dict[str, list], backbone: nn.Module, stage: str, optim: OptimConfig,
                    act_lr: float | None = None) -> dict[str, Schedule]:
    """The schedule of every group in ``groups`` (raises ConfigError naming a group without a rate)."""
    unknown = set(optim.groups) - set(groups)
    if unknown:
        raise ConfigError(f"train.optim.groups: unknown group(s) {sorted(unknown)}; "
                          f"stage '{stage}' has {sorted(groups)}")
    declared = backbone.learning_rates(stage)
    out: dict[str, Schedule] = {}
    for g in groups:
        if g == "act" and act_lr is not None:
            out[g] = GroupSchedule(lr=act_lr)
            continue
        base = declared.get(g)
        override = dict(optim.groups.get(g) or {})
        if override:  # replaces the backbone's schedule of the group entirely
            if "lr" not in override:
                raise ConfigError(f"train.optim.groups.{g}: no lr")
            out[g] = validate_config(GroupSchedule, override, where=f"train.optim.groups.{g}")
        elif base is not None:
            out[g] = base
        else:
            raise ConfigError(f"no learning rate for parameter group '{g}' (stage '{stage}'): the backbone's "
                              f"learning_rates() does not give one; set train.optim.groups.{g}.lr")
    return out


def build_optimizers(groups: dict[str, list[nn.Parameter]], schedules: dict[str, Schedule],
                     optim: OptimConfig, default_type: str = "adam") -> dict[str, torch.optim.Optimizer]:
    """One optimiser per group: ``{group: Optimizer}`` with a single param group ``{"name": group}``."""
    kind = (optim.type or default_type).lower()
    out = {}
    for g, params in groups.items():
        lr = lr_at(schedules[g], 0, 1)
        spec = [{"params": list(params), "lr": lr, "name": g}]
        if kind == "adam":
            fused = optim.fused and all(p.dtype.is_floating_point and not p.is_sparse for p in params)
            out[g] = torch.optim.Adam(spec, lr=lr, betas=tuple(optim.betas), eps=optim.eps, fused=fused or None)
        elif kind == "rmsprop":
            out[g] = torch.optim.RMSprop(spec, lr=lr, alpha=optim.rmsprop_alpha, eps=optim.rmsprop_eps)
        else:
            raise ConfigError(f"train.optim.type: unknown optimiser '{kind}'; expected adam or rmsprop")
    return out


def make_optimizers(backbone: nn.Module, groups: dict[str, list[nn.Parameter]], schedules: dict[str, Schedule],
                    optim: OptimConfig, stage: str) -> dict[str, torch.optim.Optimizer]:
    """Backbone's ``make_optimizers(stage)`` for its groups (unless ``optim.type`` is set), Adam for the rest."""
    out: dict[str, torch.optim.Optimizer] = {}
    if optim.type is None:
        out = dict(backbone.make_optimizers(stage, {g: ps for g, ps in groups.items() if g != "act"}))
        unknown = set(out) - set(groups)
        if unknown:
            raise ConfigError(f"backbone.make_optimizers('{stage}') returned unknown group(s) {sorted(unknown)}")
    rest = {g: ps for g, ps in groups.items() if g not in out}
    out.update(build_optimizers(rest, schedules, optim))
    return out


def apply_schedules(optimizers: dict[str, torch.optim.Optimizer], schedules: dict[str, Schedule],
                    step: int, total_steps: int, lr_scale: float = 1.0) -> dict[str, float]:
    """Set every group's rate for ``step`` (times ``lr_scale``, except the ``act`` group); returns ``{group: lr}``."""
    lrs = {}
    for g, opt in optimizers.items():
        lrs[g] = lr_at(schedules[g], step, total_steps) * (1.0 if g == "act" else lr_scale)
        for pg in opt.param_groups:
            pg["lr"] = lrs[g]
    return lrs
