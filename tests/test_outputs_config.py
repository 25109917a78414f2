"""The ``mesh`` and ``render`` blocks of conf/config.yaml repeat their dataclasses' defaults exactly."""
from __future__ import annotations

import dataclasses

import pytest
import yaml
from conftest import CONF

from arcsem.export.render import RenderConfig, render_config
from arcsem.mesh import MeshConfig, mesh_config


@pytest.mark.parametrize("key,cls,parse", [("mesh", MeshConfig, mesh_config), ("render", RenderConfig, render_config)])
def test_yaml_block_equals_dataclass_defaults(key, cls, parse):
    block = yaml.safe_load((CONF / "config.yaml").read_text())[key]
    assert parse(block) == cls()
    assert set(block) == {f.name for f in dataclasses.fields(cls)}


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
