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
    for conv in ("3dgs", "skimage"):
        assert metrics.ssim(a, a, convention=conv) == pytest.approx(1.0)
    # constant images, scikit-image (reflected borders): contrast/structure terms are 1, luminance
    # (2xy + C1) / (x^2 + y^2 + C1) with C1 = 1e-4, at every pixel
    x, y = np.full((16, 16, 3), 0.5), np.full((16, 16, 3), 0.4)
    assert metrics.ssim(x, y, convention="skimage") == pytest.approx((0.4 + 1e-4) / (0.41 + 1e-4), rel=1e-9)
    # 3DGS (zero padding, every pixel in the mean): in the interior the same value; a border pixel sees a window
    # partly outside the image, where zeros pull the means down (so the image mean differs from the interior)
    inner = np.zeros((16, 16), bool)
    inner[5:-5, 5:-5] = True
    assert metrics.ssim(x, y, inner, convention="3dgs") == pytest.approx((0.4 + 1e-4) / (0.41 + 1e-4), rel=1e-9)
    assert metrics.ssim(x, y, convention="3dgs") != pytest.approx((0.4 + 1e-4) / (0.41 + 1e-4), rel=1e-4)


def _ssim_zero_padded(a, b):
    """An independent reference of the 3DGS convention: scipy's separable correlation with zeros outside."""
    from scipy.ndimage import correlate1d

    x = np.arange(11) - 5.0
    g = np.exp(-x**2 / (2 * 1.5**2))
    g /= g.sum()

    def blur(img):
        return correlate1d(correlate1d(img, g, axis=0, mode="constant"), g, axis=1, mode="constant")
    mu_a, mu_b = blur(a), blur(b)
    va, vb, cov = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2, blur(a * b) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    return ((2 * mu_a * mu_b + c1) * (2 * cov + c2) / ((mu_a**2 + mu_b**2 + c1) * (va + vb + c2))).mean()


def test_ssim_conventions_match_their_references(pair):
    a, b = pair
    assert metrics.ssim(a, b, convention="3dgs") == pytest.approx(_ssim_zero_padded(a, b), rel=1e-12)
    ref = structural_similarity(a, b, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                use_sample_covariance=False)
    assert metrics.ssim(a, b, convention="skimage") == pytest.approx(ref, rel=1e-12)
    mask = np.zeros(a.shape[:2], bool)
    mask[5:20, 10:30] = True
    _, smap = structural_similarity(a, b, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                    use_sample_covariance=False, full=True)
    assert metrics.ssim(a, b, mask, convention="skimage") == pytest.approx(smap[5:20, 10:30].mean(), rel=1e-12)
    assert metrics.ssim(a, b, mask) != pytest.approx(metrics.ssim(a, b), rel=1e-6)
    with pytest.raises(ValueError, match="convention must be one of 3dgs, skimage"):
        metrics.ssim(a, b, convention="matlab")


def test_3dgs_convention_scores_the_render_as_an_8_bit_file():
    gt = np.full((16, 16, 3), 100 / 255)
    pred = gt + 0.4 / 255  # rounds back to the ground truth's 8-bit value
    assert metrics.image_metrics(pred, gt, with_lpips=False)["psnr"] == math.inf
    assert metrics.image_metrics(pred, gt, with_lpips=False, convention="skimage")["psnr"] == pytest.approx(
        -10 * math.log10((0.4 / 255) ** 2))
    np.testing.assert_array_equal(metrics.quantise(np.array([[[0.0, 0.5, 1.2]]])), [[[0.0, 128 / 255, 1.0]]])


def test_lpips_missing_weights_is_nan_with_reason(pair, tmp_path, monkeypatch):
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setenv("ARCSEM_OFFLINE", "1")
    monkeypatch.setattr(metrics, "_LPIPS_CACHE", {})
    value, status = metrics.lpips(*pair)
    assert math.isnan(value)
    assert status.startswith("missing: alexnet-owt-7be5be79.pth not in") and str(tmp_path) in status
    out = metrics.image_metrics(*pair)  # the 3DGS convention: LPIPS with VGG16
    assert math.isnan(out["lpips"]) and out["lpips_weights"].startswith("missing: vgg16-397923af.pth not in")
    assert out["psnr"] > 20


# conv layers of torchvision's `features` (the classifiers are not used by LPIPS): index -> weight shape
ALEX_CONVS = {0: (64, 3, 11, 11), 3: (192, 64, 5, 5), 6: (384, 192, 3, 3), 8: (256, 384, 3, 3), 10: (256, 256, 3, 3)}
VGG_CONVS = dict(zip((0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28),
                     [(64, 3), (64, 64), (128, 64), (128, 128), (256, 128), (256, 256), (256, 256), (512, 256),
                      (512, 512), (512, 512), (512, 512), (512, 512), (512, 512)]))


@pytest.mark.parametrize("net,convs,last", [("alex", ALEX_CONVS, ("slice5", "10")),
                                            ("vgg", {i: (*s, 3, 3) for i, s in VGG_CONVS.items()}, ("slice5", "28"))])
def test_lpips_loads_hub_checkpoint(pair, tmp_path, monkeypatch, net, convs, last):
    """With a checkpoint in the hub cache the network's features are exactly its weights."""
    g = torch.Generator().manual_seed(0)
    sd = {}
    for i, shape in convs.items():
        sd[f"features.{i}.weight"] = torch.randn(shape, generator=g) * 0.05
        sd[f"features.{i}.bias"] = torch.randn(shape[0], generator=g) * 0.05
    (tmp_path / "hub" / "checkpoints").mkdir(parents=True)
    torch.save(sd, tmp_path / "hub" / "checkpoints" / metrics.LPIPS_FILES[net])
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    monkeypatch.setattr(metrics, "_LPIPS_CACHE", {})
    model, status = metrics.lpips_model(net=net)
    assert status.endswith(metrics.LPIPS_FILES[net])
    torch.testing.assert_close(model.net.slice1[0].weight, sd["features.0.weight"])
    torch.testing.assert_close(getattr(getattr(model.net, last[0]), last[1]).bias, sd[f"features.{last[1]}.bias"])
    a, b = pair
    assert metrics.lpips(a, a, net=net)[0] == pytest.approx(0.0, abs=1e-7)
    d, _ = metrics.lpips(a, b, net=net)
    assert d > 0 and math.isfinite(d)
    mask = np.zeros(a.shape[:2], bool)
    mask[10:30, 10:40] = True
    assert metrics.lpips(a, b, mask, net=net)[0] == pytest.approx(
        metrics.lpips(a * mask[..., None], b * mask[..., None], net=net)[0])


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
