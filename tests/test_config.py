"""The Hydra config tree: every option of every group composes; the app runs on a composed config."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml
from conftest import CONF, missing_defaults, write_transforms_scene
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf

from arcsem import app
from arcsem.data import KINDS, reader_options
from arcsem.errors import PluginError
from arcsem.plugins import BACKBONES
from arcsem.registry import validate_config
from arcsem.stages import STAGES

DEFAULT_GROUPS = {next(iter(e)) for e in yaml.safe_load((CONF / "config.yaml").read_text())["defaults"]
                  if isinstance(e, dict)}
OPTIONS = sorted((d.name, f.stem) for d in CONF.iterdir() if d.is_dir() and not d.name.startswith("_")
                 and d.name != "tuning" for f in d.glob("*.yaml"))  # tuning: chosen by train x backbone (below)
LAUNCHERS = {"basic": "BasicLauncher", "joblib": "JoblibLauncher", "submitit_local": "LocalLauncher",
             "submitit_slurm": "SlurmLauncher"}


def compose_with(*overrides: str, hydra_cfg: bool = False):
    with initialize_config_module("arcsem.conf", version_base="1.3"):
        return compose("config", overrides=[*missing_defaults(overrides), *overrides],
                       return_hydra_config=hydra_cfg)


def test_default_config_composes():
    missing = missing_defaults()
    assert not missing, f"conf/config.yaml defaults without a file: {missing}"
    cfg = compose_with()
    assert cfg.stage in STAGES and cfg.seed == 0


@pytest.mark.parametrize("group,option", OPTIONS, ids=[f"{g}={o}" for g, o in OPTIONS])
def test_every_option_composes(group, option):
    override = f"{group}={option}" if group in DEFAULT_GROUPS else f"+{group}={option}"
    cfg = compose_with(override)
    assert OmegaConf.to_container(cfg, resolve=False)  # no interpolation errors in the structure
    if group == "dataset":
        assert cfg.dataset.kind in KINDS
        reader_options(cfg.dataset)
    if group == "experiment":
        assert cfg.stage in STAGES


@pytest.mark.parametrize("option", sorted(o for g, o in OPTIONS if g == "backbone"))
def test_backbone_configs_validate_against_plugin(option):
    cfg = OmegaConf.to_container(compose_with(f"backbone={option}").backbone, resolve=True)
    name = cfg.pop("name")
    try:
        cls = BACKBONES.get(name)
    except PluginError as exc:
        pytest.skip(f"backbone '{name}' does not load yet: {exc}")
    validate_config(cls.Config, cfg, where=f"backbone '{name}'")


@pytest.mark.parametrize("launcher", sorted(LAUNCHERS))
def test_launchers(launcher):
    cfg = compose_with(f"hydra/launcher={launcher}", hydra_cfg=True)
    assert cfg.hydra.launcher._target_.endswith(LAUNCHERS[launcher])


def test_app_run_check_stage(tmp_path):
    scene = write_transforms_scene(tmp_path / "scene", n=3, w=24, h=16)
    name = next((n for n in ("gs3d", "gs2d", "plenoxels") if _loads(n)), None)
    if name is None:
        pytest.skip("no in-tree backbone loads yet")
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", f"backbone={name}", "stage=check",
                       "seed=7")
    metrics = app.run(cfg, run_dir=tmp_path / "run")
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert saved == json.loads(json.dumps(metrics))
    assert saved["seed"] == 7 and saved["backbone"] == name and saved["stage"] == "check"
    assert re.fullmatch(r"[0-9a-f]{40}|unknown", saved["git_revision"])
    assert saved["dataset"]["train_views"] == 3 and saved["dataset"]["image_size"] == [24, 16]
    assert saved["backbone_origin"].startswith(f"arcsem.backbones.{name}") and saved["primitives"] > 0
    assert {"load_scene_s", "check_s", "total_s"} <= set(saved["timings"])
    written = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert written["dataset"]["path"] == str(scene.parent) and written["seed"] == 7
    left = sorted(p.name for p in (tmp_path / "run").iterdir())
    assert left == [".arcsem.lock", "config.yaml", "metrics.json"]  # no tmp file, no owner note left behind


def test_app_dispatches_stages(tmp_path, monkeypatch):
    import arcsem.colorize
    import arcsem.train

    scene = write_transforms_scene(tmp_path / "scene", n=2)
    calls = []

    def stage1(cfg, sc, run_dir):
        calls.append(("gray", len(sc.train), Path(run_dir)))
        return {"psnr": 30.5, "lpips": float("nan"), "lpips_weights": "missing: test", "timings": {"train_s": 1.5}}

    def stage2(cfg, sc, run_dir):
        calls.append(("color", len(sc.train), Path(run_dir)))
        return {"psnr": 25.0}

    monkeypatch.setattr(arcsem.train, "run_stage1", stage1, raising=False)
    monkeypatch.setattr(arcsem.colorize, "run_stage2", stage2, raising=False)
    import cv2
    import numpy as np

    colour = np.zeros((12, 16, 3), np.uint8)  # the scene's 16x12 images
    colour[..., 0] = 200  # a colour reference for view_01 (stage=all checks the references before stage 1)
    cv2.imwrite(str(tmp_path / "view_01.png"), colour)
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=all",
                       f"colorize.references={tmp_path / 'view_01.png'}",  # 16x12 px: too small for TCM/CCM
                       "colorize.losses.tcm.weight=0", "colorize.losses.ccm.weight=0")
    m = app.run(cfg, run_dir=tmp_path / "r")
    assert calls == [("gray", 2, tmp_path / "r"), ("color", 2, tmp_path / "r")]
    assert m["psnr"] == 25.0 and m["stages"]["gray"]["psnr"] == 30.5 and m["lpips_weights"] == "missing: test"
    assert m["timings"]["gray.train_s"] == 1.5 and "color_s" in m["timings"]
    monkeypatch.delattr(arcsem.train, "run_stage1")
    with pytest.raises(PluginError, match="stage 'gray' needs arcsem.train.run_stage1"):
        app.run(compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=gray"),
                run_dir=tmp_path / "r2")


def test_write_json_atomic(tmp_path):
    import numpy as np
    import torch

    from arcsem.files import write_json_atomic

    write_json_atomic(tmp_path / "a" / "m.json", {"x": torch.tensor([1.5, 2.0]), "y": np.float32(0.5),
                                                       "z": float("nan"), "p": tmp_path})
    data = json.loads((tmp_path / "a" / "m.json").read_text())
    assert data["x"] == [1.5, 2.0] and data["y"] == 0.5 and np.isnan(data["z"]) and data["p"] == str(tmp_path)
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["m.json"]


def _loads(name: str) -> bool:
    try:
        BACKBONES.get(name)
        return True
    except PluginError:
        return False


def test_every_tuning_file_is_a_train_preset_for_a_backbone():
    """conf/tuning/<train>_<backbone>.yaml is picked by the defaults list; a stray name would never be used."""
    trains = {o for g, o in OPTIONS if g == "train"}
    backbones = {o for g, o in OPTIONS if g == "backbone"}
    for f in (CONF / "tuning").glob("*.yaml"):
        train, _, backbone = f.stem.partition("_")
        assert train in trains and (backbone in backbones or backbone == "gaussians"), f.name


def test_loss_keys_override_without_plus():
    """A loss's documented keys (its Config's, not all in the presets' YAML) override as written: the CLI
    passes ``train.losses.<loss>.<key>=v`` as ``++...`` (add or override); the loss validates the key itself."""
    from arcsem.cli.main import loss_overrides

    args = ["stage=gray", "train.losses.dssim.impl=torch", "colorize.losses.tcm.weight=2", "train.losses.l1=null",
            "+train.losses.l2.weight=1", "train.steps=5", "train.losses.dssim.impl=torch,cpp"]
    got = loss_overrides(args)
    assert got == ["stage=gray", "++train.losses.dssim.impl=torch", "++colorize.losses.tcm.weight=2",
                   "train.losses.l1=null", "+train.losses.l2.weight=1", "train.steps=5",
                   "++train.losses.dssim.impl=torch,cpp"]
    with pytest.raises(Exception, match="impl"):  # Hydra's struct mode: what the rewrite avoids
        compose_with("train.losses.dssim.impl=torch")
    cfg = compose_with(*loss_overrides(["train.losses.dssim.impl=torch", "train.losses.l1.masked=true"]))
    assert cfg.train.losses.dssim.impl == "torch" and cfg.train.losses.dssim.weight == 0.2
    assert cfg.train.losses.l1.masked is True and cfg.train.losses.l1.weight == 0.8


def test_quick_gaussian_schedule_scales_with_train_steps():
    """The quick preset's schedule is a fraction of the run: 1500 steps give the tuned values, 300 steps the same
    shape (the opacity resets at 60 and 120, not on the last step, which left 10 dB held-out), 4500 steps densify
    every 75 (every 25 there doubled the primitives and lost 6.6 dB held-out); a schedule written by hand that resets
    in the run's last tenth is warned about."""
    from arcsem.registry import plain
    from arcsem.train.gray_stage import late_reset_warning

    keys = ("sh_increase_every", "densify_from", "densify_until", "densify_every", "opacity_reset_every",
            "lr_position_max_steps")
    for steps, want, starts in ((1500, (75, 30, 750, 25, 300, 1500), (360, 150)),
                                (300, (15, 30, 150, 25, 60, 300), (72, 30)),  # the cadence stays at 25 ...
                                (4500, (225, 30, 2250, 75, 900, 4500), (1080, 450))):  # ... and grows past 1500
        cfg = compose_with("experiment=demo", f"train.steps={steps}")
        assert tuple(cfg.backbone[k] for k in keys) == want
        losses = plain(cfg.train.losses)
        assert (losses["normal_consistency"]["start_step"], losses["distortion"]["start_step"]) == starts
        assert late_reset_warning(cfg) is None
    assert compose_with("experiment=demo", "backbone=gs3d", "train.steps=300").backbone.opacity_reset_every == 60
    by_hand = compose_with("experiment=demo", "train.steps=300", "backbone.densify_until=1000",
                           "backbone.opacity_reset_every=100")
    assert "last opacity reset is at step 300 of 300" in late_reset_warning(by_hand)
    fine = compose_with("experiment=demo", "train.steps=300", "backbone.densify_until=1000",
                        "backbone.opacity_reset_every=130")
    assert late_reset_warning(fine) is None  # resets at 130 and 260: 40 steps to recover
