"""Checkpoints: atomic writes, config diffs, resizing loads, optimiser-state round trips."""
from __future__ import annotations

import pytest
import torch
from torch import nn

from arcsem.errors import TrainingError
from arcsem.train.checkpoint import (
    check_config,
    config_diff,
    config_hash,
    flatten,
    load_checkpoint,
    load_module_state,
    save_checkpoint,
)


def test_flatten_and_diff_list_dotted_keys():
    a = {"train": {"steps": 10, "losses": {"l1": {"weight": 0.8}}}, "seed": 0, "backbone": {"name": "gs2d"}}
    b = {"train": {"steps": 20, "losses": {"l1": {"weight": 0.8}, "dssim": {"weight": 0.2}}}, "seed": 0,
         "backbone": {"name": "gs2d"}}
    assert flatten(a) == {"train.steps": 10, "train.losses.l1.weight": 0.8, "seed": 0, "backbone.name": "gs2d"}
    assert config_diff(a, b) == ["train.losses.dssim.weight", "train.steps"]
    assert config_diff(a, a) == []
    assert config_hash(a) == config_hash(dict(reversed(list(a.items()))))  # key order does not matter
    assert config_hash(a) != config_hash(b)
    with pytest.raises(TrainingError, match=r"train\.steps \(10 -> 20\)"):
        check_config(a, b, "x/last.pt")


def test_save_is_atomic_and_keeps_the_old_file_when_writing_fails(tmp_path, monkeypatch):
    path = tmp_path / "ck" / "last.pt"
    save_checkpoint(path, {"step": 1, "w": torch.ones(3)})
    assert load_checkpoint(path)["step"] == 1
    assert not path.with_name("last.pt.tmp").exists()

    def boom(obj, f, *a, **k):
        f.write(b"partial")
        raise RuntimeError("disk full")
    monkeypatch.setattr(torch, "save", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        save_checkpoint(path, {"step": 2})
    monkeypatch.undo()
    assert load_checkpoint(path)["step"] == 1  # the previous checkpoint is intact


def test_unreadable_checkpoint_is_a_training_error(tmp_path):
    bad = tmp_path / "last.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(TrainingError, match="cannot read checkpoint"):
        load_checkpoint(bad)


class Growing(nn.Module):
    """A model whose parameter count changes (like densified Gaussians)."""

    def __init__(self, n):
        super().__init__()
        self.points = nn.Parameter(torch.zeros(n, 3))
        self.register_buffer("counts", torch.zeros(n))


def test_load_module_state_resizes_parameters_and_buffers():
    big = Growing(7)
    with torch.no_grad():
        big.points.copy_(torch.arange(21.0).reshape(7, 3))
        big.counts.fill_(2)
    small = Growing(3)
    load_module_state(small, big.state_dict())
    assert small.points.shape == (7, 3) and torch.equal(small.points, big.points)
    assert torch.equal(small.counts, torch.full((7,), 2.0))
    assert isinstance(small.points, nn.Parameter)


def test_optimiser_state_survives_a_round_trip(tmp_path):
    torch.manual_seed(0)
    m = Growing(4)
    opt = torch.optim.Adam(m.parameters(), lr=0.1)
    for _ in range(3):
        opt.zero_grad()
        (m.points**2 - 1).sum().backward()
        opt.step()
    save_checkpoint(tmp_path / "c.pt", {"model": m.state_dict(), "opt": opt.state_dict()})
    state = load_checkpoint(tmp_path / "c.pt")
    m2 = Growing(1)
    load_module_state(m2, state["model"])
    opt2 = torch.optim.Adam(m2.parameters(), lr=0.1)
    opt2.load_state_dict(state["opt"])
    for mm, oo in ((m, opt), (m2, opt2)):  # one more identical step on both
        oo.zero_grad()
        (mm.points**2 - 1).sum().backward()
        oo.step()
    assert torch.equal(m.points, m2.points)


def test_resume_removes_what_a_killed_checkpoint_write_left(tmp_path):
    """A SIGKILL during a checkpoint write leaves ``.last.pt.<random>.tmp``; the next run of the same command
    removes it (untouched for 30 s: a write in progress keeps its file) and resumes from the checkpoint."""
    import os
    import time

    from test_trainer import build
    from trainer_util import L1_DSSIM, loop, tiny_scene

    from arcsem.train.loop import train
    from arcsem.train.losses import build_losses

    scene = tiny_scene()
    ck = tmp_path / "ck"
    bb = build(scene)
    train(bb, scene.train, build_losses(L1_DSSIM, bb.provides), loop(4), ckpt_dir=ck)
    stale, fresh = ck / ".last.pt.k1ll3d.tmp", ck / ".last.pt.wr1t1ng.tmp"
    stale.write_bytes(b"x" * 1000)
    fresh.write_bytes(b"y")
    os.utime(stale, (time.time() - 120, time.time() - 120))
    res = train(build(scene), scene.train, build_losses(L1_DSSIM, bb.provides), loop(6), ckpt_dir=ck)
    assert res.resumed_from == 4 and not stale.exists() and fresh.exists()
