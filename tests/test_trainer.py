"""The generic training loop on tiny test-only backbones (registered under names starting with '_').

``TinyImage`` renders one learned image for every camera (with ACT applied when given);
``TinyRays`` colours each ray by a learned linear function of its direction (a ray backbone).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import pytest
import torch
from torch import nn
from trainer_util import L1_DSSIM, TinyImage, loop, tiny_scene

from arcsem.act import ACT
from arcsem.errors import ConfigError, TrainingError
from arcsem.plugins import BACKBONES, LOSSES, Backbone, Loss
from arcsem.train.loop import train
from arcsem.train.losses import build_losses, merge_loss_cfgs
from arcsem.train.optim import GroupSchedule, lr_at
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


@LOSSES.register("_extras_l1")
class ExtrasL1(Loss):
    """L1 against ``batch.extras['target']`` (stage-2 style targets)."""

    def forward(self, out, batch, step):
        return (out["rgb"] - batch.extras["target"]).abs().mean()


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


@pytest.mark.parametrize("solver", ["adam", "closed_form"])
def test_act_group_is_optimised_and_resume_is_exact(tmp_path, solver):
    scene = tiny_scene()
    cfg = {"train": {"steps": 200}, "seed": 0}

    def run(ckpt_dir, stop_at=None, seed=0):
        torch.manual_seed(seed)
        act = ACT(len(scene.train), "rgb", 1e-3, solver=solver)
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


def test_act_prior_penalises_the_batch_images_and_holds_act_near_identity():
    from arcsem.plugins import Batch

    scene = tiny_scene()
    act = ACT(len(scene.train), "rgb", 0.0)
    with torch.no_grad():
        act.weight[1] = torch.tensor([1.1, 1.0, 0.9])
        act.bias[1] = torch.tensor([0.0, 0.2, 0.0])
    prior = build_losses({"act_prior": {}}, {"rgb"}, act=act).terms["act_prior"]
    cams = scene.train.cameras[[1, 1]]
    value = prior({}, Batch(cameras=cams, images=scene.train.images[[1, 1]], indices=torch.tensor([1, 1])), 0)
    assert value.item() == pytest.approx(0.01 + 0.01 + 0.04)  # image 1 once; images 0, 2, 3 are not in the batch
    with pytest.raises(ConfigError, match="act=paper"):
        build_losses({"act_prior": {}}, {"rgb"})

    def fit(weight):  # the views differ by gains of ~5 %: ACT learns them unless the prior holds it
        torch.manual_seed(0)
        act = ACT(len(scene.train), "rgb", 0.0)
        bb = build(scene, act=act)
        terms = {**L1_DSSIM, "act_prior": {"weight": weight}}
        train(bb, scene.train, build_losses(terms, bb.provides, act=act), loop(200), act=act, act_lr=1e-2)
        return (act.weight - 1).abs().max().item() + act.bias.abs().max().item()

    free, held = fit(0.0), fit(100.0)
    assert free > 0.02 and held < 0.25 * free, (free, held)


def test_closed_form_act_learns_the_views_gains_without_adam(monkeypatch):
    """The tiny scene's views are one image times a per-view gain: the closed-form ACT finds the gains'
    ratios (up to one shared factor, absorbed by the image), and ACT gets no optimiser group."""
    from arcsem.act import affine_fit

    pre = torch.rand(2, 8, 6, 3, dtype=torch.float64)
    alpha = torch.ones(2, 8, 6, 1, dtype=torch.float64)
    target = 1.2 * pre + 0.05
    W, b = affine_fit(pre, alpha, target, "scalar")
    assert W.shape == (2, 1) and torch.allclose(W, torch.full_like(W, 1.2)) and torch.allclose(b, torch.full_like(b, 0.05))
    shrunk = [affine_fit(pre, alpha, target, "scalar", p)[0][0, 0].item() for p in (0.1, 1.0, 100.0)]
    assert 1.2 > shrunk[0] > shrunk[1] > shrunk[2] > 1.0 and shrunk[2] < 1.01  # the ridge pulls W to the identity

    scene = tiny_scene(n=6)
    torch.manual_seed(0)
    act = ACT(len(scene.train), "scalar", 0.0, solver="closed_form", fit_rate=0.5)
    bb = build(scene, act=act)
    from arcsem.train import loop as loop_mod

    groups = []
    real = loop_mod.apply_schedules
    monkeypatch.setattr(loop_mod, "apply_schedules", lambda opts, *a, **k: groups.append(set(opts)) or real(opts, *a, **k))
    train(bb, scene.train, build_losses({"l2": {}}, bb.provides), loop(300), act=act, act_lr=1e-3)
    assert groups and all("act" not in g for g in groups) and not act.weight.requires_grad
    gains = torch.stack([(scene.train.images[i] / scene.train.clean[i]).median() for i in range(6)])
    ratio = act.weight[:, 0] / gains
    assert (ratio / ratio.mean() - 1).abs().max() < 0.01, (act.weight[:, 0], gains)
    assert (gains / gains.mean() - 1).abs().max() > 0.03  # the gains do differ


def test_resume_with_a_different_config_lists_the_keys(tmp_path):
    scene = tiny_scene()
    bb = build(scene)
    losses = build_losses(L1_DSSIM, bb.provides)
    cfg = {"train": {"steps": 20, "losses": {"l1": {"weight": 0.8}}}, "seed": 0}
    train(bb, scene.train, losses, loop(20), ckpt_dir=tmp_path, config=cfg)
    other = {"train": {"steps": 20, "losses": {"l1": {"weight": 0.5}}}, "seed": 1}
    with pytest.raises(TrainingError, match=r"seed \(0 -> 1\), train\.losses\.l1\.weight \(0.8 -> 0.5\)"):
        train(build(scene), scene.train, losses, loop(20), ckpt_dir=tmp_path, config=other)
    # never: starts over; must without a checkpoint: refuses
    res = train(build(scene), scene.train, losses, loop(20, resume="never"), ckpt_dir=tmp_path, config=other)
    assert res.resumed_from is None
    with pytest.raises(TrainingError, match="no checkpoint"):
        train(build(scene), scene.train, losses, loop(5, resume="must"), ckpt_dir=tmp_path / "x", config=other)


def test_nan_loss_names_step_and_term_and_keeps_last_good_checkpoint(tmp_path):
    scene = tiny_scene()
    bb = build(scene)
    losses = build_losses({"l1": {}, "_nan_at": {"at_step": 7}}, bb.provides)
    with pytest.raises(TrainingError, match=r"step 7: loss term '_nan_at'.*the checkpoint on disk is from step 6 \("):
        train(bb, scene.train, losses, loop(20, checkpoint_every=3), ckpt_dir=tmp_path, config={})
    state = torch.load(tmp_path / "last.pt", weights_only=True)
    assert state["step"] == 6
    assert all(torch.isfinite(v).all() for v in state["model"].values() if v.is_floating_point())


def test_nan_gradient_names_the_parameter_group(tmp_path):
    scene = tiny_scene()
    bb = build(scene)
    losses = build_losses({"l1": {}, "_nan_grad": {"weight": 1.0, "start_step": 3}}, bb.provides)
    with pytest.raises(TrainingError, match=r"step 3: gradient of group '(image|gain)'.*no checkpoints are written"):
        train(bb, scene.train, losses, loop(10))
    with pytest.raises(TrainingError, match=r"step 3: .*no checkpoint has been written yet \(.*last.pt does not exist"):
        train(build(scene), scene.train, losses, loop(10, checkpoint_every=5), ckpt_dir=tmp_path, config={})
    assert torch.isfinite(bb.logits).all()  # the bad step was not applied


def test_loss_requirements_are_checked_at_build_time():
    with pytest.raises(ConfigError, match=r"needs \['normal'\].*'_tiny_image'"):
        build_losses({"l1": {}, "_needs_normal": {}}, TinyImage.provides, backbone="_tiny_image")
    with pytest.raises(ConfigError, match="'image'.*'rays'"):
        build_losses({"dssim": {}}, TinyRays.provides, batch_mode="rays")
    with pytest.raises(ConfigError, match="no loss term"):
        build_losses({"l1": None, "dssim": {"weight": 0}}, TinyImage.provides)
    merged = merge_loss_cfgs({"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}, {"dssim": None, "l2": {"weight": 1}})
    assert merged == {"l1": {"weight": 0.8}, "dssim": None, "l2": {"weight": 1}}


def test_start_steps_switch_terms_on():
    losses = build_losses({"l1": {}, "dssim": {"weight": 0.2, "start_step": 50}}, TinyImage.provides)
    assert losses.active(49) == ["l1"] and losses.active(50) == ["l1", "dssim"]


def test_lr_schedule_is_log_linear_with_delay():
    s = GroupSchedule(lr=1e-2, lr_final=1e-4, decay_steps=100)
    assert lr_at(s, 0, 1000) == pytest.approx(1e-2)
    assert lr_at(s, 50, 1000) == pytest.approx(1e-3)  # geometric midpoint
    assert lr_at(s, 500, 1000) == pytest.approx(1e-4)  # held after the decay
    d = GroupSchedule(lr=1.0, delay_steps=10, delay_mult=0.01)
    assert lr_at(d, 0, 100) == pytest.approx(0.01)
    assert lr_at(d, 5, 100) == pytest.approx(0.01 + 0.99 * math.sin(math.pi / 4))


def test_ray_backbone_trains_on_random_ray_batches():
    scene = tiny_scene()
    bb = build(scene, "_tiny_rays")
    losses = build_losses({"l2": {}}, bb.provides, batch_mode="rays")
    res = train(bb, scene.train, losses, loop(100, rays_per_batch=256))
    assert bb.seen[0] == ((256, 3), (256,))
    assert res.history[-1]["loss"] < 0.5 * res.history[0]["loss"]
    act = ACT(len(scene.train), "rgb", solver="closed_form")
    with pytest.raises(ConfigError, match="act.solver=adam"):  # the closed form fits whole views only
        train(build(scene, "_tiny_rays", act=act), scene.train, losses, loop(2, rays_per_batch=16), act=act, act_lr=1e-3)
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


def test_batch_hook_fills_extras_and_color_stage_uses_its_groups():
    scene = tiny_scene()
    bb = build(scene)
    target = torch.full((1, 16, 24, 3), 0.25)

    def hook(batch):
        batch.extras = {"target": target.expand(len(batch.cameras), -1, -1, -1)}
        return batch
    losses = build_losses({"_extras_l1": {}}, bb.provides)
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
