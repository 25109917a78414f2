"""An external plugin (plugin_template/) is selected from the command line like an in-tree one.

Installing into the venv is too invasive for a test, so the template is "installed" by hand into a
temporary folder on PYTHONPATH: its package, its ``hydra_plugins`` search-path plugin, and a
``.dist-info`` whose ``entry_points.txt`` is generated from the template's own pyproject.toml.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from conftest import arcsem_command, missing_defaults, write_transforms_scene

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
TEMPLATE = Path(__file__).resolve().parent.parent / "plugin_template"


def install_by_hand(site: Path) -> None:
    """Copy the template's packages into ``site`` and write the dist-info importlib.metadata reads."""
    project = tomllib.loads((TEMPLATE / "pyproject.toml").read_text())["project"]
    shutil.copytree(TEMPLATE / "arcsem_plugin_template", site / "arcsem_plugin_template")
    shutil.copytree(TEMPLATE / "hydra_plugins", site / "hydra_plugins")
    dist = site / f"{project['name'].replace('-', '_')}-{project['version']}.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n")
    lines = []
    for group, eps in project["entry-points"].items():
        lines += [f"[{group}]", *(f"{name} = {value}" for name, value in eps.items()), ""]
    (dist / "entry_points.txt").write_text("\n".join(lines))


@pytest.fixture
def plugin_env(tmp_path):
    site = tmp_path / "site"
    site.mkdir()
    install_by_hand(site)
    env = {k: v for k, v in os.environ.items() if k not in ("ARCSEM_DEBUG", "HYDRA_FULL_ERROR")}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(site), env.get("PYTHONPATH")]))
    return env


def test_template_declares_a_backbone_entry_point():
    project = tomllib.loads((TEMPLATE / "pyproject.toml").read_text())["project"]
    assert project["entry-points"]["arcsem.backbones"] == {"constant": "arcsem_plugin_template.backbone"}
    cfg = yaml.safe_load((TEMPLATE / "arcsem_plugin_template/conf/backbone/constant.yaml").read_text())
    assert cfg == {"name": "constant"}


@pytest.mark.slow
def test_external_backbone_selected_from_command_line(tmp_path, plugin_env):
    scene = write_transforms_scene(tmp_path / "scene", n=2).parent
    overrides = ["backbone=constant", "+backbone.value=0.25", "dataset=transforms", f"dataset.path={scene}"]
    run_dir = tmp_path / "run"
    proc = subprocess.run([*arcsem_command(), "stage=check", f"hydra.run.dir={run_dir}",
                           *missing_defaults(overrides), *overrides],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path, env=plugin_env, check=False)
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["backbone"] == "constant"
    assert metrics["backbone_origin"] == "arcsem_plugin_template.backbone [arcsem-plugin-template]"
    assert metrics["primitives"] == 3  # one RGB parameter
    assert yaml.safe_load((run_dir / "config.yaml").read_text())["backbone"] == {"name": "constant", "value": 0.25}
    # the YAML came from the template's package through its SearchPathPlugin
    sources = yaml.safe_load((run_dir / ".hydra" / "hydra.yaml").read_text())["hydra"]["runtime"]["config_sources"]
    assert {"path": "arcsem_plugin_template.conf", "schema": "pkg",
            "provider": "arcsem-plugin-template"} in sources


@pytest.mark.slow
def test_arcsem_plugins_lists_external_backbone(plugin_env, tmp_path):
    exe = Path(sys.executable).with_name("arcsem-plugins")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "arcsem.cli.plugins"]
    proc = subprocess.run([*cmd, "--kind", "backbone"], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path, env=plugin_env, check=False)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    row = next(i for i, ln in enumerate(lines) if ln.startswith("backbone") and " constant " in ln)
    assert "arcsem_plugin_template.backbone [arcsem-plugin-template]" in lines[row]
    assert "provides: alpha, depth, rgb" in lines[row]
    assert lines[row + 1].strip() == "config: value=0.5, depth=1.0, lr=0.01"
    assert any("in-tree arcsem.backbones." in ln for ln in lines)  # in-tree ones listed the same way
