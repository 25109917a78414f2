"""Stage 2 end to end on the analytic ellipsoid with a tiny 2DGS: frozen geometry, outputs, metrics, caches."""
import warnings

import pytest
import torch
from omegaconf import OmegaConf

from arcsem.colorize.analytic import analytic_scene
from arcsem.colorize.config import ColorizeConfig
from arcsem.colorize.stage2 import find_stage1
from arcsem.errors import DataError


def test_missing_stage1_is_a_clear_error(tmp_path):
    cfg = OmegaConf.create({"cache_dir": str(tmp_path / "cache")})
    with pytest.raises(DataError, match="no stage-1 checkpoint"):
        find_stage1(cfg, ColorizeConfig(), tmp_path)


@pytest.mark.slow
def test_stage2_end_to_end(tmp_path, monkeypatch):
    from arcsem.colorize import run_stage2
    from arcsem.train import load_checkpoint, run_stage1

    monkeypatch.setenv("ARCSEM_OFFLINE", "1")
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    warnings.simplefilter("ignore")
    torch.manual_seed(0)
    scene = analytic_scene(8, 2, 32, 24)
    ev = {"lpips": False, "video": False, "renders": False}
    cfg = OmegaConf.create({
        "backbone": {"name": "gs2d", "random_init_points": 300}, "act": {"enabled": True, "mode": "rgb"},
        "seed": 0, "device": "cpu", "cache_dir": str(tmp_path / "cache"),
        "train": {"steps": 3, "progress": False, "checkpoint_every": 0, "eval": ev},
        "colorize": {"steps": 4, "progress": False, "tcm_downscale": 1, "ccm_downscale": 4, "checkpoint_every": 0,
                     "eval": ev, "features": "vgg16"}})
    run = tmp_path / "run"
    run_stage1(cfg, scene, run)
    before = load_checkpoint(run / "checkpoints" / "last.pt")["model"]
    r = run_stage2(cfg, scene, run)
    s2 = r["stage2"]
    # the extractor is recorded as used when a guided loss trained: the validation keeps TCM/CCM only where they act
    # (with the background's own target, the analytic scene may leave them nothing)
    used = "vgg16-random" if {"tcm", "ccm"} & set(s2["losses"]) else "unused"
    assert r["features"] == used and s2["features"] == used
    assert s2["feature_extractor"]["tcm_space"] == "features"
    assert s2["steps"] == 4
    for part in ("train_nonref", "train_ref", "test"):
        assert {"psnr", "ssim", "psnr_masked"} <= set(s2[part]) and s2[part]["psnr"] > 0
    assert sorted(p.stem for p in (run / "colored").glob("*.png")) == sorted(scene.train.names)
    assert (run / "colored_model.ply").is_file() and (run / "colorize" / "views.csv").is_file()
    import pandas as pd

    hist = pd.read_csv(run / "colorize" / "train_history.csv")  # stage 2's loss per logged step (1 and the last)
    assert hist["step"].tolist() == [1, 4] and hist["loss"].notna().all() and "reference_l1" in hist.columns
    assert s2["post_renders"]["reused"] >= len(scene.train) + len(scene.test)  # metrics and PNGs: one render a view
    assert s2["pseudo"]["cache_hit"] is False and 0.5 < s2["pseudo"]["coverage"] <= 1
    # held-out colour renders beside the grey ones, with their true colour; the pseudo-colour target's parts
    held = run / "colorize" / "renders" / "test"
    assert sorted(p.name for p in held.glob("*.png")) == sorted(
        f"{n}{s}.png" for n in scene.test.names for s in ("", "_gt"))
    v = s2["validation"]  # each reference held out in turn chose the settings
    assert s2["pseudo"]["shading"]["mode"] == v["shading"]
    assert ({"nodes", "confident", "filled"} <= set(s2["pseudo"]["surface"])) if v["surface"] == "fill" else (
        "surface" not in s2["pseudo"])
    assert v["references"] >= 2 and set(v["target_mse"]) == {
        f"{a}/{b}/{c}" for a in ("fill", "off") for b in ("auto", "off") for c in ("grey", "off")}
    assert v["target_mse"][f"{v['surface']}/{v['shading']}/{v['prior']}"] == min(v["target_mse"].values())
    assert ("prior" in s2["pseudo"]) == (v["prior"] == "grey")  # the specimen pixels nothing else reaches
    prior = s2["pseudo"].get("prior", {"filled_px": 0, "filled": 0.0})
    assert prior["filled_px"] >= 0 and 0.0 <= prior["filled"] <= 1.0  # a share of the specimen pixels
    assert {"guidance", "target", "keep"} <= set(v["tcm"]) and sorted(s2["losses"]) == sorted(
        ["pseudo_color", "reference_l1"] + [k for k in ("ccm", "tcm") if v[k]["keep"]])
    if v["tcm"]["keep"] or v["ccm"]["keep"]:  # guarded matches also tested for agreement across the views
        dropped = s2["feature_extractor"]["agreement_dropped"]
        assert set(dropped) == {"ccm", "tcm0", "tcm1"} and all(0 <= x <= 1 for x in dropped.values())
    after = load_checkpoint(run / "colorize" / "checkpoints" / "last.pt")["model"]
    for k, v in before.items():  # geometry frozen, colour changed, no ACT in stage 2
        if k.startswith("act."):
            assert k not in after
        elif "sh" in k or "f_dc" in k or "feature" in k:
            continue
        else:
            torch.testing.assert_close(after[k], v, msg=k)
    assert any(not torch.equal(after[k], before[k]) for k in after if "sh" in k or "f_dc" in k or "feature" in k)
    assert "match_check" not in s2["feature_extractor"]  # with references held out, the validation decides
    bg = s2["pseudo"]["background"]  # the references' background colour as a line of the grey, for the others
    assert bg["pixels"] > 0 and len(bg["a"]) == len(bg["b"]) == 3
    # a rerun reuses the pseudo-colours and guidance from the cache and the finished checkpoint
    r2 = run_stage2(cfg, scene, run)
    assert r2["stage2"]["pseudo"]["cache_hit"] is True
    # one reference: its halves choose the surface spread and the prior; the match check against the
    # pseudo-colours decides TCM and CCM
    cfg.colorize.references, cfg.colorize.stage1 = "one", str(run)
    one = run_stage2(cfg, scene, tmp_path / "one")["stage2"]
    check, v1 = one["feature_extractor"]["match_check"], one["validation"]
    assert v1["references"] == 1 and v1["split"] == "halves" and set(check) == {"tcm", "ccm"}
    assert v1["target_mse"][f"{v1['surface']}/{v1['prior']}"] == min(v1["target_mse"].values()) and len(
        v1["target_mse"]) == 4
    assert ("prior" in one["pseudo"]) == (v1["prior"] == "grey") and ("surface" in one["pseudo"]) == (
        v1["surface"] == "fill")
    assert sorted(one["losses"]) == sorted(["pseudo_color", "reference_l1"] + [k for k in check if check[k]["keep"]])
    assert all(c["keep"] == (c["cells"] > 0 and c["match"] < c["guess"]) for c in check.values())


@pytest.mark.slow
@pytest.mark.parametrize("features", ["daisy", "learned"])
def test_stage2_with_features_that_need_no_weights(tmp_path, monkeypatch, features):
    from arcsem.colorize import run_stage2
    from arcsem.train import run_stage1

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    warnings.simplefilter("ignore")
    torch.manual_seed(0)
    scene = analytic_scene(8, 2, 64, 48)
    ev = {"lpips": False, "video": False, "renders": False}
    cfg = OmegaConf.create({
        "backbone": {"name": "gs2d", "random_init_points": 300}, "act": {"enabled": True, "mode": "rgb"},
        "seed": 0, "device": "cpu", "cache_dir": str(tmp_path / "cache"),
        "train": {"steps": 3, "progress": False, "checkpoint_every": 0, "eval": ev},
        "colorize": {"steps": 3, "progress": False, "tcm_downscale": 1, "ccm_downscale": 8, "checkpoint_every": 0,
                     "eval": ev, "features": features, "depth": "dataset", "references": "one",
                     "guard": {"check": False}}})  # TCM/CCM kept whatever the match check says: the features' path
    run = tmp_path / "run"
    run_stage1(cfg, scene, run)
    s2 = run_stage2(cfg, scene, run)["stage2"]
    fx = s2["feature_extractor"]
    assert s2["features"] == features and fx["name"] == features and fx["tcm_space"] == "color"
    test = s2["test"]
    assert 0 < test["coverage"] < 1 and test["psnr_uncovered"] > 0 and test["psnr_covered"] > 0
    assert 0 < s2["train_nonref"]["coverage"] < 1
    guides = sorted((tmp_path / "cache" / "colorize").glob("guide_*.npz"))
    assert len(guides) == len(scene.train)
    if features == "learned":
        assert fx["training"]["cache_hit"] is False and len(list((tmp_path / "cache" / "colorize" / "features")
                                                                 .glob("learned_*.pt"))) == 1
    s2b = run_stage2(cfg, scene, tmp_path / "run")["stage2"]  # again: model and guidance from the cache
    if features == "learned":
        assert s2b["feature_extractor"]["training"]["cache_hit"] is True
    assert sorted((tmp_path / "cache" / "colorize").glob("guide_*.npz")) == guides
