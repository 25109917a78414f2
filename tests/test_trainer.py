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

from arcsem.act import ACT
from arcsem.cameras import Cameras, look_at
from arcsem.errors import ConfigError, TrainingError
from arcsem.plugins import BACKBONES, LOSSES, Backbone, Loss
from arcsem.scene import Scene, Split
from arcsem.train.loop import LoopConfig, train
from arcsem.train.losses import build_losses, merge_loss_cfgs
from arcsem.train.optim import GroupSchedule, lr_at
from arcsem.train.sampling import RaySampler, ViewSampler, resize_split


@pytest.fixture(autouse=True)
def _one_thread():
    """Tiny tensors: one thread avoids oversubscription on the shared 2-core machine (20x slower otherwise)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def tiny_scene(n: int = 4, w: int = 24, h: int = 16, test: int = 2, seed: int = 0) -> Scene:
    """``n`` training + ``test`` held-out pinhole cameras on an arc; images = one smooth pattern x gain."""
    g = torch.Generator().manual_seed(seed)
    ang = torch.linspace(-0.5, 0.5, n + test)
    eye = torch.stack([4 * torch.sin(ang), torch.full_like(ang, -0.5), -4 * torch.cos(ang)], -1)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0]))
    K = torch.tensor([[30.0, 0, w / 2], [0, 30.0, h / 2], [0, 0, 1.0]]).repeat(n + test, 1, 1)
    ids = torch.cat([torch.arange(n), torch.full((test,), -1)])
    cams = Cameras(w2c, K, w, h, "pinhole", image_ids=ids)
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    base = (0.3 + 0.4 * xx * yy)[None, ..., None].expand(n + test, h, w, 3)
    gain = 1 + 0.05 * torch.randn(n + test, 1, 1, 1, generator=g)
    clean = base.clone()
    imgs = (base * gain + 0.01 * torch.randn(n + test, h, w, 3, generator=g)).clamp(0, 1)
    masks = torch.zeros(n + test, h, w, dtype=torch.bool)
    masks[:, 3:-3, 4:-4] = True
    depths = torch.where(masks, torch.tensor(2.0), torch.tensor(0.0))
    tr = [i for i in range(n + test) if i < n]
    te = list(range(n, n + test))
    full = Split([f"v{i}" for i in range(n + test)], cams, imgs, masks, depths, clean=clean)
    return Scene("tiny", full.subset(tr), full.subset(te), torch.tensor([[-1.0] * 3, [1.0] * 3]))


@BACKBONES.register("_tiny_image")
class TinyImage(Backbone):
    """One learned ``[H,W,3]`` image for every camera; ``gain`` is a second parameter group."""

    provides = frozenset({"rgb", "alpha", "depth"})

    @dataclass
    class Config:
        lr_image: float = 0.05
        lr_gain: float = 0.01

    def __init__(self, cfg, scene=None, act=None):
        super().__init__(cfg)
        h, w = scene.train.cameras.height, scene.train.cameras.width
        self.logits = nn.Parameter(0.1 * torch.randn(h, w, 3))
        self.gain = nn.Parameter(torch.zeros(1))
        self.act = act
        self.register_buffer("hook_calls", torch.zeros(2, dtype=torch.long))

    def render(self, cams, **kw):
        C = len(cams)
        rgb = torch.sigmoid(self.logits + self.gain)[None].expand(C, -1, -1, -1)
        if self.act is not None:
            rgb = self.act.apply(rgb.reshape(C, -1, 3), cams.image_ids).reshape(rgb.shape)
        ones = torch.ones_like(rgb[..., :1])
        return {"rgb": rgb, "alpha": ones, "depth": 2.0 * ones + 0.01 * self.logits[None, ..., :1]}

    def param_groups(self, stage):
        return {"image": [self.logits], "gain": [self.gain]} if stage == "geometry" else {"image": [self.logits]}

    def pre_backward(self, step, out):
        self.hook_calls[0] += 1

    def post_backward(self, step, out, optimizers):
        self.hook_calls[1] += 1
        assert set(optimizers) >= {"image"}

    def num_primitives(self):
        return self.logits.shape[0] * self.logits.shape[1]


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


def loop(steps, **kw):
    return LoopConfig(steps=steps, progress=False, log_every=10, checkpoint_every=kw.pop("checkpoint_every", 0), **kw)


L1_DSSIM = {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}


def test_training_fits_the_images_and_calls_hooks_every_step():
    scene = tiny_scene()
    bb = build(scene)
    losses = build_losses(L1_DSSIM, bb.provides)
    res = train(bb, scene.train, losses, loop(300))
    assert res.steps == 300 and len(res.history) == 30
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
    with pytest.raises(TrainingError, match=r"step 7: loss term '_nan_at'"):
        train(bb, scene.train, losses, loop(20, checkpoint_every=3), ckpt_dir=tmp_path, config={})
    state = torch.load(tmp_path / "last.pt", weights_only=False)
    assert state["step"] == 6
    assert all(torch.isfinite(v).all() for v in state["model"].values() if v.is_floating_point())


def test_nan_gradient_names_the_parameter_group():
    scene = tiny_scene()
    bb = build(scene)
    losses = build_losses({"l1": {}, "_nan_grad": {"weight": 1.0, "start_step": 3}}, bb.provides)
    with pytest.raises(TrainingError, match=r"step 3: gradient of group '(image|gain)'"):
        train(bb, scene.train, losses, loop(10))
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


TINY_OVERRIDES = {  # tiny settings per in-tree backbone: every schedule event happens within 20 steps
    "gs2d": {"random_init_points": 300, "densify_from": 2, "densify_every": 4, "densify_until": 30,
             "opacity_reset_every": 9},
    "gs3d": {"random_init_points": 300, "densify_from": 2, "densify_every": 4, "densify_until": 30,
             "opacity_reset_every": 9},
    "plenoxels": {"reso": [[12, 12, 12], [16, 16, 16]], "upsample_every": 8},
}

@pytest.mark.slow
@pytest.mark.parametrize("name", ["gs2d", "gs3d",
                                  "plenoxels"])
def test_real_backbone_resumes_exactly_across_densification(name, tmp_path):
    """20 steps straight vs 10 + crash at 13 + resume: identical models (densify/upsample at 12, 16)."""
    scene = tiny_scene(n=6, w=48, h=32)
    losses_cfg = {"l2": {}} if name == "plenoxels" else {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}

    def run(d, stop=None, seed=0):
        torch.manual_seed(seed)
        act = ACT(len(scene.train), "rgb", 1e-3)
        bb = BACKBONES.build({"name": name, **TINY_OVERRIDES[name]}, scene=scene, act=act)
        losses = build_losses(losses_cfg, bb.provides, bb.batch_mode)

        def on_step(s, rec):
            if s == stop:
                raise KeyboardInterrupt
        train(bb, scene.train, losses, loop(20, checkpoint_every=10, rays_per_batch=200), ckpt_dir=d, config={},
              act=act, act_lr=1e-3, on_step=on_step)
        return bb, act

    a, act_a = run(tmp_path / "a")
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path / "b", stop=13)
    b, act_b = run(tmp_path / "b", seed=5)
    assert a.num_primitives() == b.num_primitives()
    sa, sb = a.state_dict(), b.state_dict()
    for k, v in sa.items():
        if torch.is_tensor(v):
            assert torch.equal(v, sb[k]), k
    assert torch.equal(act_a.weight, act_b.weight)


@pytest.mark.parametrize("preset", ["quick", "paper"])
def test_presets_validate_against_trainer_and_backbone_configs(preset):
    from hydra import compose, initialize_config_module

    from arcsem.registry import validate_config
    from arcsem.train.stage1 import train_config

    with initialize_config_module("arcsem.conf", version_base=None):
        cfg = compose("config", overrides=[f"train={preset}", "dataset=transforms"])
    tc = train_config(cfg)
    assert tc.losses == {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}  # (1-0.2) L1 + 0.2 D-SSIM
    for name, over in tc.per_backbone.items():
        cls = BACKBONES.get(name)
        validate_config(cls.Config, dict(over.get("backbone") or {}), where=f"train.per_backbone.{name}")
        assert set(over) <= {"backbone", "losses", "steps"}, over
        merged = merge_loss_cfgs(tc.losses, over.get("losses"))
        assert all(k in LOSSES.names() for k, v in merged.items() if v is not None), merged
    if preset == "paper":
        assert tc.steps == 60_000 and tc.downscale == 1 and tc.width is None


def test_gaussian_rates_follow_the_backbone_schedule_unless_the_config_overrides_a_group(monkeypatch):
    """train.optim.groups.<g> wins over the Gaussian backbone's own schedule, across densification
    (the rates are read after each step: a backbone hook that rewrote them would show here)."""
    from arcsem.train import loop as loop_mod

    scene = tiny_scene(n=4, w=24, h=16)
    bb = BACKBONES.build({"name": "gs2d", **TINY_OVERRIDES["gs2d"]}, scene=scene)
    opts, seen = {}, []

    def spy(optimizers, *args):
        opts.update(optimizers)
        return loop_mod_apply(optimizers, *args)

    loop_mod_apply = loop_mod.apply_schedules
    monkeypatch.setattr(loop_mod, "apply_schedules", spy)
    losses = build_losses(L1_DSSIM, bb.provides, bb.batch_mode)
    train(bb, scene.train, losses, loop(12), optim={"groups": {"opacity": {"lr": 0.0123}}, "lr_scale": 2.0},
          on_step=lambda s, rec: seen.append({g: o.param_groups[0]["lr"] for g, o in opts.items()}))
    assert len(seen) == 12 and all(r["opacity"] == pytest.approx(2 * 0.0123) for r in seen)  # x lr_scale
    assert [r["xyz"] for r in seen] == pytest.approx([2 * bb.learning_rates(s)["xyz"] for s in range(12)])
    assert seen[0]["xyz"] > seen[-1]["xyz"]  # the position rate decays
