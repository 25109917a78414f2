"""Hydra set-up at start-up: config schemas in the ConfigStore, and third-party config folders on the search path.

* **Schemas.** The core's dataclasses (:mod:`arcsem.configs`) and every installed backbone's ``Config`` (the
  ``CONFIG`` of the module its ``arcsem.backbones`` entry point names: light, no torch; see :mod:`arcsem.registry`)
  are stored as ``<group>/<name>_schema``; each YAML of
  the group lists its schema first in its defaults (``defaults: [gs2d_schema, _self_]``). So
  ``backbone.sh_degree=2`` works without ``+``, a mistyped key fails when the config is composed, and
  ``--cfg job`` and the run's ``config.yaml`` show every effective key.
  ``mesh`` and ``render`` (top-level blocks, not groups) have theirs in ``outputs_schema``, the first entry of
  conf/config.yaml's defaults: their defaults live in the dataclasses only.
* **Search path.** A plugin package adds its YAML folder with an entry point in the group ``arcsem.conf``
  naming a package of config groups (``my_plugin = "my_plugin.conf"``); :class:`EntryPointSearchPath`
  appends every such package (as ``pkg://my_plugin.conf``). It is
  registered with Hydra directly, so it works for editable installs too (Hydra's scan of the
  ``hydra_plugins`` namespace does not see packages installed with ``pip install -e``).

* **Resolvers.** ``${gs2d_lowpass:<rasterizer>,<sigma>}``: a preset's 2DGS low-pass sigma, or gsplat's fixed one
  where ``backbone.rasterizer=gsplat`` (:func:`arcsem.backbones.gs2d.config.lowpass_for`);
  ``${of_steps:${train.steps},<fraction>}``: a schedule's step as a fraction of the run (:func:`of_steps`);
  ``${slurm_cpus:${threads}}`` and ``${slurm_gpus:${device}}``: what a SLURM job asks for
  (conf/hydra/launcher/submitit_slurm.yaml; :func:`slurm_cpus`, :func:`slurm_gpus`).

:func:`setup` is idempotent; the ``arcsem`` CLI and ``arcsem.conf`` (read by ``compose``) call it.
"""
from __future__ import annotations

import dataclasses
import warnings
from importlib import metadata

from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin

__all__ = ["CONF_GROUP", "SLURM_CPUS", "EntryPointSearchPath", "backbone_schema", "of_steps", "setup",
           "slurm_cpus", "slurm_gpus"]

CONF_GROUP = "arcsem.conf"  # plugin name -> "package.conf" (a package of config groups)
SLURM_CPUS = 4  # cores a SLURM job asks for when ``threads`` is null
_done = False


class EntryPointSearchPath(SearchPathPlugin):
    """Appends the config folder of every installed arcsem plugin (entry-point group ``arcsem.conf``)."""

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        for ep in sorted(metadata.entry_points(group=CONF_GROUP), key=lambda e: e.name):
            search_path.append(provider=f"arcsem-plugin:{ep.name}", path=f"pkg://{ep.module}")


def backbone_schema(name: str, config: type) -> type:
    """``config`` with a leading ``name: str = <name>`` field: the schema of ``conf/backbone/<name>.yaml``."""
    return dataclasses.make_dataclass(f"{config.__name__}Schema", [("name", str, dataclasses.field(default=name))],
                                      bases=(config,))


def of_steps(steps: int, fraction: float, least: int = 1) -> int:
    """``${of_steps:${train.steps},<fraction>[,<least>]}``: a step of a preset's schedule as a fraction of the run
    (rounded, at least ``least``), so the schedule keeps its shape when ``train.steps`` changes
    (conf/tuning/quick_*.yaml)."""
    return max(int(least), round(int(steps) * float(fraction)))


def slurm_cpus(threads: int | None) -> int:
    """``${slurm_cpus:${threads}}``: the cores a SLURM job asks for: ``threads``, or :data:`SLURM_CPUS` when null
    (the job then runs that many threads: :func:`arcsem.cores.usable_cores` reads its allocation)."""
    return SLURM_CPUS if threads is None else int(threads)


def slurm_gpus(device: str | None) -> int | None:
    """``${slurm_gpus:${device}}``: GPUs a SLURM task asks for: 1 for ``cuda``, k + 1 for ``cuda:k`` (a job sees
    its GPUs as ``cuda:0`` ...), None (none) for the CPU."""
    name = str(device or "cpu")
    if name == "cuda":
        return 1
    if name.startswith("cuda:") and name[5:].isdigit():
        return int(name[5:]) + 1
    return None


def _store_backbone_schemas(cs) -> None:
    """Store every installed backbone's Config as ``backbone/<name>_schema`` (a plugin registered the old way is
    read too, and its :class:`~arcsem.registry.PluginDeprecationWarning` shown)."""
    from .registry import BACKBONES, PluginDeprecationWarning

    warnings.filterwarnings("default", category=PluginDeprecationWarning)  # hidden by default, as DeprecationWarning
    for name in BACKBONES.declared():
        try:
            config = BACKBONES.config(name)
        except Exception as exc:  # noqa: BLE001 (a broken plugin must not stop the others; named when used)
            warnings.warn(f"arcsem: backbone config {name} does not load: {exc!r}", stacklevel=3)
            continue
        cs.store(group="backbone", name=f"{name}_schema", node=backbone_schema(name, config))


def setup() -> None:
    """Store the schemas and register the search-path plugin (once per process)."""
    global _done
    if _done:
        return
    from hydra.core.config_store import ConfigStore
    from hydra.core.plugins import Plugins
    from omegaconf import OmegaConf

    from .configs import ActConfig, ColorizeConfig, MeshConfig, RenderConfig, TrainConfig

    cs = ConfigStore.instance()
    for group, node in (("train", TrainConfig), ("colorize", ColorizeConfig), ("act", ActConfig)):
        cs.store(group=group, name=f"{group}_schema", node=node)
    # the top-level blocks with a schema and no group: conf/config.yaml lists `outputs_schema` first in its defaults
    cs.store(name="outputs_schema", node={"mesh": OmegaConf.structured(MeshConfig),
                                          "render": OmegaConf.structured(RenderConfig)})
    _store_backbone_schemas(cs)
    Plugins.instance().register(EntryPointSearchPath)
    from .backbones.gs2d.config import lowpass_for
    from .runconfig import cache_path

    OmegaConf.register_new_resolver("gs2d_lowpass", lowpass_for, replace=True)
    OmegaConf.register_new_resolver("arcsem_cache", cache_path, replace=True)
    OmegaConf.register_new_resolver("of_steps", of_steps, replace=True)
    OmegaConf.register_new_resolver("slurm_cpus", slurm_cpus, replace=True)
    OmegaConf.register_new_resolver("slurm_gpus", slurm_gpus, replace=True)
    # conf/hydra/launcher/submitit_slurm.yaml (every key, so it stands alone) is checked against the plugin's
    # schema of the same name, which Hydra calls deprecated on every sweep: the check is wanted, the notice is not
    warnings.filterwarnings("ignore", message=r"(?s).*'hydra/launcher/submitit_slurm' is validated against ConfigStore")
    _done = True
