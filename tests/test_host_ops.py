"""What a GPU's host issues in a training step: every operator is a call the host makes before the GPU can run it
(benchmarks/gpu/op_count.py counts them by site). The trainer's own bookkeeping must not grow with the model's parts
nor cost anything when nobody profiles. Checked on the CPU with a dispatch mode that sees every operator."""
from __future__ import annotations

from collections import Counter

import torch
from test_step_syncs import _run
from torch.utils._python_dispatch import TorchDispatchMode

from arcsem.cameras import Cameras
from arcsem.imageops import gaussian_window
from arcsem.train import loop as loop_module


class Ops(TorchDispatchMode):
    """Counts dispatched operators by name."""

    def __init__(self):
        super().__init__()
        self.names: Counter = Counter()
        self.regions: Counter = Counter()  # profiler regions entered, by name

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = str(func.overloadpacket.__name__)
        self.names[name] += 1
        if name == "_record_function_enter_new":
            self.regions[args[0]] += 1
        return func(*args, **(kwargs or {}))


def test_profiler_regions_issue_nothing_without_a_profiler_and_are_seen_with_one():
    run, losses, hook = _run("gs2d", "geometry")
    loop_module._step(run, losses, hook, 0, record=False)
    with Ops() as ops:
        loop_module._step(run, losses, hook, 1, record=False)
    ours = {n: c for n, c in ops.regions.items() if n.startswith("arcsem::") or "zero_grad" in n}
    assert not ours, f"profiler regions dispatched operators with no profiler running: {ours}"
    assert set(ops.regions) == {"Optimizer.step#Adam.step"}, ops.regions  # torch.optim's own, one an optimiser
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        loop_module._step(run, losses, hook, 2, record=False)
    names = {e.name for e in prof.events()}
    for want in ("arcsem::sample", "arcsem::render", "arcsem::render/sh", "arcsem::loss/l1", "arcsem::backward",
                 "arcsem::optimizer", "arcsem::densify/stats"):
        assert want in names, f"{want} missing from the profile: {sorted(n for n in names if 'arcsem' in n)}"


def _health_ops(groups: int) -> int:
    health = loop_module._Health(every=1000)
    params = {f"g{i}": [torch.nn.Parameter(torch.randn(5 + i, 3))] for i in range(groups)}
    terms = {"l1": torch.tensor(0.5, requires_grad=True) * 2, "dssim": torch.tensor(0.1)}
    health.record(None, 0, terms, params, {})  # the first record sets the layout
    with Ops() as ops:
        health.record(None, 1, terms, params, {})
    return sum(ops.names.values())


def test_the_finiteness_notes_issue_a_few_operators_whatever_the_number_of_groups():
    few, many = _health_ops(2), _health_ops(12)
    assert few == many <= 8, f"finiteness notes: {few} operators for 2 groups, {many} for 12"


def test_the_finiteness_notes_still_name_the_first_bad_step():
    health = loop_module._Health(every=1000)
    p = torch.nn.Parameter(torch.ones(4))
    params, terms = {"xyz": [p]}, {"l1": torch.tensor(1.0)}
    for step in range(5):
        if step == 2:
            with torch.no_grad():
                p[1] = float("nan")
        health.record(None, step, terms, params, {})
    assert health.first.tolist() == [-1, 2]


def test_camera_centres_are_kept_until_the_pose_changes():
    w2c = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    w2c[:, :3, 3] = torch.tensor([[1.0, 2.0, 3.0], [0.0, -1.0, 4.0]], dtype=torch.float64)
    cams = Cameras(w2c, torch.eye(3, dtype=torch.float64).repeat(2, 1, 1), 8, 6)
    first = cams.centers
    assert torch.equal(first, -w2c[:, :3, 3])
    with Ops() as ops:
        again, moved = cams.centers, cams.to(dtype=torch.float64).centers
    assert again is first and moved is first and not ops.names, ops.names
    with Ops() as ops:
        one = cams[1]
        assert torch.equal(one.centers, first[1:])
    assert ops.names["bmm"] == 0, ops.names  # sliced from the batch's, not computed again
    with torch.no_grad():
        cams.world_to_cam[0, 0, 3] = 5.0  # in place: the version changes
    assert cams.centers[0, 0].item() == -5.0
    cams.world_to_cam = w2c[:1].clone()
    assert cams.centers.shape == (1, 3)
    pose = w2c.clone().requires_grad_(True)  # a pose being optimised: never kept (its graph would outlive the step)
    cams = Cameras(pose, torch.eye(3, dtype=torch.float64).repeat(2, 1, 1), 8, 6)
    assert cams.centers is not cams.centers
    cams.centers.sum().backward()
    assert pose.grad is not None


def test_the_ssim_window_is_made_once_and_is_an_ordinary_tensor():
    with torch.inference_mode():
        g = gaussian_window(11, 1.5, torch.float32)
    assert not g.is_inference() and not g.requires_grad
    assert gaussian_window(11, 1.5, torch.float32) is g
    assert gaussian_window(11, 1.5, torch.float64) is not g
    x = torch.arange(11, dtype=torch.float64) - 5
    ref = torch.exp(-x**2 / (2 * 1.5**2))
    torch.testing.assert_close(gaussian_window(11, 1.5, torch.float64), ref / ref.sum())


def test_derived_values_follow_the_batch_and_its_intrinsics():
    """Values kept on a batch (the normal-consistency loss's affine rays here) are sliced into an indexed batch,
    equal to what it would compute itself, and made again when the intrinsics change in place."""
    from arcsem.losses.fused import _affine_rays, _affine_rays_of
    from test_fused_losses import _nc_inputs

    _, _, _, cams = _nc_inputs(False)
    whole = _affine_rays(cams, torch.float64)
    assert _affine_rays(cams, torch.float64) is whole
    one = cams[1]
    with Ops() as ops:
        kept = _affine_rays(one, torch.float64)
    assert set(ops.names) == {"slice"}, ops.names  # the whole batch's value, sliced
    with Ops() as ops:
        assert _affine_rays(one, torch.float64) is kept
    assert not ops.names, ops.names
    for a, b in zip(kept, _affine_rays_of(one, torch.float64)):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-15)
    with torch.no_grad():
        one.K[0, 0, 0] *= 2  # a view's own intrinsics changed in place: nothing kept holds
    fresh = _affine_rays(one, torch.float64)
    assert not torch.equal(fresh[1], kept[1])
    for a, b in zip(fresh, _affine_rays_of(one, torch.float64)):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-15)
