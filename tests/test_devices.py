"""The run's device decides where everything a stage trains with lives (arcsem/devices.py), checked without a GPU:
the stage-2 targets are moved to the ``meta`` device, every tensor they hold must then be there, and the stage-2
losses must run on a ``meta`` render (a tensor left on the CPU stops them, as the CUDA run stopped in TCM's VGG)."""
from __future__ import annotations

import dataclasses

import pytest
import torch
from torch import nn

from arcsem.cameras import Cameras
from arcsem.colorize.features import build_extractor, tcm_space
from arcsem.colorize.guidance import Guidance
from arcsem.colorize.references import References
from arcsem.colorize.targets import ColorTargetHook
from arcsem.devices import held_tensors, run_device, stray_tensors
from arcsem.plugins import LOSSES, Batch


def test_held_tensors_reach_modules_lists_dicts_and_dataclasses():
    @dataclasses.dataclass
    class Box:
        t: torch.Tensor
        items: list

    class Holder:
        def __init__(self):
            self.net = nn.Linear(2, 2)
            self.box = Box(torch.zeros(1), [{"deep": torch.ones(1)}, (torch.ones(2),)])
            self.fn = len

    h = Holder()
    paths = dict(held_tensors(h))
    assert {"net.weight", "net.bias", "box.t", "box.items.0.deep", "box.items.1.0"} <= set(paths)
    h.net.to("meta")
    assert sorted(p.split(":")[0] for p in stray_tensors(h, "meta")) == ["box.items.0.deep", "box.items.1.0", "box.t"]
    assert run_device({"device": "cuda:1"}) == torch.device("cuda:1") and run_device({}) == torch.device("cpu")


def _targets(features: str, space: str, n: int = 4, size: tuple[int, int] = (32, 48)):
    """A real stage-2 hook on ``n`` views of ``size`` px (view 0 the reference), as run_stage2 builds it."""
    g = torch.Generator().manual_seed(0)
    h, w = size
    gray = torch.rand(n, h, w, 1, generator=g).expand(n, h, w, 3).contiguous()
    refs = References(["v0"], torch.tensor([0]), torch.rand(1, h, w, 3, generator=g))
    extractor = build_extractor(features)
    loss_space = tcm_space(space, extractor)
    guidance = Guidance(extractor, loss_space, gray, [0], refs.images, tcm_downscale=1, ccm_downscale=8)
    for v in range(n):
        guidance.matches(v)
    pseudo, valid = torch.rand(n, h, w, 3, generator=g), torch.rand(n, h, w, generator=g) > 0.5
    return ColorTargetHook(refs, pseudo, valid, guidance, loss_space, tcm_downscale=1, ccm_downscale=8)


@pytest.mark.parametrize("features,space", [("vgg16", "auto"), ("vgg16", "color")])
def test_stage2_targets_and_losses_follow_the_run_device(features, space):
    hook = _targets(features, space)
    assert any(isinstance(t, torch.Tensor) for _, t in held_tensors(hook))
    hook.to("meta")
    assert stray_tensors(hook, "meta") == []
    cams = Cameras(torch.eye(4).expand(2, 4, 4), torch.eye(3).expand(2, 3, 3), 48, 32)
    batch = Batch(cameras=cams, images=torch.zeros(2, 32, 48, 3, device="meta"),
                  indices=torch.tensor([2, 0], device="meta"), views=(2, 0))
    batch = hook(batch)
    assert stray_tensors(batch.color, "meta") == []
    out = {"rgb": torch.zeros(2, 32, 48, 3, device="meta", requires_grad=True)}
    for name in ("pseudo_color", "tcm", "ccm", "reference_l1"):
        value = LOSSES.build({"name": name})(out, batch, 0)
        assert value.device.type == "meta" and value.shape == ()
