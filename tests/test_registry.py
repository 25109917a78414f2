"""Registry: decorator registration, lazy entry-point discovery, Config validation messages."""
from __future__ import annotations

import sys
import types
from dataclasses import dataclass, fields
from importlib import metadata

import pytest

from arcsem.errors import ConfigError, PluginError
from arcsem.plugins import BACKBONES, LOSSES
from arcsem.registry import Registry, validate_config

GROUP = "arcsem.test_widgets"
PLUGIN_SRC = '''
from dataclasses import dataclass
import fake_holder

fake_holder.LOADED.append("{name}")


@fake_holder.REG.register("{name}")
class Widget:
    @dataclass
    class Config:
        lr: float = 0.1
        steps: int = 10

    def __init__(self, cfg, **runtime):
        self.cfg, self.runtime = cfg, runtime
'''


@pytest.fixture
def reg(tmp_path, monkeypatch):
    """A fresh registry whose entry-point group holds fake plugins a, b (modules on disk), 'broken'
    (raises on import) and 'silent' (imports but registers nothing)."""
    registry = Registry("widget", GROUP)
    holder = types.ModuleType("fake_holder")
    holder.REG, holder.LOADED = registry, []
    monkeypatch.setitem(sys.modules, "fake_holder", holder)
    for name in ("a", "b"):
        (tmp_path / f"fake_widget_{name}.py").write_text(PLUGIN_SRC.format(name=name))
    (tmp_path / "fake_widget_broken.py").write_text("raise ImportError('no such dependency: foo')\n")
    (tmp_path / "fake_widget_silent.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for mod in [m for m in sys.modules if m.startswith("fake_widget_")]:
        monkeypatch.delitem(sys.modules, mod)
    eps = [metadata.EntryPoint(n, f"fake_widget_{n}", GROUP) for n in ("a", "b", "broken", "silent")]
    real = metadata.entry_points

    def fake_entry_points(**kw):
        return metadata.EntryPoints(eps) if kw.get("group") == GROUP else real(**kw)

    monkeypatch.setattr(metadata, "entry_points", fake_entry_points)
    return registry


def test_lazy_loading_loads_only_the_requested_entry_point(reg):
    assert reg.names() == ["a", "b", "broken", "silent"]
    assert sys.modules["fake_holder"].LOADED == []  # listing names imports nothing
    cls = reg.get("b")
    assert cls.name == "b" and sys.modules["fake_holder"].LOADED == ["b"]
    assert "fake_widget_a" not in sys.modules and "fake_widget_broken" not in sys.modules
    assert reg.get("b") is cls and sys.modules["fake_holder"].LOADED == ["b"]  # cached, not re-imported
    assert reg.registered("b") is cls and reg.registered("a") is None  # what is in memory; loads nothing
    assert "fake_widget_a" not in sys.modules


def test_build_validates_and_passes_runtime(reg):
    obj = reg.build({"name": "a", "lr": 2, "steps": 5}, scene="S")
    assert (obj.cfg.lr, obj.cfg.steps, obj.runtime) == (2.0, 5, {"scene": "S"})
    assert isinstance(obj.cfg.lr, float)
    assert reg.build({"name": "a"}).cfg.steps == 10  # defaults from the Config dataclass


def test_typo_key_names_it_and_lists_valid_keys(reg):
    with pytest.raises(ConfigError, match=r"widget 'a': unknown key\(s\) 'stpes'; valid keys: lr, steps"):
        reg.build({"name": "a", "stpes": 3})


def test_wrong_type_names_the_key(reg):
    with pytest.raises(ConfigError, match=r"widget 'a': bad value for key 'steps'"):
        reg.build({"name": "a", "steps": "many"})


def test_unknown_plugin_lists_what_exists(reg):
    with pytest.raises(PluginError, match=r"unknown widget 'gizmo'; available: a, b, broken, silent"):
        reg.get("gizmo")
    with pytest.raises(ConfigError, match=r"widget config has no 'name'; available: a, b"):
        reg.build({"lr": 1.0})


def test_broken_and_silent_entry_points(reg):
    with pytest.raises(PluginError, match=r"widget 'broken' \(fake_widget_broken\) failed to load: .*foo"):
        reg.get("broken")
    with pytest.raises(PluginError, match=r"arcsem.test_widgets:silent = fake_widget_silent did not register"):
        reg.get("silent")


def test_duplicate_registration_raises():
    reg = Registry("widget", "arcsem.nothing")

    def make(module: str) -> type:
        return type("Same", (), {"__module__": module})

    first = reg.register("x")(make("pkg_one"))
    assert reg.register("x")(make("pkg_one")).name == "x"  # the same class re-executed: allowed
    with pytest.raises(PluginError, match=r"widget 'x' registered twice"):
        reg.register("x")(make("pkg_two"))
    with pytest.raises(PluginError, match="registered twice"):
        reg.register("x")(type("Other", (), {}))
    assert first.name == "x"


def test_validate_config_plain_dataclass():
    @dataclass
    class Cfg:
        a: int = 1
        b: str = "x"

    assert validate_config(Cfg, {"a": 3}, where="t") == Cfg(a=3, b="x")
    with pytest.raises(ConfigError, match=r"t: unknown key\(s\) 'c', 'd'; valid keys: a, b"):
        validate_config(Cfg, {"c": 1, "d": 2}, where="t")
    assert [f.name for f in fields(Cfg)] == ["a", "b"]


def test_in_tree_plugins_declared_as_entry_points():
    assert {"gs2d", "gs3d", "plenoxels"} <= set(BACKBONES.names())
    assert {"l1", "dssim", "tv"} <= set(LOSSES.names())
    assert BACKBONES.group == "arcsem.backbones" and LOSSES.group == "arcsem.losses"
