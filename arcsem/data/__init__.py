"""Dataset readers: ``load_scene(cfg)`` dispatches on ``cfg.kind`` (transforms | colmap | synthetic).

Every reader returns one :class:`~arcsem.scene.Scene`; options shared by all readers are in
:class:`~arcsem.data.build.ReaderOptions` (``downscale``, ``split``, ``test_every``, ``max_views``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import ConfigError, PluginError
from ..scene import Scene
from .build import ReaderOptions, reader_options
from .colmap import read_colmap
from .io import read_image, read_ply, write_ply
from .transforms import read_transforms

__all__ = [
    "KINDS",
    "ReaderOptions",
    "load_scene",
    "read_colmap",
    "read_image",
    "read_ply",
    "read_transforms",
    "reader_options",
    "write_ply",
]

KINDS = ("transforms", "colmap", "synthetic")
# Keys of a dataset config that are reader options, not parameters of the synthetic generator.
_READER_KEYS = {"kind", "path", "downscale", "split", "test_every", "max_views", "holdout", "images", "masks",
                "undistort", "params"}


def _get(cfg: Any, key: str, default: Any = None) -> Any:
    return cfg.get(key, default) if hasattr(cfg, "get") else getattr(cfg, key, default)


def _synthetic_path(cfg: Any) -> Path:
    """Generate (or reuse) the synthetic scene: ``arcsem.synthetic.ensure_scene(**params)``.

    ``params`` is ``cfg.params`` if present, else every key of ``cfg`` that is not a reader option.
    """
    try:
        from ..synthetic import ensure_scene
    except ImportError as exc:
        raise PluginError(f"dataset kind 'synthetic' needs arcsem.synthetic.ensure_scene: {exc}") from None
    from omegaconf import DictConfig, OmegaConf

    plain = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else dict(cfg)
    params = plain.get("params")
    if params is None:
        params = {k: v for k, v in plain.items() if k not in _READER_KEYS}
    return Path(ensure_scene(**params))


def load_scene(cfg: Any) -> Scene:
    """Read the dataset described by a ``conf/dataset/*.yaml`` config (DictConfig or dict)."""
    kind = _get(cfg, "kind")
    if kind not in KINDS:
        raise ConfigError(f"dataset.kind: unknown kind '{kind}'; available: {', '.join(KINDS)}")
    opts = reader_options(cfg)
    if kind == "synthetic":
        return read_transforms(_synthetic_path(cfg), opts)
    from omegaconf import DictConfig, OmegaConf

    if isinstance(cfg, DictConfig) and OmegaConf.is_missing(cfg, "path"):
        raise ConfigError(f"dataset.path is not set: add dataset.path=/path/to/scene (dataset kind '{kind}')")
    path = _get(cfg, "path")
    if not path:
        raise ConfigError(f"dataset.path is not set (dataset kind '{kind}')")
    if kind == "transforms":
        return read_transforms(path, opts)
    return read_colmap(path, opts, images=_get(cfg, "images", "images"), masks=_get(cfg, "masks"),
                       undistort=bool(_get(cfg, "undistort", True)))
