"""The weighted sum of loss plugins that a training stage optimises.

A loss set is configured as a mapping ``name -> cfg`` (``cfg`` holds ``weight``, ``start_step`` and
the plugin's own keys; ``null`` or ``weight: 0`` switches a term off)::

    losses: {l1: {weight: 0.8}, dssim: {weight: 0.2}, normal_consistency: {weight: 0.05, start_step: 7000}}

Each plugin's ``requires`` is checked against the backbone's ``provides`` (and its ``batch_modes``
against the backbone's ``batch_mode``) when the set is built, so a run cannot start with a loss the
backbone cannot feed. A plugin registered under another name can be used twice with ``plugin:``::

    losses: {l1_mask: {plugin: l1, weight: 0.1, masked: true}}
"""
from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import torch
from torch import Tensor, nn

from ..errors import ConfigError
from ..plugins import LOSSES, Batch, Loss, RenderOutput
from ..registry import plain, validate_config
from ..timing import region

__all__ = ["LossSet", "build_losses"]


class LossSet(nn.Module):
    """Named loss plugins; ``forward`` returns the weighted total and every term (unweighted)."""

    def __init__(self, terms: dict[str, Loss]):
        super().__init__()
        self.terms = nn.ModuleDict(terms)

    def active(self, step: int) -> list[str]:
        """Names of the terms that contribute at ``step`` (weight != 0 and ``step >= start_step``)."""
        return [n for n, t in self.terms.items() if t.cfg.weight != 0 and step >= t.cfg.start_step]

    def forward(self, out: RenderOutput, batch: Batch, step: int) -> tuple[Tensor, dict[str, Tensor]]:
        """Returns ``(total, {name: unweighted term})`` for the terms active at ``step``."""
        terms = {}
        for n in self.active(step):
            with region(f"arcsem::loss/{n}"):  # a profiler region (benchmarks/profile_step.py), free otherwise
                terms[n] = self.terms[n](out, batch, step)
        if not terms:
            raise ConfigError(f"no loss term is active at step {step}; losses: {', '.join(self.terms) or 'none'}")
        total = sum(self.terms[n].cfg.weight * v for n, v in terms.items())
        return total, terms

    def requires(self, step: int | None = None) -> set[str]:
        names = self.active(step) if step is not None else list(self.terms)
        return set().union(*(self.terms[n].requires for n in names)) if names else set()


def build_losses(cfg: Mapping | None, provides: frozenset[str] | set[str], batch_mode: str = "image",
                 where: str = "train.losses", backbone: str = "backbone", batch_parts: frozenset[str] = frozenset(),
                 validated: dict | None = None, **runtime: Any) -> LossSet:
    """Build the loss plugins of ``cfg`` and check them against the backbone.

    Args:
        cfg: ``{name: {weight, start_step, plugin?, ...} | None}``.
        provides: the render outputs the backbone produces (``Backbone.provides``).
        batch_mode: ``"image"`` or ``"rays"`` (``Backbone.batch_mode``).
        batch_parts: the optional :class:`~arcsem.plugins.Batch` parts the stage fills (``{"color"}`` in stage 2),
            checked against each loss's ``needs``.
        validated: a run's cache of the terms' validated ``Config`` (:meth:`arcsem.runconfig.RunConfig.loss_configs`):
            a term already there is built from a copy of it, not validated again; one validated here is added.
        runtime: passed to every plugin constructor (e.g. ``scene``).
    Raises:
        ConfigError: a term needs an output the backbone does not provide, or a batch mode it lacks.
    """
    terms: dict[str, Loss] = {}
    for name, term_cfg in (plain(cfg) or {}).items():
        if term_cfg is None:
            continue
        term_cfg = dict(term_cfg)
        plugin = term_cfg.pop("plugin", name)
        if float(term_cfg.get("weight", 1.0)) == 0.0:
            continue
        loss = _build_term(plugin, term_cfg, validated, runtime)
        for key in ("weight", "start_step"):
            value = getattr(loss.cfg, key, 0)
            if not isinstance(value, (int, float)) or value < 0:
                raise ConfigError(f"{where}.{name}.{key}: must be >= 0, got {value!r}")
        missing = set(loss.requires) - set(provides)
        if missing:
            raise ConfigError(
                f"{where}.{name}: loss '{plugin}' needs {sorted(missing)} which backbone '{backbone}' does not "
                f"provide (it provides {sorted(provides)}); drop the term with {where}.{name}=null")
        modes = loss.batch_modes
        if batch_mode not in modes:
            raise ConfigError(
                f"{where}.{name}: loss '{plugin}' works on {sorted(modes)} batches but backbone '{backbone}' "
                f"trains on '{batch_mode}' batches; drop the term with {where}.{name}=null")
        lacking = set(loss.needs) - set(batch_parts)
        if lacking:
            raise ConfigError(f"{where}.{name}: loss '{plugin}' needs the batch's {sorted(lacking)} targets, which "
                              f"this stage does not give ('color': a stage-2 loss, for colorize.losses)")
        terms[name] = loss
    if not terms:
        raise ConfigError(f"{where}: no loss term with a non-zero weight")
    return LossSet(terms)


def _build_term(plugin: str, term_cfg: dict, validated: dict | None, runtime: dict) -> Loss:
    """The loss plugin ``plugin`` with ``term_cfg`` validated against its ``Config`` once per ``validated`` cache
    (keyed by the plugin and the values: a changed term is another config, validated anew)."""
    cls = LOSSES.get(plugin)
    key = (plugin, repr(sorted(term_cfg.items())))
    if validated is None or key not in validated:
        config = validate_config(cls.Config, term_cfg, where=f"{LOSSES.kind} '{plugin}'")
        if validated is None:
            return cls(config, **runtime)
        validated[key] = config
    return cls(copy.deepcopy(validated[key]), **runtime)


def is_finite(x: Tensor) -> bool:
    return bool(torch.isfinite(x).all())
