"""One run's config, validated once: :class:`RunConfig`.

``app.run`` wraps the composed config in a :class:`RunConfig` and passes that object down to every stage check and
stage. Each config group is validated against its schema (:mod:`arcsem.configs`, the backbone plugin's ``Config``)
the first time it is read and kept: a group is validated at most once per run, by :func:`validated`, and a group
that a run never reads (``render`` in a training run) is never validated, so a stage's problems surface in the
order the stage checks read them. Code that is handed a plain ``DictConfig`` (a test, a benchmark, a finished
run's stored config) wraps it with :func:`run_config`; handed a :class:`RunConfig` it gets the same object back.
"""
from __future__ import annotations

import os
from functools import cached_property
from pathlib import Path
from typing import Any

from .configs import ActConfig, ColorizeConfig, MeshConfig, RenderConfig, TrainConfig
from .registry import plain, validate_config

__all__ = ["RunConfig", "cache_path", "cache_root", "run_config", "validated"]


def cache_root(cfg: Any = None) -> Path:
    """The cache root: ``cfg.cache_dir``, ``$ARCSEM_CACHE`` or ``~/.cache/arcsem`` (first set)."""
    root = None
    if cfg is not None:
        root = plain(cfg).get("cache_dir") if hasattr(cfg, "get") else None
    root = root or os.environ.get("ARCSEM_CACHE") or "~/.cache/arcsem"
    return Path(str(root)).expanduser()


def cache_path(sub: str, *, _root_: Any = None) -> str:
    """``${arcsem_cache:sub}`` in a config: ``sub`` under the cache root of the config being composed (its
    ``cache_dir``, else ``$ARCSEM_CACHE``, else ``~/.cache/arcsem``), e.g. the public colour scenes' default folder."""
    from omegaconf import OmegaConf

    root = OmegaConf.select(_root_, "cache_dir", default=None) if _root_ is not None else None
    return str(cache_root({"cache_dir": root}) / sub)


def validated(schema: type, raw: Any, where: str) -> Any:
    """``raw`` (a config node, a dict or None) as a checked ``schema`` instance: :func:`~arcsem.registry.validate_config`
    and then the schema's own cross-field ``check()``, where it has one. The one place a run's groups are validated."""
    obj = validate_config(schema, dict(plain(raw) or {}), where=where)
    check = getattr(obj, "check", None)
    if callable(check):
        check()
    return obj


class RunConfig:
    """The composed config of one run (``cfg``: read it for plain keys such as ``seed``, ``device`` or the dataset)
    and its groups as typed, checked dataclasses, each validated once, when first read.

    Fields: ``dataset`` (:class:`~arcsem.data.DatasetSpec`), ``train`` (:class:`~arcsem.configs.TrainConfig`), ``act``, ``colorize``, ``mesh``, ``render``, and
    ``backbone``: the plugin's validated ``Config`` (its class: ``backbone_class``, its name: ``backbone_name``);
    the loss terms' ``Config``: :meth:`loss_configs`.
    """

    def __init__(self, cfg: Any):
        self.cfg = cfg
        self.features: str | None = None  # colorize.features with `auto` resolved, by the stage-2 check (once)

    @property
    def backbone_name(self) -> str:
        return str(self.cfg.backbone.name)

    @cached_property
    def backbone_class(self) -> type:
        """The registered backbone class (:data:`arcsem.plugins.BACKBONES`)."""
        from .plugins import BACKBONES

        return BACKBONES.get(self.backbone_name)

    @cached_property
    def backbone(self) -> Any:
        """``cfg.backbone`` without ``name``, checked against the plugin's ``Config`` (ranges too)."""
        values = {k: v for k, v in dict(plain(self.cfg.backbone)).items() if k != "name"}
        return validated(self.backbone_class.Config, values, where=f"backbone '{self.backbone_name}'")

    @cached_property
    def dataset(self) -> Any:
        """``cfg.dataset`` checked once (:func:`arcsem.data.check_dataset_config`): the
        :class:`~arcsem.data.DatasetSpec` that :func:`arcsem.data.load_scene` reads."""
        from .data import check_dataset_config

        return check_dataset_config(self.cfg.dataset)

    @cached_property
    def train(self) -> TrainConfig:
        return validated(TrainConfig, self.cfg.train, where="train")

    @cached_property
    def act(self) -> ActConfig:
        return validated(ActConfig, self.cfg.get("act"), where="act")

    @cached_property
    def colorize(self) -> ColorizeConfig:
        return validated(ColorizeConfig, self.cfg.get("colorize"), where="colorize")

    @cached_property
    def mesh(self) -> MeshConfig:
        return validated(MeshConfig, self.cfg.get("mesh") if hasattr(self.cfg, "get") else None, where="mesh")

    @cached_property
    def render(self) -> RenderConfig:
        return validated(RenderConfig, self.cfg.get("render"), where="render")

    def loss_configs(self, where: str) -> dict:
        """The cache of validated loss ``Config``s of ``where`` (``train.losses``, ``colorize.losses``) that
        :func:`arcsem.train.losses.build_losses` fills and reads: a run validates each term once, however often its
        checks and stages build the loss set."""
        return self._loss_configs.setdefault(where, {})

    @cached_property
    def _loss_configs(self) -> dict:
        return {}

    @property
    def device(self) -> str:
        return str(self.cfg.get("device", "cpu"))


def run_config(cfg: Any) -> RunConfig:
    """``cfg`` itself if it is a :class:`RunConfig`, else a new one around it (nothing is validated until read)."""
    return cfg if isinstance(cfg, RunConfig) else RunConfig(cfg)
