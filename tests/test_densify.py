"""Densification: statistics, clone/split/prune decisions, and optimiser state surgery."""
from __future__ import annotations

import math

import pytest
import torch
from arcsem.backbones.gaussians.densify import (
    DensifyStats,
    clone_split_prune,
    remap_optimizers,
    reset_opacity,
    screen_grad_norms,
)
from arcsem.backbones.gaussians.model import GaussianModel

from arcsem.cameras import Cameras


def model_of(n: int, num_scales: int = 3, seed: int = 0) -> GaussianModel:
    g = torch.Generator().manual_seed(seed)
    return GaussianModel({
        "means": torch.randn(n, 3, generator=g),
        "quats": torch.randn(n, 4, generator=g),
        "log_scales": torch.full((n, num_scales), math.log(0.005)),
        "opacity_logits": torch.zeros(n),
        "sh_dc": torch.randn(n, 1, 3, generator=g),
        "sh_rest": torch.zeros(n, 15, 3),
    })


def adam_after_one_step(m: GaussianModel) -> torch.optim.Adam:
    opt = torch.optim.Adam([{"params": [p], "name": k} for k, p in m.params().items()], lr=1e-3)
    loss = sum((p * torch.randn_like(p)).sum() for p in m.parameters())
    loss.backward()
    opt.step()
    return opt


def test_prune_and_clone_keep_adam_state_aligned():
    m = model_of(6)
    opt = adam_after_one_step(m)
    rows_before = {k: (p.detach().clone(), opt.state[p]["exp_avg"].clone(), opt.state[p]["exp_avg_sq"].clone())
                   for k, p in m.params().items()}
    ids_before = {k: id(p) for k, p in m.params().items()}
    with torch.no_grad():
        m.opacity_logits[[1, 4]] = -10.0  # prune rows 1 and 4
        rows_before["opacity_logits"][0][[1, 4]] = -10.0
    stats = DensifyStats.zeros(6)
    stats.grad_sum[[0, 3]] = 1.0  # clone rows 0 and 3 (small scale)
    stats.count[:] = 1
    info = clone_split_prune(m, stats, {"main": opt}, grad_threshold=0.5, percent_dense=0.01, extent=1.0,
                             min_opacity=0.005)
    assert info == {"cloned": 2, "split": 0, "pruned": 2, "total": 6}
    src = torch.tensor([0, 2, 3, 5, 0, 3])  # survivors in order, then the clones
    fresh = torch.tensor([False] * 4 + [True] * 2)
    for k, p in m.params().items():
        assert id(p) == ids_before[k] and p.grad is None
        val, ea, eas = rows_before[k]
        torch.testing.assert_close(p.detach(), val[src])
        exp = ea[src].clone()
        exp[fresh] = 0
        torch.testing.assert_close(opt.state[p]["exp_avg"], exp)
        exp = eas[src].clone()
        exp[fresh] = 0
        torch.testing.assert_close(opt.state[p]["exp_avg_sq"], exp)
    # the optimiser still steps with the new shapes
    sum((p**2).sum() for p in m.parameters()).backward()
    opt.step()


def test_split_children_scale_and_positions():
    m = model_of(3)
    with torch.no_grad():
        m.log_scales[1] = torch.log(torch.tensor([0.4, 0.2, 0.1]))
        m.quats[1] = torch.tensor([1.0, 0, 0, 0])
    stats = DensifyStats.zeros(3)
    stats.grad_sum[1], stats.count[:] = 1.0, 2
    parent = m.means[1].detach().clone()
    g = torch.Generator().manual_seed(3)
    info = clone_split_prune(m, stats, [], grad_threshold=0.3, percent_dense=0.01, extent=1.0,
                             min_opacity=0.005, generator=g)
    assert info["split"] == 1 and info["total"] == 4
    kids = slice(2, 4)
    torch.testing.assert_close(torch.exp(m.log_scales[kids]), torch.tensor([[0.4, 0.2, 0.1]]).expand(2, 3) / 1.6)
    offs = (m.means[kids] - parent).detach()
    g = torch.Generator().manual_seed(3)
    torch.testing.assert_close(offs, torch.randn(2, 3, generator=g) * torch.tensor([0.4, 0.2, 0.1]))


def test_split_of_surfels_stays_in_plane():
    m = model_of(1, num_scales=2)
    with torch.no_grad():
        m.log_scales[0] = math.log(0.5)
    stats = DensifyStats.zeros(1)
    stats.grad_sum[0], stats.count[0] = 1.0, 1
    parent, normal = m.means[0].detach().clone(), m.rotations[0, :, 2].detach().clone()
    clone_split_prune(m, stats, [], grad_threshold=0.3, percent_dense=0.01, extent=1.0, min_opacity=0.0)
    assert len(m) == 2
    offs = (m.means - parent).detach()
    torch.testing.assert_close(offs @ normal, torch.zeros(2), atol=1e-6, rtol=0)
    assert offs.norm(dim=1).min() > 0


def test_prune_huge_in_screen_and_world_only_when_asked():
    m = model_of(4)
    with torch.no_grad():
        m.log_scales[2] = math.log(0.3)  # > 0.1 * extent (1.0)
    stats = DensifyStats.zeros(4)
    stats.max_radii[0] = 25.0
    kw = {"grad_threshold": 1.0, "percent_dense": 0.01, "extent": 1.0, "min_opacity": 0.005}
    assert clone_split_prune(m, stats, [], **kw)["pruned"] == 0
    info = clone_split_prune(m, stats, [], max_screen_size=20, **kw)
    assert info["pruned"] == 2 and len(m) == 2


def test_reset_opacity_and_its_state():
    m = model_of(3)
    opt = adam_after_one_step(m)
    with torch.no_grad():
        m.opacity_logits[0] = -8.0  # 3e-4, below the cap: unchanged
    reset_opacity(m, {"o": opt})
    torch.testing.assert_close(m.opacities.detach(), torch.tensor([1 / (1 + math.exp(8)), 0.01, 0.01]))
    assert opt.state[m.opacity_logits]["exp_avg"].abs().sum() == 0
    assert opt.state[m.means]["exp_avg"].abs().sum() > 0


def test_remap_ignores_foreign_parameters():
    other = torch.nn.Parameter(torch.randn(5, 3))
    m = model_of(5)
    opt = torch.optim.Adam([other, *m.parameters()])
    (other.sum() + m.means.sum()).backward()
    opt.step()
    before = opt.state[other]["exp_avg"].clone()
    remap_optimizers(m.params(), torch.tensor([0, 1]), torch.tensor([False, True]), [opt])
    torch.testing.assert_close(opt.state[other]["exp_avg"], before)
    assert opt.state[m.means]["exp_avg"].shape == (2, 3)


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
def test_screen_grad_matches_pixel_chain_rule(model):
    """A loss of the projected pixel position: the statistic equals |dL/dpix| * (W/2, H/2)."""
    torch.manual_seed(0)
    w2c = torch.eye(4)
    w2c[:3, :3] = torch.linalg.qr(torch.randn(3, 3))[0]
    if torch.det(w2c[:3, :3]) < 0:
        w2c[:3, 0] *= -1
    w2c[2, 3] = 6.0
    cams = Cameras(w2c, torch.tensor([[40.0, 0, 16], [0, 50.0, 12], [0, 0, 1]]), 32, 24, model)
    means = torch.randn(5, 3, requires_grad=True)
    a = torch.randn(5, 2)
    uv, _ = cams.project(means)
    (uv[0] * a).sum().backward()  # dL/du = a[:,0], dL/dv = a[:,1] exactly in pixels
    # Only in-plane motion enters; the gradient through z is not part of the statistic.
    # Remove the depth part of the 3-D gradient to compare with the pure pixel gradient.
    R = w2c[:3, :3]
    g_cam = means.grad @ R.T
    if model == "pinhole":  # du/dz = -fx x / z^2 only adds to the z-component: drop it
        g_cam[:, 2] = 0
    norms = screen_grad_norms(g_cam @ R, means.detach(), cams)
    expected = torch.sqrt((a[:, 0] * 16) ** 2 + (a[:, 1] * 12) ** 2)
    torch.testing.assert_close(norms[0], expected, rtol=1e-5, atol=1e-6)


def test_stats_accumulate_only_visible():
    s = DensifyStats.zeros(3)
    s.accumulate(torch.tensor([[1.0, 2.0, 3.0], [5.0, 6.0, 7.0]]), torch.tensor([[True, False, True], [True, True, False]]),
                 torch.tensor([[4, 9, 2], [1, 3, 8]]))
    torch.testing.assert_close(s.mean_grad(), torch.tensor([3.0, 6.0, 3.0]))
    torch.testing.assert_close(s.max_radii, torch.tensor([4.0, 3.0, 2.0]))
    assert DensifyStats.zeros(2).mean_grad().tolist() == [0.0, 0.0]


@pytest.mark.parametrize("model", ["pinhole", "orthographic"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fused_stats_equal_the_reference(model, dtype):
    """The fused statistics kernel (rasterizer cpp) adds what screen_grad_norms + accumulate add: three cameras,
    splats visible in some of them, accumulators already holding earlier steps."""
    from arcsem.backbones.gaussians.fused import densify_stats, load_extension

    from arcsem.cameras import look_at

    if load_extension() is None:
        pytest.skip("the fused kernels did not build")
    g = torch.Generator().manual_seed(1)
    n = 1000
    eye = torch.tensor([[0.0, 0.0, -4.0], [1.0, -0.5, -3.5], [-2.0, 0.3, -3.0]], dtype=torch.float64)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64))
    K = torch.tensor([[60.0, 0, 30.0], [0, 55.0, 20.0], [0, 0, 1]], dtype=torch.float64).repeat(3, 1, 1)
    K[1, 0, 0] = 70.0
    cams = Cameras(w2c, K, 64, 40, model)
    means = torch.randn(n, 3, generator=g, dtype=dtype)
    grad = torch.randn(n, 3, generator=g, dtype=dtype) * 1e-3
    visible = torch.rand(3, n, generator=g) > 0.4
    radii = torch.where(visible, torch.randint(1, 30, (3, n), generator=g), torch.zeros(3, n, dtype=torch.long))
    ref, fused = DensifyStats.zeros(n), DensifyStats.zeros(n)
    for s in (ref, fused):  # earlier steps
        s.grad_sum += torch.arange(n) * 1e-4
        s.count += 2
        s.max_radii += torch.arange(n) % 17
    ref.accumulate(screen_grad_norms(grad, means, cams), visible, radii)
    densify_stats(fused, grad, means, cams, visible, radii)
    assert (ref.count != 2).any() and (ref.max_radii != torch.arange(n) % 17).any(), "the step should add something"
    torch.testing.assert_close(fused.grad_sum, ref.grad_sum, rtol=1e-5, atol=1e-9)
    assert torch.equal(fused.count, ref.count) and torch.equal(fused.max_radii, ref.max_radii)
