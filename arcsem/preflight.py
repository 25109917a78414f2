"""The checks every stage shares, before anything is trained (the stages' own checks: :mod:`arcsem.stages`).

:func:`check_flag_overrides` and :func:`check_run` run before the dataset is read: the command line's booleans,
the top-level keys (``seed``,
``device``, ``threads``) and the dataset config. :func:`check_scene_basics` runs once the scene is loaded: enough
views, images no smaller than the SSIM window. :func:`check_backbone` and :func:`check_backbone_scene` run the
backbone plugin's own checks (:meth:`arcsem.plugins.Backbone.check_config`, ``check_scene``); the stages that
build a backbone list them, and a run calls each once.

Every problem raises :class:`~arcsem.errors.ConfigError` or :class:`~arcsem.errors.DataError` naming the
key, file or view; warnings are returned as strings.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .errors import ConfigError, DataError

__all__ = ["MIN_IMAGE_SIZE", "check_backbone", "check_backbone_scene", "check_device", "check_flag_overrides",
           "check_run", "check_scene_basics", "check_threads", "training_size"]

MIN_IMAGE_SIZE = 11
"""Smallest image side arcsem trains or scores on: the 11-pixel SSIM window."""


def check_device(device: Any) -> None:
    """``device`` must name a torch device this machine has."""
    import torch

    try:
        dev = torch.device(str(device))
    except RuntimeError:
        raise ConfigError(f"device: '{device}' is not a device; use cpu, cuda or cuda:<index>") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "a CPU-only build"
            raise ConfigError(f"device={device}: no CUDA device is available on this machine (torch is {build}); "
                              "use device=cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"device={device}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    elif dev.type != "cpu":
        raise ConfigError(f"device: '{device}' is not supported; use cpu or cuda")


def check_threads(threads: Any) -> None:
    """``threads``: a positive integer, or None (the cores this process may use)."""
    if threads is not None and (not isinstance(threads, int) or isinstance(threads, bool) or threads < 1):
        raise ConfigError(f"threads: expected a positive integer or null, got {threads!r}")


def _check_top_level(cfg: Any) -> None:
    seed = cfg.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise ConfigError(f"seed: expected an integer, got {seed!r}")
    check_threads(cfg.get("threads"))
    check_device(cfg.get("device", "cpu"))


def check_flag_overrides(cfg: Any, overrides: list[str]) -> None:
    """A command-line value for a true/false key must read as a boolean.

    The Hydra schemas convert ``train.progress=-7`` to ``True`` (OmegaConf reads any non-zero number as true)
    before a dataclass sees it, so the raw overrides are checked against the composed config's types.
    """
    from omegaconf import OmegaConf

    for item in overrides:
        key, sep, value = item.lstrip("+~").partition("=")
        if not sep or not isinstance(OmegaConf.select(cfg, key, default=None), bool):
            continue
        if value.strip().lower() not in ("true", "false"):
            raise ConfigError(f"{key}: must be true or false, got {value!r}")


def training_size(cams: Any, downscale: float, width: int | None) -> tuple[int, int]:
    """``(w, h)`` of the training images of ``cams`` at ``width`` (never above the images') or ``1 / downscale``."""
    w = min(width, cams.width) if width else round(cams.width / downscale)
    return w, round(cams.height * w / cams.width)


def check_run(rc: Any, dataset: bool = True) -> None:
    """The run-wide keys ``seed``, ``threads``, ``device`` and, with ``dataset``, the dataset config (read once into
    ``rc.dataset``, :func:`arcsem.data.check_dataset_config`); reads no data. ``rc``: the run's
    :class:`~arcsem.runconfig.RunConfig`."""
    _check_top_level(rc.cfg)
    if dataset:
        rc.dataset  # noqa: B018 - validated (and kept) on first read


def check_scene_basics(scene: Any) -> list[str]:
    """At least two training views, images no smaller than :data:`MIN_IMAGE_SIZE`; returns the reader's warnings."""
    if len(scene.train) < 2:
        raise DataError(f"{scene.root}: {len(scene.train)} training view(s); a 3-D scene needs at least 2 "
                        "(check dataset.split and dataset.max_views)")
    cams = scene.train.cameras
    if min(cams.width, cams.height) < MIN_IMAGE_SIZE:
        raise DataError(f"{scene.root}: the images are {cams.width}x{cams.height} px ('{scene.train.names[0]}'); "
                        f"arcsem needs at least {MIN_IMAGE_SIZE}x{MIN_IMAGE_SIZE} (the SSIM window)")
    return list(getattr(scene, "warnings", []))


def check_backbone(rc: Any) -> None:
    """The backbone config against its plugin's ``Config``, then the plugin's own config check (the optional gsplat
    rasteriser needs gsplat and a CUDA device: :meth:`arcsem.plugins.Backbone.check_config`)."""
    rc.backbone_class.check_config(rc.backbone, rc.device)


def check_backbone_scene(rc: Any, scene: Any, stage: str, run_dir: Path) -> list[str]:
    """The backbone plugin's checks of the loaded scene (:meth:`arcsem.plugins.Backbone.check_scene`)."""
    rc.backbone_class.check_scene(rc.backbone, scene)
    return []
