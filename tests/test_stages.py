"""The stage registry (:mod:`arcsem.stages`) and the run's config validated once (:mod:`arcsem.runconfig`).

* a stage registered in a test (no other file edited) runs through ``app.run`` with ``stage=<name>``: its checks,
  its warnings, its result in ``metrics.json``, and its failures where the other stages' are;
* one small ``stage=all`` run validates each config group of the run once (the stage-1 checkpoint's stored config
  once more: another input) and calls the backbone's own checks once;
* every default and rule has one home: the 2DGS low-pass sigma (and its > 0 bound, at the boundary), the feature
  extractor names.
"""
from __future__ import annotations

import ast
import json
import sys
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from conftest import write_transforms_scene
from test_config import compose_with
from torch import nn

from arcsem import app, registry
from arcsem.errors import ConfigError, DataError, PluginError
from arcsem.plugins import BACKBONES, Backbone
from arcsem.runconfig import RunConfig
from arcsem.stages import STAGES, Stage, resolve

ROOT = Path(__file__).resolve().parent.parent


# ------------------------------------------------------------------ a stage added from a test
@pytest.fixture
def toy(monkeypatch):
    """Register the stage ``toy`` (unregistered afterwards); returns the record of what it was called with."""
    seen: dict = {"config": [], "scene": [], "run": [], "fail_config": False, "fail_run": False}

    def check_config(rc):
        seen["config"].append(rc)
        if seen["fail_config"]:
            raise ConfigError("toy.size: must be > 0, got -1")

    def check_scene(rc, scene, stage, run_dir):
        seen["scene"].append((stage, len(scene.train)))
        return ["toy: a warning about the scene"]

    def run(rc, scene, run_dir):
        seen["run"].append(rc)
        if seen["fail_run"]:
            raise DataError("toy: the scene is not a toy")
        (Path(run_dir) / "toy.txt").write_text("played")
        return {"toy": {"views": len(scene.train), "seed": int(rc.cfg.seed)}}

    STAGES.register(Stage("toy", plan=("toy",), check_config=(check_config,), check_scene=(check_scene,), run=run))
    yield seen
    STAGES.unregister("toy")


def _toy_cfg(tmp_path):
    scene = write_transforms_scene(tmp_path / "scene", n=3, w=24, h=16)
    return compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=toy")


def test_a_stage_registered_in_a_test_runs_through_app_run(tmp_path, toy):
    metrics = app.run(_toy_cfg(tmp_path), run_dir=tmp_path / "run")
    assert metrics["status"] == "complete" and metrics["completed_stages"] == ["toy"]
    assert metrics["stages"]["toy"] == {"toy": {"views": 3, "seed": 0}}
    assert "toy: a warning about the scene" in metrics["warnings"]
    assert toy["scene"] == [("toy", 3)]
    # the checks and the stage get the one run config: each group validated at most once, there
    assert len(toy["config"]) == 1 and toy["run"] == toy["config"] and isinstance(toy["run"][0], RunConfig)
    assert (tmp_path / "run" / "toy.txt").read_text() == "played"
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["stages"]["toy"]["toy"]["views"] == 3


def test_a_registered_stage_check_stops_the_run_before_anything_is_written(tmp_path, toy):
    toy["fail_config"] = True
    with pytest.raises(ConfigError, match=r"toy.size: must be > 0"):
        app.run(_toy_cfg(tmp_path), run_dir=tmp_path / "run")
    assert toy["run"] == [] and not (tmp_path / "run" / "metrics.json").exists()


@pytest.mark.parametrize("stage", ["gray", "color", "all"])
@pytest.mark.parametrize("key, value, message", [
    ("impl", "bogus", r"mesh.impl: 'bogus' is not one of auto, torch, cpp"),
    ("formats", ["ply", "obj2"], r"mesh.formats: unknown format"),
])
def test_a_bad_mesh_key_stops_the_run_before_training(stage, key, value, message):
    """Both stages end with a mesh; its config was read only there, after training (found with mesh.impl=bogus: the
    error came after stage 1's training and evaluation)."""
    from arcsem.stages import check_config

    cfg = compose_with(f"stage={stage}")
    cfg.mesh[key] = value
    with pytest.raises(ConfigError, match=message):
        check_config(RunConfig(cfg), stage)


def test_mesh_impl_cpp_without_the_kernel_stops_the_run_before_training(monkeypatch):
    from arcsem import cext
    from arcsem.stages import check_config

    monkeypatch.setattr(cext, "load", lambda ext, verbose=False: None)  # as where no C++ toolchain is found
    cfg = compose_with("stage=gray")
    cfg.mesh.impl = "cpp"
    with pytest.raises(ConfigError, match=r"mesh.impl: 'cpp' \(fused C\+\+ TSDF fusion\) needs a C\+\+ toolchain"):
        check_config(RunConfig(cfg), "gray")
    cfg.mesh.impl = "auto"
    check_config(RunConfig(cfg), "gray")  # auto falls back to the PyTorch path


def test_a_registered_stage_failure_is_recorded_like_the_others(tmp_path, toy):
    toy["fail_run"] = True
    with pytest.raises(DataError, match="not a toy"):
        app.run(_toy_cfg(tmp_path), run_dir=tmp_path / "run")
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["status"] == "failed" and metrics["failed_stage"] == "toy" and "not a toy" in metrics["error"]


def test_unknown_stage_lists_the_registered_ones(tmp_path, toy):
    cfg = compose_with("stage=tyo")
    with pytest.raises(ConfigError, match=r"stage: unknown stage 'tyo'; available: gray, color, all, check, render, toy"):
        app.run(cfg, run_dir=tmp_path / "run")


def test_registry_refuses_a_second_stage_and_unknown_plans():
    with pytest.raises(PluginError, match="registered twice"):
        STAGES.register(Stage("gray", plan=("gray",)))
    with pytest.raises(PluginError, match="unknown stage"):
        STAGES.register(Stage("both", plan=("gray", "paint")))
    assert "both" not in STAGES
    with pytest.raises(PluginError, match=r"stage 'x' needs arcsem.nowhere.run, which is not available"):
        resolve("arcsem.nowhere:run", "x")
    assert STAGES.get("all").runs() == ("gray", "color") and STAGES.get("check").runs() == ("check",)


def test_preflight_imports_neither_the_app_nor_the_stages():
    """The cycle app <-> preflight and the upward import preflight -> app are gone."""
    tree = ast.parse((ROOT / "arcsem" / "preflight.py").read_text())
    names = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not names & {"app", "stages", "arcsem.app", "arcsem.stages"}, names


# ------------------------------------------------------------------ validated once
CHECKS: Counter = Counter()


@BACKBONES.register("_checked")
class Checked(Backbone):
    """A grey plane with a learnable colour whose own run checks count their calls."""

    @dataclass
    class Config:
        lr_color: float = 1e-2

    def __init__(self, cfg, scene=None, **runtime):
        super().__init__(cfg, scene)
        self.color = nn.Parameter(torch.full((3,), 0.5))

    @classmethod
    def check_config(cls, cfg, device):
        assert isinstance(cfg, cls.Config) and device == "cpu"
        CHECKS["config"] += 1

    @classmethod
    def check_scene(cls, cfg, scene):
        assert isinstance(cfg, cls.Config) and len(scene.train) == 3
        CHECKS["scene"] += 1

    def render(self, cams, **kw):
        ones = torch.ones(len(cams), cams.height, cams.width, 1, device=self.color.device)
        return {"rgb": ones * self.color, "alpha": ones, "depth": ones * 4.0}

    def param_groups(self, stage):
        return {"color": [self.color]}


def _count_validations(monkeypatch) -> Counter:
    """Count :func:`arcsem.registry.validate_config` calls by ``where``, under every name a module holds it by."""
    calls: Counter = Counter()
    original = registry.validate_config

    def counting(schema, values, where):
        calls[where] += 1
        return original(schema, values, where)

    for module in list(sys.modules.values()):
        if getattr(module, "validate_config", None) is original:
            monkeypatch.setattr(module, "validate_config", counting)
    return calls


def test_a_whole_run_validates_each_group_once(tmp_path, monkeypatch):
    scene = write_transforms_scene(tmp_path / "scene", n=3, w=24, h=16)
    cv2.imwrite(str(tmp_path / "view_01.png"), np.full((16, 24, 3), (0, 0, 200), np.uint8))
    cfg = compose_with("dataset=transforms", f"dataset.path={scene.parent}", "stage=all", "act=none",
                       "backbone=gs2d", "train.width=null", "train.steps=3", "train.eval.lpips=false",
                       "train.progress=false", "train.eval.video=false", "colorize.steps=2", "colorize.progress=false",
                       "colorize.eval.lpips=false", "colorize.eval.video=false", "colorize.losses.tcm.weight=0",
                       "colorize.losses.ccm.weight=0", f"colorize.references={tmp_path / 'view_01.png'}",
                       f"cache_dir={tmp_path / 'cache'}")
    cfg.backbone = {"name": "_checked"}
    cfg.train.losses = {"l1": {"weight": 1.0}}
    CHECKS.clear()
    calls = _count_validations(monkeypatch)
    metrics = app.run(cfg, run_dir=tmp_path / "run")
    assert metrics["status"] == "complete" and metrics["completed_stages"] == ["gray", "color"]
    t = metrics["timings"]  # each stage's phases, inside its wall time (where a job's time goes)
    gray = ("prepare", "train", "evaluate", "export", "products")
    color = ("prepare", "guidance", "pseudo", "train", "evaluate", "outputs", "products")
    assert {f"gray.{p}_s" for p in gray} | {f"color.{p}_s" for p in color} <= set(t), sorted(t)
    for stage, parts in (("gray", gray), ("color", color)):
        assert 0 < sum(t[f"{stage}.{p}_s"] for p in parts) <= t[f"{stage}_s"]
    # once for the run; train, act and the backbone once more for the stage-1 checkpoint's own stored config,
    # which stage 2 rebuilds its model from (another input, read from disk)
    # the dataset once (its reader options, by the preflight; the scene is loaded from that checked spec)
    assert {k: calls[k] for k in ("dataset", "train", "act", "backbone '_checked'", "colorize", "mesh", "render")} == {
        "dataset": 1, "train": 2, "act": 2, "backbone '_checked'": 2, "colorize": 1, "mesh": 1, "render": 0}, calls
    # each loss term once, though the checks and the stages build the loss sets four times
    assert {k: n for k, n in calls.items() if k.startswith("loss ")} == {
        "loss 'l1'": 1, "loss 'dssim'": 1, "loss 'reference_l1'": 1, "loss 'pseudo_color'": 1}, calls
    assert CHECKS == {"config": 1, "scene": 1}  # listed by both stages, called once


def test_backbone_checks_default_to_nothing():
    assert Backbone.check_config(Backbone.Config(), "cpu") is None
    assert Backbone.check_scene(Backbone.Config(), None) is None


# ------------------------------------------------------------------ one home for each default and rule
def test_2dgs_lowpass_sigma_has_one_default_and_the_kernels_bound():
    """The official 1/sqrt(2) px, written once; the kernels take 1/sigma^2, so 0 is refused and any sigma above
    it accepted (the bound was >= 0 in the Config and > 0 in the backbone)."""
    import inspect

    from arcsem.backbones.gaussians import fused, gsplat_bridge
    from arcsem.backbones.gaussians.config import LOWPASS_SIGMA
    from arcsem.backbones.gs2d import render
    from arcsem.backbones.gs2d.config import GSPLAT_LOWPASS_SIGMA, GS2DConfig

    assert LOWPASS_SIGMA == 2**-0.5 == GS2DConfig().lowpass_sigma == render.LOWPASS_SIGMA == GSPLAT_LOWPASS_SIGMA
    for func in (fused.composite2d, fused.footprint_bin_2dgs, gsplat_bridge.render_gsplat_2dgs, render.render_2dgs):
        assert inspect.signature(func).parameters["lowpass_sigma"].default == LOWPASS_SIGMA, func
    with pytest.raises(ConfigError, match=r"lowpass_sigma: must be > 0.0, got 0.0"):
        registry.validate_config(GS2DConfig, {"lowpass_sigma": 0.0}, where="backbone 'gs2d'")
    assert registry.validate_config(GS2DConfig, {"lowpass_sigma": 1e-6}, where="backbone 'gs2d'").lowpass_sigma == 1e-6


def test_feature_extractor_names_have_one_home():
    import dataclasses

    from arcsem.colorize.features import FEATURES
    from arcsem.configs import EXTRACTORS, ColorizeConfig
    from arcsem.report import collect

    choices = {f.name: f for f in dataclasses.fields(ColorizeConfig)}["features"].metadata["checks"]["choices"]
    assert FEATURES == choices == ("auto", *EXTRACTORS)
    assert set(collect._EXTRACTORS) == set(FEATURES)


def test_auto_features_resolved_once_by_the_check(tmp_path, monkeypatch):
    """``colorize.features=auto`` is resolved (and announced) by the stage-2 check and kept on the run config,
    which stage 2 builds its extractor from (the build no longer resolves it again)."""
    from arcsem.colorize import color_stage
    from arcsem.colorize.features import base as fbase

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))  # no ImageNet weights: auto -> the default below
    monkeypatch.setattr(fbase, "DEFAULT_WITHOUT_IMAGENET", "daisy")
    rc = RunConfig(compose_with("colorize.features=auto"))
    assert rc.features is None
    color_stage.check_config(rc)
    assert rc.features == "daisy"
