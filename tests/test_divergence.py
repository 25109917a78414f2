"""Divergence and a training that makes the model worse: the run says what happened, where, and what is on disk."""
from __future__ import annotations

import pytest
import torch
from test_trainer import build
from trainer_util import L1_DSSIM, loop, tiny_scene

from arcsem.errors import TrainingError
from arcsem.train import loop as loop_module
from arcsem.train.checkpoint import load_checkpoint
from arcsem.train.loop import LoopConfig, train
from arcsem.train.losses import build_losses
from arcsem.train.trend import loss_trend_warning


def _nan_gradient_from(bb, step_from: int):
    """Make the ``image`` group's gradient NaN from training step ``step_from`` on (a diverging update)."""
    calls = {"n": 0}

    def hook(g):
        calls["n"] += 1
        return g * float("nan") if calls["n"] >= step_from else g
    bb.logits.register_hook(hook)


@pytest.mark.parametrize("nan_from,on_disk", [
    (1, "no checkpoint has been written yet ({ckpt} does not exist)"),  # not "the last good one": none exists
    (13, "the checkpoint on disk is from step 10 ({ckpt})"),
])
def test_non_finite_gradient_names_the_step_and_what_is_on_disk(tmp_path, nan_from, on_disk):
    scene = tiny_scene()
    bb = build(scene)
    _nan_gradient_from(bb, nan_from)
    ckpt = tmp_path / "ckpt" / "last.pt"
    with pytest.raises(TrainingError) as info:
        train(bb, scene.train, build_losses(L1_DSSIM, bb.provides), loop(20, checkpoint_every=5),
              ckpt_dir=tmp_path / "ckpt")
    msg = str(info.value)
    assert msg.startswith(f"step {nan_from}: gradient of group 'image' is not finite"), msg
    assert msg.endswith(on_disk.format(ckpt=ckpt)), msg
    assert ckpt.exists() == (nan_from > 5)


def test_a_parameter_made_non_finite_by_the_step_is_named(tmp_path, monkeypatch):
    """Finite gradients, yet the optimiser step leaves a parameter non-finite (here a post-step hook, as an update
    that overflows would): the run stops at that step naming the group and the check, before any checkpoint of it."""
    scene = tiny_scene()
    bb = build(scene)
    steps = {"n": 0}

    def poison(opt, args, kwargs):
        steps["n"] += 1
        if steps["n"] == 7:
            with torch.no_grad():
                bb.logits.view(-1)[3] = float("inf")

    real = loop_module.make_optimizers

    def with_hook(*args, **kwargs):
        optimizers = real(*args, **kwargs)
        optimizers["image"].register_step_post_hook(poison)
        return optimizers
    monkeypatch.setattr(loop_module, "make_optimizers", with_hook)
    with pytest.raises(TrainingError) as info:
        train(bb, scene.train, build_losses(L1_DSSIM, bb.provides), loop(20, checkpoint_every=5),
              ckpt_dir=tmp_path / "ckpt")
    msg = str(info.value)
    assert msg.startswith("step 7: parameter group 'image' is not finite (after the optimiser step)"), msg
    assert msg.endswith(f"the checkpoint on disk is from step 5 ({tmp_path / 'ckpt' / 'last.pt'})"), msg


def test_non_finite_loss_term_is_named():
    scene = tiny_scene()
    bb = build(scene)
    scene.train.images[1, 2, 3, 0] = float("inf")  # a target the reader would refuse; here only the loop's check
    with pytest.raises(TrainingError, match=r"step \d+: loss term 'l1' is not finite \(loss\); training stopped, "
                                            "no checkpoints are written in this run"):
        train(bb, scene.train, build_losses(L1_DSSIM, bb.provides), loop(8))


def test_a_learning_rate_that_wrecks_training_is_warned_about():
    """The issue's case: a rate far too high ends below where it started (PSNR 6 against 13); the run says so."""
    scene = tiny_scene()
    results = {}
    for name, lr in (("sane", 0.05), ("wrecking", 500.0)):
        torch.manual_seed(0)
        bb = build(scene)
        res = train(bb, scene.train, build_losses(L1_DSSIM, bb.provides), loop(100),
                    optim={"groups": {"image": {"lr": lr}}})
        results[name] = res
    sane, bad = results["sane"], results["wrecking"]
    assert bad.history[-1]["psnr"] < bad.history[0]["psnr"] < sane.history[-1]["psnr"], \
        "the test's premise: the high rate made the model worse than at step 1"
    assert loss_trend_warning(sane.history, "stage 1") is None
    warning = loss_trend_warning(bad.history, "stage 1")
    assert warning is not None and "the model got worse while training" in warning and "train.optim" in warning


@pytest.mark.parametrize("check_every", [1, 4])
def test_a_parameter_whose_norm_overflows_is_finite(check_every):
    """The step notes a parameter's finiteness by its norm: two elements of 3e38 (finite float32) have an infinite
    norm, which the read tells apart element by element, every step (CPU) or every few (as on a GPU); training goes
    on."""
    scene = tiny_scene()
    bb = build(scene)
    with torch.no_grad():
        bb.logits.view(-1)[:2] = 3e38  # sigmoid saturates: no gradient, Adam leaves them
    res = train(bb, scene.train, build_losses(L1_DSSIM, bb.provides), loop(8, check_every=check_every))
    assert res.steps == 8 and torch.isinf(torch.linalg.vector_norm(bb.logits.detach()))
    assert torch.isfinite(bb.logits).all()


def test_deferred_checks_name_the_first_bad_step_and_write_nothing_after_it(tmp_path):
    """As on a GPU (checks read every 5 steps): a gradient NaN from step 3 is found at the checkpoint of step 4
    (read before writing), named by its first step; the checkpoint of step 2 stays the one on disk."""
    scene = tiny_scene()
    bb = build(scene)
    _nan_gradient_from(bb, 3)
    ckpt = tmp_path / "ckpt" / "last.pt"
    with pytest.raises(TrainingError) as info:
        train(bb, scene.train, build_losses(L1_DSSIM, bb.provides), loop(20, checkpoint_every=2, check_every=5),
              ckpt_dir=tmp_path / "ckpt")
    msg = str(info.value)
    assert msg.startswith("step 3: parameter group 'image' is not finite (after the optimiser step)"), msg
    assert msg.endswith(f"the checkpoint on disk is from step 2 ({ckpt})"), msg
    assert load_checkpoint(ckpt)["step"] == 2


def test_one_late_heavy_batch_is_not_read_as_a_worse_model():
    """Stage 2 of the demo warned on every seed-0 run: step 1 was a pseudo-colour view (0.127), the last logged step a
    reference view (20x weight, 0.40), while every other late step was far below step 1. A median of the tail does
    not warn; a tail that is high throughout still does."""
    steps = [1, *range(50, 601, 50)]
    mixed = [0.127, 0.09, 0.35, 0.05, 0.04, 0.38, 0.035, 0.03, 0.03, 0.37, 0.028, 0.027, 0.40]
    assert loss_trend_warning([{"step": s, "loss": v} for s, v in zip(steps, mixed)], "stage 2") is None
    worse = [0.127, *(0.2 + 0.01 * k for k in range(12))]
    warning = loss_trend_warning([{"step": s, "loss": v} for s, v in zip(steps, worse)], "stage 2")
    assert warning is not None and "from 0.127 at step 1 to 0.3" in warning and "median of the last 3" in warning


def test_the_trend_compares_the_means_of_the_log_intervals_not_single_batches():
    """Stage 2 on a NeRF-synthetic chair (two references, dataset.grey=true, 200 px) warned "rose from 0.02407 at
    step 1 to 0.04001": one-batch losses at the log steps (step 1 an easy view; late steps views where TCM acts).
    The same job again (below, its colorize/train_history.csv): interval means that fell from 0.044 to 0.031."""
    steps = [1, *range(50, 601, 50)]
    batch = [0.0241, 0.0109, 0.0084, 0.0101, 0.0102, 0.0202, 0.0219, 0.0068, 0.0699, 0.0111, 0.0073, 0.0203, 0.0455]
    means = [0.0241, 0.0437, 0.0436, 0.0368, 0.0360, 0.0331, 0.0351, 0.0268, 0.0386, 0.0270, 0.0369, 0.0308, 0.0322]
    history = [{"step": s, "loss": b, "loss_mean": m} for s, b, m in zip(steps, batch, means)]
    assert not _warns(history)  # the means fell
    rising = [{**h, "loss_mean": 0.03 + 0.002 * k} for k, h in enumerate(history)]  # worse while training
    assert "rose from 0.032 (the mean to step 50) to 0.05" in loss_trend_warning(rising, "stage 2")
    wrecked = [{**h, "loss_mean": 0.06} for h in history]  # at once, then flat: over twice step 1's
    assert "rose from 0.0241 at step 1 (more than twice) to 0.06" in loss_trend_warning(wrecked, "stage 2")


def _warns(history: list[dict]) -> bool:
    return loss_trend_warning(history, "stage 2") is not None


def test_the_logged_mean_is_the_mean_of_the_interval_s_step_losses():
    """``loss_mean`` at a logged step is the mean of every step's loss since the last logged one, also where a
    callback reads every step (which must not restart the interval)."""
    scene = tiny_scene()
    torch.manual_seed(0)
    bb = build(scene)
    seen = {}
    res = train(bb, scene.train, build_losses(L1_DSSIM, bb.provides),
                LoopConfig(steps=9, progress=False, log_every=4, checkpoint_every=0),
                on_step=lambda step, rec: seen.__setitem__(step, rec["loss"]))
    assert [h["step"] for h in res.history] == [1, 4, 8, 9]
    for h, interval in zip(res.history, ([1], [2, 3, 4], [5, 6, 7, 8], [9])):
        assert h["loss_mean"] == pytest.approx(sum(seen[s] for s in interval) / len(interval), rel=1e-5)
