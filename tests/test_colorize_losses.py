"""Stage-2 loss plugins on hand-computed values; the batch hook; reference views vs other views."""
import torch
from arcsem.losses.colorize import CCM, TCM, PseudoColor, ReferenceL1, ccm_distance, masked_l1, tcm_distance

from arcsem.colorize.analytic import arc_cameras
from arcsem.colorize.references import References
from arcsem.colorize.targets import ColorTargetHook
from arcsem.plugins import Batch, ColorTargets


def _batch(idx, color=None, h=4, w=4):
    cams = arc_cameras(len(idx), w, h)
    return Batch(cameras=cams, images=torch.zeros(len(idx), h, w, 3), indices=torch.tensor(idx), color=color)


def test_masked_l1_hand_values():
    pred = torch.tensor([[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]])
    tgt = torch.tensor([[[0.3, 0.6, 0.9], [0.0, 0.0, 0.0]]])
    # only the first pixel: (0.3 + 0.6 + 0.9) / 3 = 0.6
    torch.testing.assert_close(masked_l1(pred, tgt, torch.tensor([[True, False]])), torch.tensor(0.6))
    assert masked_l1(pred, tgt, torch.zeros(1, 2, dtype=torch.bool)) == 0


def test_tcm_and_ccm_distances_hand_values():
    f = torch.tensor([[1.0, 0.0], [0.0, 1.0]]).T.reshape(1, 2, 1, 2)  # two locations: e_x, e_y
    g = torch.tensor([[1.0, 0.0], [1.0, 1.0]]).T.reshape(1, 2, 1, 2)
    # 1 - cos: 0 and 1 - 1/sqrt(2); mean over locations; summed over two identical blocks
    expect = 2 * (1 - 2**-0.5) / 2
    torch.testing.assert_close(tcm_distance([f, f], [g, g]), torch.tensor(expect))
    means = torch.tensor([[[[0.5, 0.5, 0.5], [0.0, 0.0, 0.0]]]])
    target = torch.tensor([[[[0.2, 0.5, 0.9], [1.0, 1.0, 1.0]]]])
    # valid only the first cell: 0.09 + 0 + 0.16 = 0.25
    torch.testing.assert_close(ccm_distance(means, target, torch.tensor([[[True, False]]])), torch.tensor(0.25))


def _targets():
    refs = References(names=["a"], indices=torch.tensor([0]), images=torch.full((1, 16, 16, 3), 0.25))
    pseudo = torch.full((3, 16, 16, 3), 0.75)
    valid = torch.zeros(3, 16, 16, dtype=torch.bool)
    valid[:, :8] = True
    return ColorTargetHook(refs, pseudo, valid, guidance=None, tcm_downscale=1, ccm_downscale=8)


def test_hook_and_reference_vs_other_views():
    hook = _targets()
    b = hook(_batch([0, 2], h=16, w=16))
    assert b.color.is_reference.tolist() == [True, False]
    rgb = torch.full((2, 16, 16, 3), 0.5, requires_grad=True)
    out = {"rgb": rgb}
    ref = ReferenceL1(ReferenceL1.Config())(out, b, 0)
    pc = PseudoColor(PseudoColor.Config())(out, b, 0)
    torch.testing.assert_close(ref, torch.tensor(0.25))  # |0.5 - 0.25| on the reference view only
    torch.testing.assert_close(pc, torch.tensor(0.25))  # |0.5 - 0.75| on valid pixels of view 2 only
    (ref + pc).backward()
    assert rgb.grad[0, 12].abs().sum() > 0 and rgb.grad[1, 12].abs().sum() == 0  # view 2: invalid rows
    assert ReferenceL1.Config().weight == 20.0
    b_ref = hook(_batch([0], h=16, w=16))
    assert PseudoColor(PseudoColor.Config())({"rgb": rgb[:1]}, b_ref, 0) == 0


def test_tcm_ccm_read_the_colour_targets():
    feats = lambda x: [x.permute(0, 3, 1, 2)]
    target = torch.rand(1, 8, 8, 3)
    b = _batch([1], h=8, w=8, color=ColorTargets(
        is_reference=torch.tensor([False]), reference=torch.zeros(1, 8, 8, 3), pseudo=torch.zeros(1, 8, 8, 3),
        pseudo_valid=torch.zeros(1, 8, 8, dtype=torch.bool), tcm_space=feats, tcm_downscale=1,
        tcm_guidance=[target.permute(0, 3, 1, 2)], ccm_downscale=4, ccm_target=torch.full((1, 2, 2, 3), 0.5),
        ccm_valid=torch.ones(1, 2, 2, dtype=torch.bool)))
    assert float(TCM(TCM.Config())({"rgb": target * 3}, b, 0)) < 1e-6  # same direction: cos = 1
    assert float(TCM(TCM.Config())({"rgb": 1 - target}, b, 0)) > 0.01
    torch.testing.assert_close(CCM(CCM.Config())({"rgb": torch.full((1, 8, 8, 3), 0.7)}, b, 0),
                               torch.tensor(3 * 0.2**2))


def test_stage2_losses_declare_their_targets_and_stay_out_of_stage1():
    import pytest

    from arcsem.errors import ConfigError
    from arcsem.train.losses import build_losses

    assert all(cls.needs == frozenset({"color"}) for cls in (ReferenceL1, PseudoColor, TCM, CCM))
    with pytest.raises(ConfigError, match="train.losses.tcm: loss 'tcm' needs the batch's \\['color'\\] targets"):
        build_losses({"tcm": {}}, {"rgb"})
    assert "tcm" in build_losses({"tcm": {}}, {"rgb"}, batch_parts=frozenset({"color"})).terms
    with pytest.raises(ConfigError, match="runs in stage 2"):
        PseudoColor(PseudoColor.Config())({"rgb": torch.zeros(1, 4, 4, 3)}, _batch([0]), 0)


class _AllValidGuidance:
    """Guidance stub: every TCM location (one block, 4x4) and CCM cell (2x2) of every view has a target."""

    def targets(self, v):
        return {"tcm_guidance": [torch.ones(2, 4, 4)], "tcm_valid": [torch.ones(4, 4, dtype=torch.bool)],
                "ccm_target": torch.full((2, 2, 3), 0.5), "ccm_valid": torch.ones(2, 2, dtype=torch.bool)}

    def to(self, device):
        return self


def test_tcm_ccm_act_only_where_the_pseudo_colours_do_not_reach():
    """``colorize.guard.uncovered_only``: the top half of each view has pseudo-colours, so TCM keeps only the bottom
    two rows of its 4x4 grid and CCM only the bottom row of cells; off, every location keeps its target."""
    refs = References(names=["a"], indices=torch.tensor([0]), images=torch.full((1, 16, 16, 3), 0.25))
    valid = torch.zeros(3, 16, 16, dtype=torch.bool)
    valid[:, :8] = True
    valid[2, 8:10, :4] = True  # view 2: an eighth of the bottom-left CCM cell also covered (under half: kept)
    args = (refs, torch.full((3, 16, 16, 3), 0.75), valid, _AllValidGuidance(), None, 4, 8)
    on = ColorTargetHook(*args, uncovered_only=True)(_batch([1, 2], h=16, w=16)).color
    assert on.tcm_valid[0].shape == (2, 4, 4) and on.ccm_valid.shape == (2, 2, 2)
    expect_tcm = torch.zeros(2, 4, 4, dtype=torch.bool)
    expect_tcm[:, 2:] = True
    expect_tcm[1, 2, 0] = False  # view 2's covered rows 8-9, columns 0-3: that TCM cell is half covered
    assert torch.equal(on.tcm_valid[0], expect_tcm)
    assert on.ccm_valid.tolist() == [[[False, False], [True, True]]] * 2
    off = ColorTargetHook(*args, uncovered_only=False)(_batch([1, 2], h=16, w=16)).color
    assert bool(off.tcm_valid[0].all()) and bool(off.ccm_valid.all())
    # the grey prior fills every specimen pixel's target; TCM/CCM still act where the evidence (``covered``) does not
    full = (refs, torch.full((3, 16, 16, 3), 0.75), torch.ones(3, 16, 16, dtype=torch.bool), _AllValidGuidance(),
            None, 4, 8)
    prior = ColorTargetHook(*full, uncovered_only=True, covered=valid)(_batch([1, 2], h=16, w=16)).color
    assert torch.equal(prior.tcm_valid[0], expect_tcm) and torch.equal(prior.ccm_valid, on.ccm_valid)
    assert bool(prior.pseudo_valid.all())
    none = ColorTargetHook(*full, uncovered_only=True)(_batch([1, 2], h=16, w=16)).color  # covered = valid: all
    assert not bool(none.ccm_valid.any())


def test_tcm_ccm_skip_their_feature_pass_on_a_batch_of_reference_views():
    """The hook knows on the host which views it drew: a batch of reference views only (5 of the demo's 32 views)
    gives TCM and CCM 0 without running the extractor, and they still run on a mixed batch."""
    calls = []

    def space(x):
        calls.append(x.shape[0])
        return [x.permute(0, 3, 1, 2)]

    hook = _targets()
    hook.space = space
    for idx, expect in (([0], True), ([0, 2], False), ([2], False)):
        assert hook(_batch(idx, h=16, w=16)).color.references_only is expect
    target = torch.rand(1, 16, 16, 3)
    for refs_only in (True, False):
        b = _batch([0] if refs_only else [2], h=16, w=16, color=ColorTargets(
            is_reference=torch.tensor([refs_only]), reference=torch.zeros(1, 16, 16, 3),
            pseudo=torch.zeros(1, 16, 16, 3), pseudo_valid=torch.zeros(1, 16, 16, dtype=torch.bool), tcm_space=space,
            tcm_downscale=1, tcm_guidance=[target.permute(0, 3, 1, 2)], ccm_downscale=4,
            ccm_target=torch.full((1, 4, 4, 3), 0.5), ccm_valid=torch.ones(1, 4, 4, dtype=torch.bool),
            references_only=refs_only))
        rgb = (1 - target).requires_grad_(True)
        tcm, ccm = TCM(TCM.Config())({"rgb": rgb}, b, 0), CCM(CCM.Config())({"rgb": rgb}, b, 0)
        if refs_only:
            assert calls == [] and float(tcm.detach()) == 0 and float(ccm.detach()) == 0
            (tcm + ccm).backward()  # the graph is kept: a loss set of these terms alone still steps
            assert rgb.grad is not None and float(rgb.grad.abs().sum()) == 0
        else:
            assert calls == [1] and float(tcm.detach()) > 0.01 and float(ccm.detach()) > 0


class _TopHalfGuidance(_AllValidGuidance):
    """View 1's matches all lie in the top half (covered by pseudo-colours); view 2's everywhere."""

    def targets(self, v):
        t = super().targets(v)
        if v == 1:
            t["tcm_valid"][0][2:] = False
            t["ccm_valid"][1:] = False
        return t


def test_tcm_ccm_skip_their_pass_where_no_guarded_match_is_left():
    """With ``uncovered_only`` a view whose guarded matches all lie under the pseudo-colours has nothing for TCM/CCM
    to pull (the demo's five references cover every VGG cell: TCM ran VGG each step to add 0): the hook says so on
    the host, TCM skips its feature pass, and the loss and its gradient are what the full pass gives (0)."""
    calls = []

    def space(x):
        calls.append(x.shape[0])
        return [x.permute(0, 3, 1, 2)[:, :2, ::4, ::4]]

    refs = References(names=["a"], indices=torch.tensor([0]), images=torch.full((1, 16, 16, 3), 0.25))
    valid = torch.zeros(3, 16, 16, dtype=torch.bool)
    valid[:, :8] = True
    hook = ColorTargetHook(refs, torch.full((3, 16, 16, 3), 0.75), valid, _TopHalfGuidance(), space, 1, 8,
                           uncovered_only=True)
    assert hook.active == {1: (False, False), 2: (True, True)}
    for idx, idle in (([1], True), ([0, 1], True), ([1, 2], False), ([2], False)):
        c = hook(_batch(idx, h=16, w=16)).color
        assert (c.tcm_idle, c.ccm_idle) == (idle, idle)
    b = hook(_batch([1], h=16, w=16))
    rgb = torch.rand(1, 16, 16, 3, requires_grad=True)
    tcm = TCM(TCM.Config())({"rgb": rgb}, b, 0)
    assert calls == []
    full = tcm_distance(space(rgb), b.color.tcm_guidance, ~b.color.is_reference, b.color.tcm_valid)
    assert float(tcm.detach()) == float(full.detach()) == 0
    tcm.backward()
    assert float(rgb.grad.abs().sum()) == 0
    TCM(TCM.Config())({"rgb": rgb}, hook(_batch([2], h=16, w=16)), 0)
    assert calls == [1, 1]
