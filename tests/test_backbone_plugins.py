"""A backbone's one registration: an entry point of ``arcsem.backbones`` naming a module with ``CONFIG`` and
``BACKBONE``; the old way (``@BACKBONES.register`` and ``arcsem.backbone_configs``) still loads, with a warning.

The plugins are real installed distributions: a ``*.dist-info`` folder with ``entry_points.txt`` and the plugin's
modules, in a folder put on ``sys.path`` (what pip leaves in site-packages), found by ``importlib.metadata``.
"""
from __future__ import annotations

import importlib
import sys
import warnings
from pathlib import Path

import pytest

import arcsem.registry
from arcsem.errors import PluginError
from arcsem.registry import BACKBONES, PluginDeprecationWarning, Registry

CONFIG_SRC = '''from dataclasses import dataclass


@dataclass
class {cls}:
    value: float = 0.5


@dataclass
class Other:  # a dataclass that is not the class's Config
    value: float = 0.5
'''
CLASS_SRC = '''from arcsem.plugins import Backbone

from .config import {config}


class {cls}(Backbone):
    Config = {config}
'''
LAZY_SRC = "from arcsem.lazy import lazy_getattr\n\n__getattr__ = lazy_getattr(__name__, {where!r})\n"
OLD_SRC = '''from arcsem.plugins import Backbone
from arcsem.registry import BACKBONES

from oldbb_cfg import OldConfig


@BACKBONES.register("{name}")
class OldBackbone{name}(Backbone):
    Config = OldConfig
'''
MODULES = ("newbb", "oldbb", "barebb", "emptybb", "mismatchbb")


def install(site: Path, dist: str, entry_points: dict[str, dict[str, str]], files: dict[str, str]) -> None:
    """Write distribution ``dist`` as pip would install it into ``site``: its dist-info and its modules."""
    info = site / f"{dist.replace('-', '_')}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("".join(
        f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in eps.items()) + "\n" for group, eps in entry_points.items()))
    for rel, text in files.items():
        (site / rel).parent.mkdir(parents=True, exist_ok=True)
        (site / rel).write_text(text)


def new_style(pkg: str, where: dict[str, str], config: str = "NewConfig", cls: str = "NewBackbone") -> dict:
    return {f"{pkg}/__init__.py": LAZY_SRC.format(where=where),
            f"{pkg}/config.py": CONFIG_SRC.format(cls=config),
            f"{pkg}/backbone.py": CLASS_SRC.format(cls=cls, config=config)}


@pytest.fixture
def reg(tmp_path, monkeypatch):
    """A registry like :data:`BACKBONES` (put in its place) over installed test distributions:
    ``_new_bb`` (one entry point, the new way), ``_old_bb`` (decorator + arcsem.backbone_configs), ``_older_bb``
    (decorator only), ``_bare_bb`` (BACKBONE but no CONFIG), ``_empty_bb`` (neither), ``_mismatch_bb``."""
    site = tmp_path / "site"
    install(site, "arcsem-test-newbb", {"arcsem.backbones": {"_new_bb": "newbb"}},
            new_style("newbb", {"CONFIG": "config:NewConfig", "BACKBONE": "backbone:NewBackbone"}))
    install(site, "arcsem-test-oldbb",
            {"arcsem.backbones": {"_old_bb": "oldbb.a", "_older_bb": "oldbb.b"},
             "arcsem.backbone_configs": {"_old_bb": "oldbb_cfg:OldConfig"}},
            {"oldbb_cfg.py": CONFIG_SRC.format(cls="OldConfig"), "oldbb/__init__.py": "",
             "oldbb/a.py": OLD_SRC.format(name="_old_bb"), "oldbb/b.py": OLD_SRC.format(name="_older_bb")})
    install(site, "arcsem-test-badbb",
            {"arcsem.backbones": {"_bare_bb": "barebb", "_empty_bb": "emptybb", "_mismatch_bb": "mismatchbb"}},
            {**new_style("barebb", {"BACKBONE": "backbone:NewBackbone"}), "emptybb.py": "X = 1\n",
             **new_style("mismatchbb", {"CONFIG": "config:Other", "BACKBONE": "backbone:NewBackbone"})})
    monkeypatch.syspath_prepend(str(site))
    importlib.invalidate_caches()
    registry = Registry(BACKBONES.kind, BACKBONES.group, class_attr=BACKBONES.class_attr,
                        legacy_config_group=BACKBONES.legacy_config_group)
    monkeypatch.setattr(arcsem.registry, "BACKBONES", registry)
    yield registry
    for mod in [m for m in sys.modules if m.split(".")[0] in (*MODULES, "oldbb_cfg")]:
        del sys.modules[mod]


def test_one_entry_point_registers_a_backbone_and_its_config(reg):
    with warnings.catch_warnings():
        warnings.simplefilter("error", PluginDeprecationWarning)
        assert {"_new_bb", "_old_bb", "gs2d"} <= set(reg.names())
        config = reg.config("_new_bb")
        assert config.__name__ == "NewConfig" and "newbb.backbone" not in sys.modules  # the class is not imported
        cls = reg.get("_new_bb")
    assert cls.__name__ == "NewBackbone" and cls.name == "_new_bb" and cls.Config is config
    assert reg.origin("_new_bb") == "newbb [arcsem-test-newbb]"
    assert reg.build({"name": "_new_bb", "value": 2}).cfg == config(value=2.0)


def test_in_tree_backbones_are_registered_the_new_way():
    from importlib import metadata

    eps = {ep.name: ep.value for ep in metadata.entry_points(group="arcsem.backbones")}
    assert {k: eps[k] for k in ("gs2d", "gs3d", "plenoxels")} == {
        "gs2d": "arcsem.backbones.gs2d", "gs3d": "arcsem.backbones.gs3d", "plenoxels": "arcsem.backbones.plenoxels"}
    legacy = {ep.name for ep in metadata.entry_points(group="arcsem.backbone_configs")}
    assert not legacy & {"gs2d", "gs3d", "plenoxels"}
    for name in ("gs2d", "gs3d", "plenoxels"):
        module = importlib.import_module(eps[name])
        assert BACKBONES.config(name) is module.CONFIG is module.BACKBONE.Config


def test_old_style_plugin_still_loads_and_warns(reg):
    with pytest.warns(PluginDeprecationWarning, match=r"backbone plugin '_old_bb' \(oldbb_cfg:OldConfig "
                      r"\[arcsem-test-oldbb\]\) declares its Config in the entry-point group arcsem.backbone_configs, "
                      r"read only until arcsem 0.3: define CONFIG \(and BACKBONE\)"):
        config = reg.config("_old_bb")
    assert config.__name__ == "OldConfig" and "oldbb.a" not in sys.modules
    with pytest.warns(PluginDeprecationWarning, match=r"backbone plugin '_old_bb' \(oldbb.a \[arcsem-test-oldbb\]\) "
                      r"registers its class with @register when imported, read only until arcsem 0.3"):
        cls = reg.get("_old_bb")
    assert cls.Config is config and cls.name == "_old_bb"
    assert reg.build({"name": "_old_bb", "value": 1}).cfg.value == 1.0
    with pytest.warns(PluginDeprecationWarning, match=r"'_older_bb' .*registers its class with @register"):
        assert reg.config("_older_bb") is config  # decorator only: its class's Config


@pytest.mark.parametrize("name,error", [
    ("_bare_bb", r"backbone '_bare_bb' \(barebb\): the module has no Config: define CONFIG = <its Config dataclass>"),
    ("_empty_bb", r"backbone '_empty_bb' \(emptybb\): the module defines neither BACKBONE \(the class\) nor CONFIG"),
    ("_mismatch_bb", r"backbone '_mismatch_bb' \(mismatchbb\): NewBackbone.Config is not CONFIG \(Other\)"),
])
def test_a_module_without_its_config_is_a_one_line_error_naming_the_plugin(reg, name, error):
    with pytest.raises(PluginError, match=error) as err:
        reg.get(name)
    assert "\n" not in str(err.value)
    if name != "_mismatch_bb":  # (reading the Config alone does not import the class, so cannot compare them)
        with pytest.raises(PluginError, match=error):
            reg.config(name)


def test_schemas_store_every_backbone_config_and_skip_a_broken_one(reg):
    from arcsem import schemas

    class Store:
        def __init__(self):
            self.nodes: dict = {}

        def store(self, group, name, node):
            self.nodes[(group, name)] = node

    cs = Store()
    with pytest.warns(UserWarning) as caught:
        schemas._store_backbone_schemas(cs)
    messages = [str(w.message) for w in caught if not issubclass(w.category, DeprecationWarning)]
    assert any(m.startswith("arcsem: backbone config _bare_bb does not load: ") and "has no Config" in m
               for m in messages), messages
    assert any(m.startswith("arcsem: backbone config _empty_bb does not load: ") for m in messages), messages
    assert {("backbone", f"{n}_schema") for n in ("_new_bb", "_old_bb", "gs2d", "plenoxels")} <= set(cs.nodes)
    assert ("backbone", "_bare_bb_schema") not in cs.nodes
    schema = cs.nodes[("backbone", "_new_bb_schema")]
    assert schema().name == "_new_bb" and schema().value == 0.5
