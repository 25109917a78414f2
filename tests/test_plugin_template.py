"""The plugin template works as its README says: ``pip install -e plugin_template`` (and a normal install), then
``arcsem backbone=constant ...`` trains stage 1 and colours in stage 2.

The slow test makes a throw-away virtual environment that sees this one's packages (a ``.pth`` file: no
download, no torch install), installs the template into it with pip, and runs arcsem there.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from conftest import write_transforms_scene

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
TEMPLATE = Path(__file__).resolve().parent.parent / "plugin_template"


def test_template_declares_its_two_entry_points():
    eps = tomllib.loads((TEMPLATE / "pyproject.toml").read_text())["project"]["entry-points"]
    assert eps == {"arcsem.backbones": {"constant": "arcsem_plugin_template"},  # CONFIG and BACKBONE: __init__.py
                   "arcsem.conf": {"arcsem-plugin-template": "arcsem_plugin_template.conf"}}
    cfg = yaml.safe_load((TEMPLATE / "arcsem_plugin_template/conf/backbone/constant.yaml").read_text())
    assert cfg == {"defaults": ["constant_schema", "_self_"], "name": "constant"}


def make_venv(path: Path) -> Path:
    """A virtual environment whose Python also sees this environment's site-packages; returns its python."""
    venv.create(path, with_pip=False)
    python = path / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             capture_output=True, text=True, check=True).stdout.strip()
    # addsitedir also runs that site's .pth files (arcsem's own editable install is one)
    (Path(purelib) / "_parent_env.pth").write_text(f"import site; site.addsitedir({sysconfig.get_paths()['purelib']!r})\n")
    return python


@pytest.mark.slow
@pytest.mark.parametrize("editable", [True, False], ids=["pip install -e", "pip install"])
def test_template_installs_and_trains_both_stages(tmp_path, editable):
    python = make_venv(tmp_path / "venv")
    src = TEMPLATE
    if not editable:  # a normal install builds from a copy (no build folders left in the checkout)
        import shutil

        src = Path(shutil.copytree(TEMPLATE, tmp_path / "template"))
    pip = [str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--no-index",
           *(["-e"] if editable else []), str(src)]
    subprocess.run(pip, check=True, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    scene = write_transforms_scene(tmp_path / "scene", n=3, w=24, h=16).parent
    cv2.imwrite(str(tmp_path / "view_01.png"), np.full((16, 24, 3), (0, 0, 200), np.uint8))  # red reference
    run_dir = tmp_path / "run"
    args = ["stage=all", "backbone=constant", "backbone.value=0.25", "act=none", "dataset=transforms",
            f"dataset.path={scene}", "train.width=null", "train.steps=5", "train.eval.lpips=false",
            "train.eval.video=false", "train.progress=false", "colorize.steps=3", "colorize.progress=false",
            "colorize.eval.lpips=false", "colorize.eval.video=false", "colorize.losses.tcm.weight=0",
            "colorize.losses.ccm.weight=0", f"colorize.references={tmp_path / 'view_01.png'}",
            f"cache_dir={tmp_path / 'cache'}", f"hydra.run.dir={run_dir}"]
    env = {k: v for k, v in os.environ.items() if k not in ("ARCSEM_DEBUG", "HYDRA_FULL_ERROR", "PYTHONPATH")}
    proc = subprocess.run([str(python), "-m", "arcsem.cli.main", *args], capture_output=True, text=True,
                          timeout=600, cwd=tmp_path, env=env, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["backbone"] == "constant" and metrics["completed_stages"] == ["gray", "color"]
    assert metrics["stage1"]["steps"] == 5 and metrics["stage2"]["steps"] == 3
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert config["backbone"] == {"value": 0.25, "depth": 1.0, "lr": 0.01, "name": "constant"}  # every key shown
    typo = subprocess.run([str(python), "-m", "arcsem.cli.main", "backbone=constant", "backbone.valeu=1",
                           "--cfg", "job"], capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env,
                          check=False)
    assert typo.returncode == 2 and "backbone.valeu: unknown key; valid keys: value, depth, lr" in typo.stderr
    listing = subprocess.run([str(python), "-m", "arcsem.cli.plugins", "--kind", "backbone"], capture_output=True,
                             text=True, timeout=300, cwd=tmp_path, env=env, check=True).stdout
    assert "arcsem_plugin_template [arcsem-plugin-template]" in listing
    assert "config: value=0.5, depth=1.0, lr=0.01" in listing
    sys.stdout.write(f"template ({'editable' if editable else 'normal'} install): {metrics['stage1']['steps']} + "
                     f"{metrics['stage2']['steps']} steps\n")
