"""The generic training loop on tiny test-only backbones (registered under names starting with '_').

``TinyImage`` renders one learned image for every camera (with ACT applied when given);
``TinyRays`` colours each ray by a learned linear function of its direction (a ray backbone).
"""
from __future__ import annotations

from dataclasses import dataclass

import pytest
import torch
from torch import nn
from trainer_util import L1_DSSIM, loop, tiny_scene

from arcsem.act import ACT
from arcsem.plugins import BACKBONES, LOSSES, Backbone, Loss
from arcsem.train.loop import train
from arcsem.train.losses import build_losses
from arcsem.train.sampling import RaySampler, ViewSampler, resize_split

pytestmark = pytest.mark.usefixtures("one_thread")


@BACKBONES.register("_tiny_rays")
class TinyRays(Backbone):
    """Ray backbone: ``rgb = sigmoid(A d + c)`` per ray direction ``d``."""

    provides = frozenset({"rgb", "alpha", "depth"})
    batch_mode = "rays"

    @dataclass
    class Config:
        lr_field: float = 0.05

    def __init__(self, cfg, scene=None, act=None):
        super().__init__(cfg)
        self.A = nn.Parameter(torch.zeros(3, 3))
        self.c = nn.Parameter(torch.zeros(3))
        self.seen: list[tuple] = []

    def render_rays(self, rays_o, rays_d, image_ids, **kw):
        self.seen.append((tuple(rays_o.shape), tuple(image_ids.shape)))
        rgb = torch.sigmoid(rays_d @ self.A.T + self.c)
        return {"rgb": rgb, "alpha": torch.ones_like(rgb[..., :1]), "depth": torch.ones_like(rgb[..., :1])}

    def render(self, cams, **kw):
        o, d = cams.rays()
        ids = cams.image_ids[:, None, None].expand(d.shape[:-1])
        out = self.render_rays(o.reshape(-1, 3), d.reshape(-1, 3), ids.reshape(-1))
        return {k: v.reshape(*d.shape[:-1], -1) for k, v in out.items()}

    def param_groups(self, stage):
        return {"field": [self.A, self.c]}


@LOSSES.register("_nan_at")
class NanAt(Loss):
    """Zero except at ``at_step`` where it is NaN."""

    @dataclass
    class Config:
        weight: float = 1.0
        start_step: int = 0
        at_step: int = 5

    def forward(self, out, batch, step):
        z = 0.0 * out["rgb"].mean()
        return z + float("nan") if step == self.cfg.at_step else z


@LOSSES.register("_nan_grad")
class NanGrad(Loss):
    """Finite value (0) with a NaN gradient: ``sqrt(|x - x|)``."""

    def forward(self, out, batch, step):
        return torch.sqrt((out["rgb"] - out["rgb"].detach()).abs()).mean()


@LOSSES.register("_needs_normal")
class NeedsNormal(Loss):
    requires = frozenset({"rgb", "normal"})

    def forward(self, out, batch, step):
        return out["normal"].mean()


@LOSSES.register("_pseudo_l1")
class PseudoL1(Loss):
    """L1 against ``batch.color.pseudo`` (a stage-2 target the batch hook fills)."""

    needs = frozenset({"color"})

    def forward(self, out, batch, step):
        return (out["rgb"] - batch.color.pseudo).abs().mean()


def build(scene, name="_tiny_image", act=None, seed=0):
    torch.manual_seed(seed)
    return BACKBONES.build({"name": name}, scene=scene, act=act)


def test_training_fits_the_images_and_calls_hooks_every_step():
    scene = tiny_scene()
    bb = build(scene)
    losses = build_losses(L1_DSSIM, bb.provides)
    res = train(bb, scene.train, losses, loop(300))
    assert res.steps == 300 and len(res.history) == 31  # step 1, then every 10th
    assert bb.hook_calls.tolist() == [300, 300]
    # the target images differ by per-view gains of ~5% plus noise 0.01: a shared image gets ~ 27+ dB
    assert res.history[-1]["psnr"] > 25 > res.history[0]["psnr"]
    assert res.history[-1]["loss"] < 0.6 * res.history[0]["loss"]  # DSSIM of the noise stays


def test_act_group_is_optimised_and_resume_is_exact(tmp_path):
    scene = tiny_scene()
    cfg = {"train": {"steps": 200}, "seed": 0}

    def run(ckpt_dir, stop_at=None, seed=0):
        torch.manual_seed(seed)
        act = ACT(len(scene.train), "rgb", 1e-3)
        bb = build(scene, act=act, seed=seed)
        losses = build_losses(L1_DSSIM, bb.provides)

        def on_step(s, rec):
            if s == stop_at:
                raise KeyboardInterrupt  # a crash after the checkpoint at step 100
        res = train(bb, scene.train, losses, loop(200, checkpoint_every=100), ckpt_dir=ckpt_dir, config=cfg,
                    act=act, act_lr=1e-2, on_step=on_step)
        return bb, act, res

    bb_a, act_a, res_a = run(tmp_path / "a")
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "b", stop_at=137)
    bb_b, act_b, res_b = run(tmp_path / "b", seed=99)  # different init: everything must come from the checkpoint
    assert res_b.resumed_from == 100 and res_b.steps == 200 and res_a.resumed_from is None
    for (n, pa), (_, pb) in zip(bb_a.state_dict().items(), bb_b.state_dict().items()):
        assert torch.equal(pa, pb), n
    assert torch.equal(act_a.weight, act_b.weight) and torch.equal(act_a.bias, act_b.bias)
    assert not torch.allclose(act_a.weight, torch.ones_like(act_a.weight), atol=2e-3)  # ACT was trained
    assert [h["loss"] for h in res_a.history] == [h["loss"] for h in res_b.history]


def test_ray_backbone_trains_on_random_ray_batches():
    scene = tiny_scene()
    bb = build(scene, "_tiny_rays")
    losses = build_losses({"l2": {}}, bb.provides, batch_mode="rays")
    res = train(bb, scene.train, losses, loop(100, rays_per_batch=256))
    assert bb.seen[0] == ((256, 3), (256,))
    assert res.history[-1]["loss"] < 0.5 * res.history[0]["loss"]
    s = RaySampler(scene.train, 64, seed=1).next()
    o, d = scene.train.cameras.rays()
    n = len(scene.train)
    dists = (s.rays_d[:, None] - d.reshape(n, -1, 3)[s.indices]).norm(dim=-1)  # [64, H*W] within its view
    pix = dists.argmin(1)
    assert float(dists.min(1).values.max()) < 1e-6
    torch.testing.assert_close(s.rays_o, o.reshape(n, -1, 3)[s.indices, pix])
    torch.testing.assert_close(s.images, scene.train.images.reshape(n, -1, 3)[s.indices, pix])
    assert s.masks.shape == (64, 1) and torch.equal(s.ray_image_ids, scene.train.cameras.image_ids[s.indices])


def test_view_sampler_visits_every_view_once_per_epoch():
    scene = tiny_scene(n=5)
    s = ViewSampler(scene.train, batch_views=1, seed=3)
    epoch = [int(s.next().indices[0]) for _ in range(5)]
    assert sorted(epoch) == [0, 1, 2, 3, 4]
    b = ViewSampler(scene.train, batch_views=2, seed=3).next()
    assert b.images.shape == (2, 16, 24, 3) and b.masks.shape == (2, 16, 24, 1) and len(b.cameras) == 2
    # the batch is the split's rows `views` (taken by slicing on the device, no index tensor from the host)
    v = list(b.views)
    assert b.indices.tolist() == v and torch.equal(b.images, scene.train.images[v])
    assert torch.equal(b.masks[..., 0], scene.train.masks[v].float())
    assert torch.equal(b.cameras.world_to_cam, scene.train.cameras.world_to_cam[v])
    assert torch.equal(b.cameras.image_ids, scene.train.cameras.image_ids[v])


def test_batch_hook_fills_colour_targets_and_color_stage_uses_its_groups():
    from arcsem.plugins import ColorTargets

    scene = tiny_scene()
    bb = build(scene)
    target = torch.full((1, 16, 24, 3), 0.25)

    def hook(batch):
        n = len(batch.cameras)
        batch.color = ColorTargets(is_reference=torch.zeros(n, dtype=torch.bool), reference=target.expand(n, -1, -1, -1),
                                   pseudo=target.expand(n, -1, -1, -1), pseudo_valid=torch.ones(n, 16, 24, dtype=torch.bool))
        return batch
    losses = build_losses({"_pseudo_l1": {}}, bb.provides, batch_parts=frozenset({"color"}))
    gain0 = bb.gain.detach().clone()
    train(bb, scene.train, losses, loop(150, stage="color"), batch_hook=hook)
    assert torch.equal(bb.gain, gain0)  # not in the colour stage's groups
    assert (torch.sigmoid(bb.logits) - 0.25).abs().max() < 0.02


def test_resize_split_scales_images_masks_and_cameras():
    scene = tiny_scene()
    half = resize_split(scene.train, downscale=2)
    assert half.images.shape == (4, 8, 12, 3) and half.masks.dtype == torch.bool and half.masks.shape == (4, 8, 12)
    torch.testing.assert_close(half.images[0, 0, 0], scene.train.images[0, :2, :2].mean((0, 1)))
    assert half.cameras.K[0, 0, 0] == pytest.approx(15.0) and half.cameras.width == 12
    assert resize_split(scene.train, width=12).images.shape == (4, 8, 12, 3)


def test_adam_is_fused_unless_switched_off():
    """``train.optim.fused`` (default true): Adam's fused kernel; ``false``: PyTorch's loop. Both step alike."""
    from arcsem.train.optim import GroupSchedule, OptimConfig, build_optimizers

    results = {}
    for fused in (True, False):
        torch.manual_seed(0)
        p = nn.Parameter(torch.randn(50, 3))
        opt = build_optimizers({"xyz": [p]}, {"xyz": GroupSchedule(lr=1e-2)}, OptimConfig(fused=fused))["xyz"]
        assert bool(opt.defaults["fused"]) is fused
        for _ in range(5):
            p.grad = torch.sin(p.detach() * 3)
            opt.step()
        results[fused] = p.detach()
    torch.testing.assert_close(results[True], results[False], rtol=1e-6, atol=1e-7)
