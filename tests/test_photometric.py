"""Photometric losses: values against references (scikit-image SSIM, hand-computed L1/L2), gradients."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from arcsem.cameras import Cameras
from arcsem.imageops import gaussian_window, ssim_map
from arcsem.plugins import LOSSES, Batch
from arcsem.train.losses import build_losses

pytestmark = pytest.mark.usefixtures("one_thread")  # tiny tensors: one torch thread


def _batch(images, masks=None):
    C = images.shape[0]
    cams = Cameras(torch.eye(4).repeat(C, 1, 1), torch.eye(3).repeat(C, 1, 1), images.shape[2], images.shape[1])
    return Batch(cameras=cams, images=images, indices=torch.arange(C), masks=masks)


def test_gaussian_window_matches_formula():
    g = gaussian_window(11, 1.5, torch.float64)
    x = np.arange(11) - 5.0
    ref = np.exp(-x**2 / (2 * 1.5**2))
    np.testing.assert_allclose(g.numpy(), ref / ref.sum(), rtol=1e-12)


def test_ssim_matches_scikit_image_in_the_interior():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(1, 40, 48, 3, generator=g, dtype=torch.float64)
    b = (a + 0.1 * torch.randn(1, 40, 48, 3, generator=g, dtype=torch.float64)).clamp(0, 1)
    ours = ssim_map(a, b)[0].numpy()
    _, ref = structural_similarity(a[0].numpy(), b[0].numpy(), gaussian_weights=True, sigma=1.5,
                                   use_sample_covariance=False, data_range=1.0, channel_axis=-1, full=True)
    # borders differ only by padding (zeros here, reflection in skimage): compare 5 px inside
    np.testing.assert_allclose(ours[5:-5, 5:-5], ref[5:-5, 5:-5], atol=1e-10)


def test_dssim_is_zero_for_equal_images_and_differentiable():
    dssim = LOSSES.build({"name": "dssim"})
    g = torch.Generator().manual_seed(1)
    img = torch.rand(2, 12, 14, 3, generator=g, dtype=torch.float64)
    assert float(dssim({"rgb": img}, _batch(img), 0)) == pytest.approx(0.0, abs=1e-12)
    x = torch.rand(1, 7, 8, 3, generator=g, dtype=torch.float64, requires_grad=True)
    y = torch.rand(1, 7, 8, 3, generator=g, dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda t: dssim({"rgb": t}, _batch(y), 0), (x,), eps=1e-6, atol=1e-6)


def test_l1_l2_values_and_masks():
    pred = torch.zeros(1, 2, 2, 3)
    tgt = torch.tensor([0.1, 0.2, 0.3, 0.4]).reshape(1, 2, 2, 1).expand(1, 2, 2, 3)
    mask = torch.tensor([[1.0, 0.0], [0.0, 1.0]]).reshape(1, 2, 2, 1)
    l1, l2 = LOSSES.build({"name": "l1"}), LOSSES.build({"name": "l2"})
    assert float(l1({"rgb": pred}, _batch(tgt), 0)) == pytest.approx(0.25)  # mean(.1,.2,.3,.4)
    assert float(l2({"rgb": pred}, _batch(tgt), 0)) == pytest.approx(0.075)  # mean(.01,.04,.09,.16)
    l1m = LOSSES.build({"name": "l1", "masked": True})
    assert float(l1m({"rgb": pred}, _batch(tgt, mask), 0)) == pytest.approx(0.25)  # mean(.1,.4)
    # ray batches [R,3]
    rays = Batch(cameras=_batch(tgt).cameras, images=tgt.reshape(4, 3), indices=torch.zeros(4, dtype=torch.long))
    assert float(l1({"rgb": torch.zeros(4, 3)}, rays, 0)) == pytest.approx(0.25)


def test_weighted_total_is_the_paper_mix():
    g = torch.Generator().manual_seed(2)
    pred, tgt = torch.rand(1, 16, 16, 3, generator=g), torch.rand(1, 16, 16, 3, generator=g)
    losses = build_losses({"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}, {"rgb"})
    total, terms = losses({"rgb": pred}, _batch(tgt), 0)
    l1 = (pred - tgt).abs().mean()
    dssim = 1 - ssim_map(pred, tgt).mean()
    torch.testing.assert_close(total, 0.8 * l1 + 0.2 * dssim)
    assert set(terms) == {"l1", "dssim"}


def test_float64_blur_equals_the_grouped_convolution_with_zero_padding():
    import torch.nn.functional as F

    from arcsem.imageops import _blur

    g = gaussian_window(11, 1.5, torch.float64)
    x = torch.rand(2, 3, 17, 23, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    gx, gy = g.view(1, 1, 1, 11).expand(3, 1, 1, 11), g.view(1, 1, 11, 1).expand(3, 1, 11, 1)
    ref = F.conv2d(F.conv2d(x, gx, padding=(0, 5), groups=3), gy, padding=(5, 0), groups=3)
    torch.testing.assert_close(_blur(x, g), ref, atol=1e-14, rtol=0)   # borders included
    torch.testing.assert_close(_blur(x.float(), g.float()), ref.float(), atol=1e-6, rtol=0)  # the conv2d path
