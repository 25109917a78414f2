"""ACT: hand-computed transforms, novel-view mean, clamping, both modes, gradients, configs."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from arcsem.act import ACT


def make(mode: str) -> ACT:
    torch.manual_seed(0)
    act = ACT(3, mode=mode, init_noise=0.0)
    k = 3 if mode == "rgb" else 1
    with torch.no_grad():
        act.weight.copy_(torch.tensor([[0.5, 1.0, 2.0], [1.0, 1.0, 1.0], [2.0, 0.0, 0.5]])[:, :k])
        act.bias.copy_(torch.tensor([[0.1, 0.0, -0.1], [0.0, 0.2, 0.0], [0.05, 0.1, 0.0]])[:, :k])
    return act


def test_rgb_mode_hand_values_and_clamp():
    act = make("rgb")
    colors = torch.tensor([[[0.2, 0.4, 0.6]], [[0.2, 0.4, 0.6]]])  # [C=2, N=1, 3]
    out = act.apply(colors, torch.tensor([0, 2]))
    # image 0: [0.5*0.2+0.1, 1*0.4+0, min(2*0.6-0.1, 1)] ; image 2: [2*0.2+0.05, 0*0.4+0.1, 0.5*0.6]
    torch.testing.assert_close(out, torch.tensor([[[0.2, 0.4, 1.0]], [[0.45, 0.1, 0.3]]]))


def test_novel_view_uses_mean_transform():
    act = make("rgb")
    colors = torch.full((1, 4, 3), 0.3)
    out = act.apply(colors, torch.tensor([-1]))
    W = torch.tensor([3.5, 2.0, 3.5]) / 3
    b = torch.tensor([0.15, 0.3, -0.1]) / 3
    torch.testing.assert_close(out, (W * 0.3 + b).clamp(0, 1).expand(1, 4, 3))


def test_scalar_mode_broadcasts_over_rgb_and_has_two_params_per_image():
    act = make("scalar")
    assert act.weight.shape == (3, 1) and act.bias.shape == (3, 1)
    out = act.apply(torch.tensor([[0.2, 0.4, 0.6]]), torch.tensor([0]))  # [R=1, 3]
    torch.testing.assert_close(out, torch.tensor([[0.2, 0.3, 0.4]]))  # 0.5 c + 0.1


def test_arbitrary_trailing_shapes_ray_batches():
    act = make("rgb")
    colors = torch.rand(5, 7, 3)  # [R, S, 3]
    ids = torch.tensor([0, 1, 2, -1, 1])
    out = act.apply(colors, ids)
    for r in range(5):
        torch.testing.assert_close(out[r], act.apply(colors[r : r + 1], ids[r : r + 1])[0])
    img = torch.rand(2, 4, 5, 3)  # whole images [C, H, W, 3]
    assert act.apply(img, torch.tensor([1, 1])).shape == img.shape


def test_identity_init_with_small_noise():
    torch.manual_seed(1)
    act = ACT(50, "rgb")
    assert (act.weight - 1).abs().max() < 6e-3 and act.bias.abs().max() < 6e-3
    assert 5e-4 < (act.weight - 1).std() < 2e-3  # N(0, 1e-3)
    c = torch.rand(50, 10, 3) * 0.9 + 0.05
    torch.testing.assert_close(act.apply(c, torch.arange(50)), c, atol=6e-3, rtol=0)


def test_gradients_reach_only_the_used_images():
    act = make("rgb")
    colors = torch.full((2, 3, 3), 0.3, requires_grad=True)
    act.apply(colors, torch.tensor([1, 1])).sum().backward()
    assert act.weight.grad[1].abs().sum() > 0 and act.weight.grad[[0, 2]].abs().sum() == 0
    torch.testing.assert_close(act.weight.grad[1], torch.full((3,), 0.3 * 6))  # 2 cams x 3 prims x colour
    torch.testing.assert_close(act.bias.grad[1], torch.full((3,), 6.0))
    assert colors.grad is not None


def test_bad_input():
    act = make("rgb")
    with pytest.raises(IndexError):
        act.apply(torch.rand(1, 2, 3), torch.tensor([3]))
    with pytest.raises(ValueError):
        act.apply(torch.rand(2, 2, 3), torch.tensor([0]))
    with pytest.raises(ValueError):
        ACT(2, mode="affine")
    with pytest.raises(ValueError, match="at least one training image"):
        ACT(0)


def test_act_configs():
    root = Path(__file__).resolve().parents[1] / "conf" / "act"
    paper, code, none = (OmegaConf.load(root / f"{n}.yaml") for n in ("paper", "code", "none"))
    assert (paper.enabled, paper.mode, paper.lr) == (True, "rgb", 1e-4)
    assert (code.enabled, code.mode, code.lr) == (True, "scalar", 1e-3)
    assert none.enabled is False
