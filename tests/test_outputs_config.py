"""The ``mesh`` and ``render`` blocks: their defaults live in their dataclasses only (the schemas in Hydra's
ConfigStore), and a composed config has every key, settable without ``+``."""
from __future__ import annotations

import dataclasses

import pytest
import yaml
from conftest import CONF

from arcsem.export.render import RenderConfig, render_config
from arcsem.mesh import MeshConfig, mesh_config


@pytest.mark.parametrize("key,cls,parse", [("mesh", MeshConfig, mesh_config), ("render", RenderConfig, render_config)])
def test_composed_block_equals_dataclass_defaults(key, cls, parse):
    from test_config import compose_with

    assert key not in yaml.safe_load((CONF / "config.yaml").read_text())  # one home for each default
    block = compose_with()[key]
    assert parse(block) == cls()
    assert set(block) == {f.name for f in dataclasses.fields(cls)}
    first = dataclasses.fields(cls)[0]
    value = {"enabled": False, "run": "elsewhere"}[first.name]
    assert compose_with(f"{key}.{first.name}={str(value).lower()}")[key][first.name] == value  # no `+` needed


def test_bad_values_name_the_key():
    from arcsem.errors import ConfigError

    with pytest.raises(ConfigError, match="mesh"):
        mesh_config({"voxel_size": -1})
    with pytest.raises(ConfigError, match="mesh"):
        mesh_config({"voxels": 3})
    with pytest.raises(ConfigError, match="render"):
        render_config({"fps": 0})
    with pytest.raises(ConfigError, match="elevation"):
        render_config({"elevation": 120})
