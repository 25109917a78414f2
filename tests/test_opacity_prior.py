"""The ``opacity_beta`` loss plugin (Neural Volumes' beta prior on each ray's opacity) on a Plenoxels grid."""
from __future__ import annotations

import torch
from test_plenoxels import make, small_scene, with_ball

from arcsem.plugins import LOSSES


def test_opacity_beta_prior_value_and_it_drives_ray_opacities_to_zero_or_one():
    loss = LOSSES.build({"name": "opacity_beta", "eps": 1e-3})
    a = torch.tensor([[0.0], [0.3], [0.5], [0.99]], dtype=torch.float64, requires_grad=True)
    value = loss({"alpha": a}, None, 0)
    want = (torch.log(a + 1e-3) + torch.log(1 - a + 1e-3)).mean()
    torch.testing.assert_close(value, want)
    value.backward()
    assert a.grad[1] > 0 and a.grad[3] < 0 and abs(a.grad[2].item()) < 1e-12   # descent: 0.3 -> 0, 0.99 -> 1
    # on a grid: a translucent ball (rays through it at opacity ~0.2-0.9) turns all-or-nothing under the prior
    scene = small_scene()
    bb = make(scene)
    with_ball(bb, radius=0.5, sigma=1.5)
    o, d = scene.train.cameras[:1].rays()
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    hit = bb.render_rays(o, d)["alpha"].detach()[:, 0] > 0.05

    def mixed() -> float:  # mean a (1 - a) of the rays that meet the ball: 0 when all-or-nothing
        al = bb.render_rays(o, d)["alpha"].detach()
        return (al * (1 - al))[hit].mean().item()

    before = mixed()
    opt = torch.optim.SGD([bb.density], lr=100.0)
    for _ in range(60):
        opt.zero_grad()
        loss(bb.render_rays(o, d), None, 0).backward()
        opt.step()
    assert before > 0.1 and mixed() < 0.5 * before
