"""TCM/CCM feature extractors: DAISY, the scene-trained CNN, correspondences, `auto`, loss spaces, coverage."""
import logging
import math

import pytest
import torch

from arcsem.colorize.analytic import analytic_scene
from arcsem.colorize.coverage import coverage_masks, split_psnr
from arcsem.colorize.features import ColourSpace, SceneContext, build_extractor, resolve_features, tcm_space
from arcsem.colorize.features import base as fbase
from arcsem.colorize.features.correspond import correspondences, downscale_geometry
from arcsem.colorize.features.daisy import DaisyFeatures, cell_centres
from arcsem.colorize.features.learned import LearnedConfig, info_nce, learned_extractor, sample_features
from arcsem.errors import ConfigError


def _texture(h=64, w=96, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.nn.functional.interpolate(torch.rand(1, 1, h // 8, w // 8, generator=g), size=(h, w), mode="bicubic",
                                        align_corners=False)[0, 0].clamp(0, 1)
    return x[..., None].expand(h, w, 3)[None].contiguous()


def test_daisy_shapes_centres_and_exposure_invariance():
    img = _texture()
    d = DaisyFeatures()
    f4, f8 = d(img)
    assert f4.shape == (1, 200, 16, 24) and f8.shape == (1, 200, 8, 12)
    xs, ys = cell_centres(64, 96, 4)
    assert xs[:2].tolist() == [1.5, 5.5] and len(ys) == 16
    # an affine exposure change (contrast 0.6, brightness +0.2) leaves the normalised histograms nearly equal
    g4, _ = d(img * 0.6 + 0.2)
    cos = torch.nn.functional.cosine_similarity(f4, g4, dim=1)
    assert float(cos.mean()) > 0.97
    # a shift by one cell (4 px) shifts the descriptors by one cell, away from the borders
    s4, _ = d(torch.roll(img, 4, dims=2))
    inner = torch.nn.functional.cosine_similarity(f4[..., 4:-5], s4[..., 5:-4], dim=1)
    other = torch.nn.functional.cosine_similarity(f4[..., 4:-5], s4[..., 4:-5], dim=1)
    assert float(inner.mean()) > 0.99 and float(inner.mean()) > float(other.mean()) + 0.05


def test_correspondences_land_on_the_same_surface_point():
    sc = analytic_scene(8, 2, 48, 32)
    tr = sc.train
    pix = tr.masks[0].nonzero().flip(-1)  # (x, y)
    uv_a, uv_b, idx = correspondences(tr.cameras, tr.depths, tr.masks, 0, 1, pix)
    assert len(idx) > 0.3 * len(pix)  # the neighbouring view sees much of it
    pa = tr.cameras[0].unproject_points(uv_a[None].double().float(), tr.depths[0][pix[idx, 1], pix[idx, 0]][None])[0]
    xb, yb = uv_b[:, 0].long(), uv_b[:, 1].long()
    pb = tr.cameras[1].unproject_points(uv_b[None], tr.depths[1][yb, xb][None])[0]
    # the same point up to the pixel grid of view b (about one pixel: 0.05 units here)
    assert float((pa - pb).norm(dim=-1).median()) < 0.05
    # where view b sees another surface (its depth moved 5 units away) the depth test refuses every pixel
    flipped = tr.depths.clone()
    flipped[1] = torch.where(flipped[1] > 0, flipped[1] + 5.0, flipped[1])
    assert len(correspondences(tr.cameras, flipped, tr.masks, 0, 1, pix)[2]) == 0


def test_downscale_geometry_takes_cell_centres():
    d = torch.arange(64.0).reshape(1, 8, 8)
    dd, mm = downscale_geometry(d, d > 20, 4)
    assert dd.tolist() == [[[18.0, 22.0], [50.0, 54.0]]] and mm.tolist() == [[[False, True], [True, True]]]


def test_info_nce_and_sampling_hand_examples():
    f = torch.eye(4)
    assert float(info_nce(f, f, 0.1)) < 1e-3  # each row's positive is the only similar one
    assert float(info_nce(f, f.roll(1, 0), 0.1)) > 5.0  # every positive is a wrong row
    feat = torch.arange(12.0).reshape(1, 3, 4)  # one channel, 3 x 4 cells of stride 2
    uv = torch.tensor([[1.0, 1.0], [3.0, 1.0], [2.0, 3.0]])  # cell (0,0) centre, cell (0,1) centre, between
    assert sample_features(feat, uv, 2)[:, 0].tolist() == [0.0, 1.0, 4.5]


def _ctx(tmp_path, seed=0, sc=None):
    sc = sc or analytic_scene(8, 2, 48, 32)
    tr = sc.train
    return SceneContext(gray=tr.images, cameras=tr.cameras, masks=tr.masks, depths=lambda: tr.depths,
                        depth_key="gt", seed=seed, downscale=1, cache_dir=tmp_path)


def test_learned_features_train_deterministically_and_are_cached(tmp_path):
    cfg = LearnedConfig(steps=40, width=8, dim=16, points=64)
    a = learned_extractor(_ctx(tmp_path / "a"), cfg)
    b = learned_extractor(_ctx(tmp_path / "b"), cfg)
    assert a.info["cache_hit"] is False and a.info["loss_last"] < a.info["loss_first"]
    for pa, pb in zip(a.net.parameters(), b.net.parameters()):
        torch.testing.assert_close(pa, pb, rtol=0, atol=0)  # same seed, same model
    again = learned_extractor(_ctx(tmp_path / "a"), cfg)
    assert again.info["cache_hit"] is True and again.key() == a.key()
    assert learned_extractor(_ctx(tmp_path / "a", seed=1), cfg).key() != a.key()  # the key follows the inputs
    f4, f8 = a(_ctx(tmp_path).gray[:2])
    assert f4.shape == (2, 16, 8, 12) and f8.shape == (2, 16, 4, 6)


def test_auto_takes_vgg_with_imagenet_weights_else_the_measured_default(tmp_path, monkeypatch, caplog):
    """Without ImageNet weights `auto` takes the measured default, VGG16 with random weights (section 5 of
    benchmarks/results/features/README.md), and says so; with them, VGG16 with its ImageNet weights."""
    from arcsem.colorize.features import announce_features

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    assert fbase.DEFAULT_WITHOUT_IMAGENET == "vgg16"
    with caplog.at_level(logging.WARNING, logger="arcsem.colorize.features.base"):
        assert announce_features("auto") == "vgg16"
    assert "with random weights" in caplog.text and "ImageNet VGG16 weights found" not in caplog.text
    ckpt = tmp_path / "torch" / "hub" / "checkpoints"
    ckpt.mkdir(parents=True)
    (ckpt / "vgg16-397923af.pth").write_bytes(b"present")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="arcsem.colorize.features.base"):
        assert announce_features("auto") == "vgg16" and resolve_features("daisy") == "daisy"
    assert "ImageNet VGG16 weights found" in caplog.text and "random" not in caplog.text


def test_auto_choice_said_once_per_job(tmp_path, monkeypatch, caplog):
    """Two jobs in one process (a sequential sweep): each job's log says once what `auto` chose, from the
    config check; building the extractor in stage 2 does not say it again."""
    from test_config import compose_with

    from arcsem.stages import check_config

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.setattr(fbase, "DEFAULT_WITHOUT_IMAGENET", "daisy")  # builds without a scene
    cfg = compose_with("colorize.features=auto")
    for job in range(2):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="arcsem.colorize.features.base"):
            check_config(cfg, "all")
            assert build_extractor("auto").name == "daisy"
        said = [r.message for r in caplog.records if "colorize.features=auto" in r.message]
        assert len(said) == 1 and "use 'daisy' features" in said[0], (job, said)


def test_tcm_space_choices():
    d = DaisyFeatures()
    assert isinstance(tcm_space("auto", d), ColourSpace)
    with pytest.raises(ConfigError, match="tcm_space=features"):
        tcm_space("features", d)
    with pytest.raises(ConfigError, match="learned needs the scene"):
        build_extractor("learned", None)
    img = torch.arange(64.0).reshape(1, 8, 8, 1).expand(1, 8, 8, 3)
    c4, c8 = ColourSpace((4, 8))(img)
    assert c4.shape == (1, 3, 2, 2) and float(c4[0, 0, 0, 0]) == (0 + 1 + 2 + 3 + 8 + 9 + 10 + 11 + 16 + 17 + 18
                                                                   + 19 + 24 + 25 + 26 + 27) / 16
    assert float(c8[0, 1, 0, 0]) == 31.5


def test_split_psnr_and_coverage():
    gt = torch.zeros(2, 4, 4, 3)
    pred = gt.clone()
    pred[:, :2] += 0.1  # error 0.1 on the top half ...
    pred[:, 2:] += 0.01  # ... 0.01 on the bottom half
    masks = torch.ones(2, 4, 4, dtype=torch.bool)
    cov = torch.zeros(2, 4, 4, dtype=torch.bool)
    cov[:, 2:] = True
    r = split_psnr(pred, gt, masks, cov)
    assert r["psnr_covered"] == pytest.approx(40.0) and r["psnr_uncovered"] == pytest.approx(20.0)
    assert r["coverage"] == 0.5 and r["no_surface"] == 0.0 and r["uncovered_px"] == 16
    surface = torch.ones(2, 4, 4, dtype=torch.bool)
    surface[:, 0] = False  # the model has no surface on the top row: in neither part
    pred[:, 1] += 0.2  # the second row's error becomes 0.3, the top row's stays 0.1
    r = split_psnr(pred, gt, masks, cov, surface)
    assert r["psnr_uncovered"] == pytest.approx(-10 * math.log10(0.09)) and r["uncovered_px"] == 8
    assert r["coverage"] == pytest.approx(16 / 24) and r["no_surface"] == pytest.approx(0.25)
    sc = analytic_scene(8, 2, 48, 32)
    tr, te = sc.train, sc.test
    own = coverage_masks(tr.cameras[:1], tr.depths[:1], tr.masks[:1], tr.cameras[:1], tr.depths[:1], tr.masks[:1])
    assert torch.equal(own[0], tr.masks[0] & (tr.depths[0] > 0))  # a reference covers itself
    all_refs = coverage_masks(tr.cameras, tr.depths, tr.masks, te.cameras, te.depths, te.masks)
    one_ref = coverage_masks(tr.cameras[:1], tr.depths[:1], tr.masks[:1], te.cameras, te.depths, te.masks)
    assert int(one_ref.sum()) < int(all_refs.sum()) <= int(te.masks.sum())
