"""Dataset readers: ``load_scene(cfg)`` dispatches on ``cfg.kind`` (transforms | colmap | synthetic).

Every reader returns one :class:`~arcsem.scene.Scene`; options shared by all readers are in
:class:`~arcsem.data.build.ReaderOptions` (``downscale``, ``split``, ``test_every``, ``max_views``).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import ConfigError, DataError, PluginError
from ..scene import Scene
from .build import ReaderOptions, reader_options
from .colmap import read_colmap
from .io import read_image, read_ply, write_ply
from .transforms import read_transforms

__all__ = [
    "KINDS",
    "DatasetSpec",
    "ReaderOptions",
    "check_dataset_config",
    "dataset_keys",
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
_READER_KEYS = {"kind", "path", "images", "masks", "undistort", "params", "source",
                *(f.name for f in dataclasses.fields(ReaderOptions))}
# ``source``: how the data at ``path`` is obtained (a command), said in the error when ``path`` does not exist.
_KIND_KEYS = {"transforms": ("path", "undistort", "source"), "colmap": ("path", "images", "masks", "undistort", "source"),
              "synthetic": ("params",)}


def dataset_keys(kind: str) -> list[str]:
    """The keys a ``dataset`` config of ``kind`` may hold: ``kind``, the reader options, the kind's own (for
    ``synthetic``: every :class:`~arcsem.synthetic.SceneParams` field)."""
    keys = ["kind", *_KIND_KEYS[kind], *(f.name for f in dataclasses.fields(ReaderOptions))]
    if kind == "synthetic":
        from ..synthetic.write import SceneParams

        keys += [f.name for f in dataclasses.fields(SceneParams) if f.name not in keys]
    return keys


@dataclass(frozen=True)
class DatasetSpec:
    """A checked ``dataset`` config (:func:`check_dataset_config`), what :func:`load_scene` reads: the kind, the
    reader options, the scene's path (``transforms``, ``colmap``), the generator's parameters (``synthetic``) and
    the COLMAP reader's own keys."""

    kind: str
    options: ReaderOptions
    path: str | None = None
    params: dict | None = None
    images: str = "images"
    masks: str | None = None
    undistort: bool = True
    source: str | None = None


def check_dataset_config(cfg: Any) -> DatasetSpec:
    """The checked :class:`DatasetSpec` of a ``dataset`` config (DictConfig or dict); ConfigError naming the key for
    a kind or key arcsem does not know (a typo added with ``+dataset.dowscale=4`` would be ignored otherwise), bad
    reader options, a missing ``path``, or, for ``synthetic``, a generator parameter out of its range
    (``n_horizontal=0``, ``noise=-1``, ``camera=fisheye``). Reads no data. A run calls it once (the run config's
    ``dataset``) and hands the spec to :func:`load_scene`."""
    if isinstance(cfg, DatasetSpec):
        return cfg
    kind = _get(cfg, "kind")
    if kind not in KINDS:
        raise ConfigError(f"dataset.kind: unknown kind '{kind}'; available: {', '.join(KINDS)}")
    keys = dataset_keys(kind)
    unknown = [str(k) for k in (cfg.keys() if hasattr(cfg, "keys") else vars(cfg)) if k not in keys]
    if unknown:
        raise ConfigError(f"dataset.{unknown[0]}: unknown key for dataset kind '{kind}'; valid keys: "
                          f"{', '.join(keys)}")
    opts = reader_options(cfg)
    if kind == "synthetic":
        return DatasetSpec(kind, opts, params=_synthetic_params(cfg))
    from omegaconf import DictConfig, OmegaConf

    if isinstance(cfg, DictConfig) and OmegaConf.is_missing(cfg, "path"):
        raise ConfigError(f"dataset.path is not set: add dataset.path=/path/to/scene (dataset kind '{kind}')")
    path = _get(cfg, "path")
    if not path:
        raise ConfigError(f"dataset.path is not set (dataset kind '{kind}')")
    source = _get(cfg, "source")
    source = None if source is None else str(source)
    if kind == "transforms":
        return DatasetSpec(kind, opts, path=str(path), undistort=bool(_get(cfg, "undistort", True)), source=source)
    masks = _get(cfg, "masks")
    return DatasetSpec(kind, opts, path=str(path), images=str(_get(cfg, "images", "images")),
                       masks=None if masks is None else str(masks), undistort=bool(_get(cfg, "undistort", True)),
                       source=source)


def _synthetic_params(cfg: Any) -> dict:
    """The generator's parameters of a synthetic dataset config, validated against ``SceneParams``."""
    from omegaconf import DictConfig, OmegaConf

    from ..registry import validate_config
    from ..synthetic.write import SceneParams

    plain = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else dict(cfg)
    params = plain.get("params")
    where = "dataset.params" if params is not None else "dataset"
    if params is None:
        params = {k: v for k, v in plain.items() if k not in _READER_KEYS}
    if not isinstance(params, dict):
        raise ConfigError(f"dataset.params: expected a mapping of generator parameters, got {params!r}")
    validate_config(SceneParams, params, where=where)
    return params


def _get(cfg: Any, key: str, default: Any = None) -> Any:
    return cfg.get(key, default) if hasattr(cfg, "get") else getattr(cfg, key, default)


def load_scene(cfg: Any) -> Scene:
    """Read the dataset a :class:`DatasetSpec` describes; handed a ``conf/dataset/*.yaml`` config (DictConfig or
    dict) instead, check it first (:func:`check_dataset_config`)."""
    spec = check_dataset_config(cfg)
    if spec.kind == "synthetic":
        try:
            from ..synthetic import ensure_scene
        except ImportError as exc:
            raise PluginError(f"dataset kind 'synthetic' needs arcsem.synthetic.ensure_scene: {exc}") from None
        return read_transforms(Path(ensure_scene(**spec.params)), spec.options)
    if spec.source and not Path(spec.path).exists():
        raise DataError(f"dataset path does not exist: {spec.path} ({spec.source})")
    if spec.kind == "transforms":
        return read_transforms(spec.path, spec.options, undistort=spec.undistort)
    return read_colmap(spec.path, spec.options, images=spec.images, masks=spec.masks, undistort=spec.undistort)
