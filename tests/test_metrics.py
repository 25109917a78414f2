"""Metrics against hand-computed values and scikit-image; LPIPS never from random weights."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from arcsem import metrics


@pytest.fixture
def pair():
    rng = np.random.default_rng(0)
    a = rng.random((40, 48, 3))
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    return a, b


def test_psnr_constant_offset():
    gt = np.full((8, 8, 3), 0.3)
    assert metrics.psnr(gt + 0.1, gt) == pytest.approx(20.0)  # MSE 0.01 -> 20 dB
    assert metrics.psnr(torch.tensor(gt + 0.01), torch.tensor(gt)) == pytest.approx(40.0)
    assert metrics.psnr(gt, gt) == math.inf


def test_psnr_masked_uses_mask_pixels_only():
    gt = np.zeros((4, 4, 3))
    pred = gt.copy()
    pred[:2] = 0.2  # error 0.2 inside the mask
    pred[2:] = 0.9  # large error outside
    mask = np.zeros((4, 4), bool)
    mask[:2] = True
    assert metrics.psnr(pred, gt, mask) == pytest.approx(-10 * math.log10(0.04))  # 13.979 dB
    assert metrics.psnr(pred, gt, mask[..., None].astype(np.float32)) == pytest.approx(13.9794, abs=1e-4)


def test_ssim_hand_values(pair):
    a, _ = pair
    assert metrics.ssim(a, a) == pytest.approx(1.0)
    # constant images: contrast/structure terms are 1, luminance (2xy + C1) / (x^2 + y^2 + C1), C1 = 1e-4
    x, y = np.full((16, 16, 3), 0.5), np.full((16, 16, 3), 0.4)
    assert metrics.ssim(x, y) == pytest.approx((0.4 + 1e-4) / (0.41 + 1e-4), rel=1e-9)


def test_ssim_matches_skimage_settings(pair):
    a, b = pair
    ref = structural_similarity(a, b, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                use_sample_covariance=False)
    assert metrics.ssim(a, b) == pytest.approx(ref, rel=1e-12)
    mask = np.zeros(a.shape[:2], bool)
    mask[5:20, 10:30] = True
    _, smap = structural_similarity(a, b, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False, full=True)
    assert metrics.ssim(a, b, mask) == pytest.approx(smap[5:20, 10:30].mean(), rel=1e-12)
    assert metrics.ssim(a, b, mask) != pytest.approx(metrics.ssim(a, b), rel=1e-6)


def test_lpips_missing_weights_is_nan_with_reason(pair, tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setenv("ARCSEM_OFFLINE", "1")
    monkeypatch.setattr(metrics, "_LPIPS_CACHE", {})
    value, status = metrics.lpips(*pair)
    assert math.isnan(value)
    assert status.startswith("missing: alexnet-owt-7be5be79.pth not in") and str(tmp_path) in status
    out = metrics.image_metrics(*pair)
    assert math.isnan(out["lpips"]) and out["lpips_weights"] == status and out["psnr"] > 20


def test_lpips_loads_hub_checkpoint(pair, tmp_path, monkeypatch):
    """With a checkpoint in the hub cache the AlexNet features are exactly its weights."""
    g = torch.Generator().manual_seed(0)
    shapes = {0: (64, 3, 11, 11), 3: (192, 64, 5, 5), 6: (384, 192, 3, 3), 8: (256, 384, 3, 3), 10: (256, 256, 3, 3)}
    sd = {}  # the conv layers of torchvision's AlexNet `features` (the classifier is not used by LPIPS)
    for i, shape in shapes.items():
        sd[f"features.{i}.weight"] = torch.randn(shape, generator=g) * 0.05
        sd[f"features.{i}.bias"] = torch.randn(shape[0], generator=g) * 0.05
    (tmp_path / "hub" / "checkpoints").mkdir(parents=True)
    torch.save(sd, tmp_path / "hub" / "checkpoints" / metrics.ALEXNET_FILE)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setattr(metrics, "_LPIPS_CACHE", {})
    model, status = metrics.lpips_model()
    assert status.endswith(metrics.ALEXNET_FILE)
    torch.testing.assert_close(model.net.slice1[0].weight, sd["features.0.weight"])
    torch.testing.assert_close(getattr(model.net.slice5, "10").bias, sd["features.10.bias"])
    a, b = pair
    assert metrics.lpips(a, a)[0] == pytest.approx(0.0, abs=1e-7)
    d, _ = metrics.lpips(a, b)
    assert d > 0 and math.isfinite(d)
    mask = np.zeros(a.shape[:2], bool)
    mask[10:30, 10:40] = True
    assert metrics.lpips(a, b, mask)[0] == pytest.approx(metrics.lpips(a * mask[..., None], b * mask[..., None])[0])


def test_torchvision_workaround_defines_only_missing_schemas():
    import torch

    from arcsem.tvfix import MISSING_OP_SCHEMAS, ensure_torchvision_ops, import_torchvision

    tv = import_torchvision()
    assert tv.models.alexnet is not None
    for name in MISSING_OP_SCHEMAS:  # defined by torchvision's own _C or by the workaround
        torch._C._dispatch_find_schema_or_throw(f"torchvision::{name}", "")
    assert ensure_torchvision_ops() == []  # nothing defined twice


def test_hub_weight_lookup(tmp_path, monkeypatch):
    from arcsem import weights

    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setenv("ARCSEM_OFFLINE", "1")
    ckpt = tmp_path / "hub" / "checkpoints"
    ckpt.mkdir(parents=True)
    assert weights.hub_checkpoint_dir() == ckpt
    (ckpt / "empty.pth").write_bytes(b"")
    assert weights.find_hub_weights("empty.pth") is None  # an interrupted download is not a checkpoint
    torch.save({"w": torch.ones(2)}, ckpt / "mine.pth")
    assert weights.find_hub_weights("mine.pth") == ckpt / "mine.pth"
    sd, src = weights.load_state_dict_from_hub("https://example.org/models/mine.pth")  # cache first
    assert src == str(ckpt / "mine.pth") and torch.equal(sd["w"], torch.ones(2))
    sd, why = weights.load_state_dict_from_hub("unknown.pth")
    assert sd is None and why == f"unknown.pth not in {ckpt} and no known URL to download it"
    sd, why = weights.load_state_dict_from_hub("vgg16-397923af.pth")
    assert sd is None and "no network to fetch https://download.pytorch.org/models/vgg16-397923af.pth" in why
