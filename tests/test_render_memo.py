"""RenderMemo: stage 2's post-training metrics and PNGs render each view once, with the same figures as before."""
from __future__ import annotations

import math

import pytest
import torch

from arcsem.colorize.analytic import analytic_scene
from arcsem.colorize.config import ColorizeConfig
from arcsem.colorize.coverage import coverage_metrics
from arcsem.colorize.memo import RenderMemo
from arcsem.colorize.outputs import evaluate_colour
from arcsem.colorize.references import load_references
from arcsem.plugins import BACKBONES


class Counting:
    """A backbone whose renders are counted."""

    def __init__(self, bb):
        self.bb, self.calls = bb, 0

    def render(self, cams, **kw):
        self.calls += 1
        return self.bb.render(cams, **kw)


@pytest.fixture(scope="module")
def setup():
    torch.manual_seed(0)
    scene = analytic_scene(6, 3, 32, 24)
    bb = BACKBONES.build({"name": "gs2d", "random_init_points": 300}, scene=scene)
    bb.eval()
    return scene, bb


def test_each_camera_is_rendered_once_and_handed_out_again(setup):
    scene, bb = setup
    counting = Counting(bb)
    memo = RenderMemo(counting)
    cams = scene.test.cameras
    first = [memo.render(cams[i:i + 1]) for i in range(len(cams))]
    again = [memo.render(cams[i:i + 1]) for i in range(len(cams))]
    assert counting.calls == len(cams) and (memo.renders, memo.hits) == (len(cams), len(cams))
    for a, b in zip(first, again):
        assert a is b and {"rgb", "depth", "alpha"} <= set(a) and all(v.ndim == 4 for v in a.values())
    with torch.no_grad():
        direct = bb.render(cams[1:2])
    assert torch.equal(first[1]["rgb"], direct["rgb"])
    memo.render(cams[0:2])  # several cameras, or options: rendered as asked, not kept
    memo.render(cams[0:1], background=torch.zeros(3))
    assert counting.calls == len(cams) + 2
    assert RenderMemo(bb).name == bb.name == "gs2d"  # anything else is the model's


def test_a_budget_keeps_what_fits_and_renders_the_rest_again(setup):
    scene, bb = setup
    counting = Counting(bb)
    one = sum(v.numel() * v.element_size() for v in RenderMemo(bb).render(scene.test.cameras[0:1]).values())
    memo = RenderMemo(counting, budget_mb=1.5 * one / 2**20)  # room for one view
    for _ in range(2):
        for i in range(3):
            memo.render(scene.test.cameras[i:i + 1])
    assert counting.calls == 5 and memo.hits == 1 and memo.used == one


def test_the_colour_and_coverage_metrics_are_the_same_through_the_memo(setup):
    scene, bb = setup
    refs = load_references(scene, "two")
    cc = ColorizeConfig()
    cc.eval.lpips = False
    masks = scene.train.masks.float()
    valid = torch.ones_like(masks, dtype=torch.bool)
    counting = Counting(bb)
    memo = RenderMemo(counting)
    got = [evaluate_colour(memo, scene, refs, _tmp(), cc), coverage_metrics(memo, scene, refs, masks, valid, cc)]
    want = [evaluate_colour(bb, scene, refs, _tmp(), cc), coverage_metrics(bb, scene, refs, masks, valid, cc)]
    assert _same(got, want)
    assert counting.calls == len(scene.train) + len(scene.test) and memo.hits > 0  # each view once


def _tmp():
    import tempfile
    from pathlib import Path

    return Path(tempfile.mkdtemp())


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return a == b
