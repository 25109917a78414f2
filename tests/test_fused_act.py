"""The fused SH colours with the per-image affine colour transform (ACT) against the PyTorch path (eval_sh, then
ACT.apply): values and gradients in float64."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from arcsem.backbones.gaussians.fused import load_extension
from arcsem.backbones.gaussians.model import GaussianModel

from arcsem.act import ACT
from tests.test_fused import _scene, assert_rel


@pytest.fixture(scope="module", autouse=True)
def extension():
    assert load_extension() is not None, "the fused C++ kernels did not build"


@pytest.mark.parametrize("mode", ["rgb", "scalar"])
@pytest.mark.parametrize("model,degree", [("pinhole", 3), ("orthographic", 1), ("pinhole", 0)])
def test_fused_sh_colors_with_act_match_torch(mode, model, degree):
    """clamp(w * max(SH + 0.5, 0) + b, 0, 1) for a training view (its own w, b) and a novel view (the mean w, b):
    colours clamped at 0 and at 1 by the ACT and at 0 by the SH clamp (the novel view's mean bias lets the latter
    through); gradients to the means, coefficients, ACT weights and biases equal the PyTorch path's within 1e-12
    (the ACT's summed over the splats in a fixed order)."""
    g = torch.Generator().manual_seed(degree + 7)
    n = 1500  # two chunks of the kernel: the ACT sums of both are added
    params = {"means": torch.randn(n, 3, generator=g, dtype=torch.float64), "quats": torch.randn(n, 4, dtype=torch.float64),
              "log_scales": torch.zeros(n, 3, dtype=torch.float64), "opacity_logits": torch.zeros(n, dtype=torch.float64),
              "sh_dc": torch.randn(n, 1, 3, generator=g, dtype=torch.float64),
              "sh_rest": torch.randn(n, 15, 3, generator=g, dtype=torch.float64) * 0.5}
    _, cams = _scene("gs3d", model, 0)
    cams = replace(cams, image_ids=torch.tensor([1, -1]))
    res = {}
    for impl in ("torch", "cpp"):
        torch.manual_seed(0)
        act = ACT(3, mode=mode).double()
        with torch.no_grad():
            act.weight.mul_(torch.tensor([0.7, 1.3, 0.9], dtype=torch.float64)[:, None])
            act.bias.add_(torch.tensor([0.2, -0.25, 0.35], dtype=torch.float64)[:, None])
        m = GaussianModel(params).double()
        rgb = m.colors(cams, degree=degree, impl=impl, act=act)
        cot = torch.rand(rgb.shape, generator=torch.Generator().manual_seed(9), dtype=torch.float64) - 0.3
        wrt = [m.means, m.sh_dc, m.sh_rest, act.weight, act.bias]
        res[impl] = rgb.detach(), torch.autograd.grad((rgb * cot).sum(), wrt, allow_unused=True)
    ref = res["torch"][0]
    assert (ref == 0).any() and (ref == 1).any() and ((ref > 0) & (ref < 1)).any(), "colours clamped both ways"
    assert_rel(res["cpp"][0], ref, 1e-12, "colours")
    for name, a, b in zip(("means", "sh_dc", "sh_rest", "act.weight", "act.bias"), res["cpp"][1], res["torch"][1]):
        if b is None:
            assert a is None or not a.any(), f"{name}: the PyTorch path has no gradient"
        else:
            assert a is not None and b.abs().max() > 0, name
            assert_rel(a, b, 1e-12, f"d/d{name}")

