"""Stage 2's recorded renders of a frozen geometry (backbones/gaussians/frozen.py, cpp/weights.h, arcsem/train/frozen.py).

The compositing weights the fused forward pass records must reproduce its render as a sparse product of the colours,
and its colour gradient as the transposed product; stage 2 trained through the recorded renders must end where the
compositing one does (up to the order of float sums), and every view past the memory budget renders as usual.
"""
from __future__ import annotations

import pytest
import torch
from arcsem.backbones.gaussians.frozen import FrozenColours
from arcsem.backbones.gs2d.render import render_2dgs
from arcsem.backbones.gs3d.render import render_3dgs
from test_fused import scene
from trainer_util import loop, tiny_scene

from arcsem.plugins import BACKBONES, ColorTargets
from arcsem.train import build_losses, train
from arcsem.train.frozen import FrozenViews

RENDER = {"gs2d": render_2dgs, "gs3d": render_3dgs}
TOL = {torch.float64: 1e-11, torch.float32: 2e-6}


@pytest.mark.parametrize("kind", ["gs2d", "gs3d"])
@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("impl", ["cpp", "torch"])
def test_recorded_weights_render_and_differentiate_as_the_compositing_does(kind, model, dtype, impl):
    (means, quats, scales, opac, colors), cams = scene(kind, dtype, model)
    colors = colors.clone().requires_grad_(True)
    bg = torch.tensor([0.2, 0.5, 0.9], dtype=dtype)
    out = RENDER[kind](means, quats, scales, opac, colors, cams, background=bg, impl=impl, colour_weights=True)
    C, H, W = len(cams), cams.height, cams.width
    w = out["colour_weights"]
    assert w.pix_w.numel() > 100 and bool((w.pix_w > 0).all())  # (the opaque stack stops pixels early: some rows short)
    frozen = FrozenColours(w, (C, H, W), bg)
    rgb = frozen(colors.reshape(-1, 3))
    scale = out["rgb"].abs().max()
    assert (rgb - out["rgb"]).abs().max() <= TOL[dtype] * scale
    g = torch.randn_like(rgb)
    (want,) = torch.autograd.grad((out["rgb"] * g).sum(), colors)
    (got,) = torch.autograd.grad((rgb * g).sum(), colors)
    assert (got - want).abs().max() <= TOL[dtype] * want.abs().max()
    # the background's weight is the final transmittance, 1 - alpha
    torch.testing.assert_close(w.t_final.view(C, H, W, 1), 1 - out["alpha"], atol=10 * TOL[dtype], rtol=0)


def test_the_two_paths_record_the_same_weights():
    """The fused record and the PyTorch path's hold the same (pixel, splat, w) in float64."""
    (means, quats, scales, opac, colors), cams = scene("gs2d", torch.float64, "pinhole")
    rec = {impl: render_2dgs(means, quats, scales, opac, colors, cams, impl=impl, colour_weights=True)["colour_weights"]
           for impl in ("cpp", "torch")}

    def dense(r):
        P = r.pix_ptr.numel() - 1
        rows = torch.repeat_interleave(torch.arange(P), torch.diff(r.pix_ptr.long()))
        out = torch.zeros(P, int(r.ids.max()) + 1, dtype=r.pix_w.dtype)
        return out.index_put_((rows, r.ids[r.pix_pair.long()]), r.pix_w, accumulate=True)

    a, b = dense(rec["cpp"]), dense(rec["torch"])
    n = min(a.shape[1], b.shape[1])
    assert (a[:, n:].abs().sum() + b[:, n:].abs().sum()) == 0
    assert (a[:, :n] - b[:, :n]).abs().max() < 1e-10 and a.sum() > 10


def _stage2(frozen_mb: int, name: str = "gs2d", steps: int = 30, rasterizer: str = "cpp", batch_views: int = 1):
    """A stage-2 training of a random Gaussian model on the tiny scene (its geometry frozen), and its FrozenViews."""
    scene = tiny_scene(n=4)
    torch.manual_seed(0)
    bb = BACKBONES.build({"name": name, "random_init_points": 300, "rasterizer": rasterizer}, scene=scene)
    bb.stage = "color"
    target = torch.rand(len(scene.train), 16, 24, 3, generator=torch.Generator().manual_seed(1))

    def hook(batch):
        n = len(batch.cameras)
        batch.color = ColorTargets(is_reference=torch.zeros(n, dtype=torch.bool), reference=target[list(batch.views)],
                                   pseudo=target[list(batch.views)], pseudo_valid=torch.ones(n, 16, 24, dtype=torch.bool))
        return batch

    losses = build_losses({"pseudo_color": {"weight": 1.0}}, bb.provides, batch_parts=frozenset({"color"}))
    seen = {}
    original = FrozenViews.render

    def spy(self, backbone, batch):
        seen["views"] = self
        return original(self, backbone, batch)

    FrozenViews.render = spy
    try:
        if steps:
            train(bb, scene.train, losses, loop(steps, stage="color", frozen_mb=frozen_mb, batch_views=batch_views),
                  batch_hook=hook)
    finally:
        FrozenViews.render = original
    return bb, seen.get("views")


@pytest.mark.parametrize("name,rasterizer", [("gs2d", "cpp"), ("gs3d", "cpp"), ("gs2d", "torch")])
def test_stage2_through_the_recorded_renders_ends_where_compositing_does(name, rasterizer):
    plain, none = _stage2(0, name, rasterizer=rasterizer)
    frozen, views = _stage2(64, name, rasterizer=rasterizer)
    assert none is None  # frozen_mb 0: the trainer never records
    assert sorted(views.ops) == [0, 1, 2, 3] and not views.refused  # every view recorded, used on its later draws
    assert views.summary()["views"] == 4 and views.summary()["over_budget"] == 0
    start, _ = _stage2(0, name, steps=0, rasterizer=rasterizer)
    assert (plain.model.sh_dc - start.model.sh_dc).abs().max() > 1e-2  # the colours did train
    for a, b in ((plain.model.sh_dc, frozen.model.sh_dc), (plain.model.sh_rest, frozen.model.sh_rest)):
        assert (a - b).abs().max() < 1e-5
    torch.testing.assert_close(frozen.model.means, plain.model.means, atol=0, rtol=0)  # the geometry never moved


def test_views_past_the_budget_render_as_usual(monkeypatch):
    plain, _ = _stage2(0)
    _, views = _stage2(64)
    one = max(op.nbytes for op in views.ops.values())
    init = FrozenViews.__init__

    def small(self, budget_mb):
        init(self, budget_mb)
        self.budget = int(2.5 * one)  # room for two views of the tiny scene, not four

    monkeypatch.setattr(FrozenViews, "__init__", small)
    frozen, views = _stage2(64)
    assert len(views.ops) == 2 and len(views.refused) == 2 and views.used <= views.budget
    assert (plain.model.sh_dc - frozen.model.sh_dc).abs().max() < 1e-5


def test_a_batch_of_several_views_is_their_recorded_renders_stacked():
    plain, _ = _stage2(0, batch_views=2)
    frozen, views = _stage2(64, batch_views=2)
    assert len(views.ops) == 4
    assert (plain.model.sh_dc - frozen.model.sh_dc).abs().max() < 1e-5
