"""colorize.validate=auto (arcsem.colorize.validate): the grid's targets, their score and the choice applied."""
from __future__ import annotations

import torch

from arcsem.colorize.validate import GRID, apply_choice, target_error, target_image
from arcsem.configs import ColorizeConfig


def _targets():
    H, W = 2, 3
    pseudo = torch.zeros(H, W, 4)
    pseudo[0, :] = torch.tensor([0.2, 0.4, 0.6, 0.5])  # row 0: 2-D pseudo-colour, painted on grey 0.5
    surface = torch.zeros(H, W, 4)
    surface[1, :2] = torch.tensor([0.8, 0.2, 0.2, 0.25])  # row 1, columns 0-1: the surface spread
    ok_p = torch.zeros(H, W, dtype=torch.bool)
    ok_p[0] = True
    ok_s = torch.zeros(H, W, dtype=torch.bool)
    ok_s[1, :2] = True
    return {"pseudo": pseudo, "pseudo_valid": ok_p, "surface": surface, "surface_valid": ok_s,
            "shading": (0.0, 1.0), "prior": torch.full((H, W, 3), 0.7), "plain": torch.full((H, W, 3), 0.25)}


def test_target_image_of_each_grid_setting():
    t, grey = _targets(), torch.full((2, 3), 0.25)
    rgb, ok = target_image(t, grey, "off", "off")  # where no target reaches: the grey (stage 1's)
    assert ok.tolist() == [[True] * 3, [False] * 3]
    assert torch.equal(rgb[0, 0], torch.tensor([0.2, 0.4, 0.6])) and torch.equal(rgb[1, 2], torch.tensor([0.25] * 3))
    rgb, ok = target_image(t, grey, "off", "off", "grey")  # ... or the prior, which does not count as covered
    assert ok.tolist() == [[True] * 3, [False] * 3] and torch.equal(rgb[1, 2], torch.tensor([0.7] * 3))
    rgb, ok = target_image(t, grey, "fill", "auto")  # shading L = g: grey 0.5 -> 0.25 halves row 0
    assert ok.tolist() == [[True] * 3, [True, True, False]]
    torch.testing.assert_close(rgb[0, 0], torch.tensor([0.1, 0.2, 0.3]))
    torch.testing.assert_close(rgb[1, 0], torch.tensor([0.8, 0.2, 0.2]))  # painted on grey 0.25: unchanged
    assert len(GRID) == 8 and {"surface": "off", "shading": "off", "prior": "off"} in GRID  # pseudo-colours alone


def test_target_error_is_the_mean_squared_error_over_the_mask():
    truth = torch.zeros(2, 3, 3)
    rgb = torch.zeros(2, 3, 3)
    rgb[0, 0] = torch.tensor([0.3, 0.0, 0.0])  # squared error 0.09 / 3 channels at one of two masked pixels
    mask = torch.zeros(2, 3, dtype=torch.bool)
    mask[0, :2] = True
    assert abs(target_error(rgb, truth, mask) - 0.015) < 1e-7


def test_apply_choice_sets_the_target_and_drops_losses_that_lose():
    cc = ColorizeConfig(losses={"tcm": {"weight": 1.0}, "ccm": {"weight": 5.0}, "pseudo_color": {"weight": 1.0}})
    choice = {"surface": "off", "shading": "auto", "prior": "off", "tcm": {"keep": False}, "ccm": {"keep": True}}
    out = apply_choice(cc, choice)
    assert out.surface.mode == "off" and out.shading == "auto" and out.prior == "off" and cc.prior == "grey"
    assert out.losses["tcm"]["weight"] == 0.0 and out.losses["ccm"]["weight"] == 5.0
    assert cc.losses["tcm"]["weight"] == 1.0  # the input config is left as it was


class _Guidance:
    """TCM guidance and CCM targets right (blue) on the top half of an 8x8 view, wrong (green) on the bottom; the
    TCM matches bring those colours."""

    def targets(self, v):
        tcm = torch.zeros(3, 8, 8)
        tcm[2, :4], tcm[1, 4:] = 1.0, 1.0
        ccm = torch.zeros(2, 2, 3)
        ccm[0, :, 2], ccm[1, :, 1] = 1.0, 1.0
        return {"tcm_guidance": [tcm], "ccm_target": ccm, "ccm_valid": torch.ones(2, 2, dtype=torch.bool)}

    def carried(self, v, name):
        return self.targets(v)["tcm_guidance"][0].permute(1, 2, 0).reshape(-1, 3), None


def test_tcm_and_ccm_are_scored_only_where_they_act():
    """Truth blue on top, red below; the target is wrong (red) on top, where it has pixels, and the flat grey below.
    Over the whole view the guidance wins (it is right on top); on the cells the target leaves, where it acts in
    training (``colorize.guard.uncovered_only``), it loses to the flat guess and is dropped."""
    from arcsem.colorize.validate import _guide_scores

    truth, rgb = torch.zeros(8, 8, 3), torch.full((8, 8, 3), 0.5)
    truth[:4, :, 2], truth[4:, :, 0] = 1.0, 1.0
    rgb[:4] = torch.tensor([1.0, 0.0, 0.0])
    covered = torch.zeros(8, 8, dtype=torch.bool)
    covered[:4] = True
    space = lambda x: [x.permute(0, 3, 1, 2)]  # colour as the feature
    g_tcm, r_tcm, g_ccm, r_ccm, gc_tcm, rc_tcm = _guide_scores(_Guidance(), 0, rgb, truth, space, 1, 4)
    assert g_tcm < r_tcm and g_ccm < r_ccm  # whole view: (0 + 1) / 2 against (1 + 0.42) / 2; 1/3 against 0.46
    assert abs(gc_tcm - 1 / 3) < 1e-6 and abs(rc_tcm - (2 / 3 + 0.25) / 2) < 1e-6  # the colours the matches bring
    g_tcm, r_tcm, g_ccm, r_ccm, gc_tcm, rc_tcm = _guide_scores(_Guidance(), 0, rgb, truth, space, 1, 4, covered)
    assert abs(g_tcm - 1.0) < 1e-6 and abs(r_tcm - (1 - 3 ** -0.5)) < 1e-6  # bottom only: green vs grey
    assert abs(g_ccm - 2 / 3) < 1e-6 and abs(r_ccm - 0.25) < 1e-6
    assert abs(gc_tcm - 2 / 3) < 1e-6 and abs(rc_tcm - 0.25) < 1e-6


def test_tcm_is_kept_only_where_its_matches_bring_better_colour_too():
    """Nearer the truth in the loss space on both held-out references, but the colours its matches bring further
    than the target's on one and in the mean: TCM is dropped; CCM, nearer on the views where it acts, kept."""
    from arcsem.colorize.validate import guide_choice

    nan = float("nan")
    scores = {"tcm": [(0.2, 0.5), (0.3, 0.4)], "tcm_colour": [(0.05, 0.01), (0.02, 0.03)],
              "ccm": [(0.01, 0.02), (nan, nan)]}
    out = guide_choice(scores)
    assert not out["tcm"]["keep"] and out["tcm"]["guidance"] < out["tcm"]["target"]
    assert abs(out["tcm"]["colour_guidance"] - 0.035) < 1e-9 and abs(out["tcm"]["colour_target"] - 0.02) < 1e-9
    assert out["ccm"]["keep"] and out["ccm"]["guidance"] == 0.01
    scores["tcm_colour"][0] = (0.005, 0.01)
    assert guide_choice(scores)["tcm"]["keep"]  # better in both: kept
    assert not guide_choice({**scores, "ccm": [(nan, nan)]})["ccm"]["keep"]  # acts nowhere: dropped


def test_the_background_counts_as_covered_when_it_has_its_own_target():
    """The held-out view's left half is background. With ``colorize.background=auto`` (and background pixels in the
    other references to fit its line) TCM/CCM act only on the uncovered specimen, so they are scored there; with
    ``background=off`` they act on the background too. A guidance right on the specimen and wrong on the background
    wins only in the first case."""
    import dataclasses

    from arcsem.colorize.validate import _guide_scores, acting_cover
    from arcsem.configs import ColorizeConfig

    class Guide:
        def targets(self, v):
            tcm = torch.zeros(3, 8, 8)
            tcm[2, :, 4:], tcm[1, :, :4] = 1.0, 1.0  # right (blue) on the specimen, wrong (green) on the background
            ccm = torch.zeros(2, 2, 3)
            ccm[:, 1, 2], ccm[:, 0, 1] = 1.0, 1.0
            return {"tcm_guidance": [tcm], "ccm_target": ccm, "ccm_valid": torch.ones(2, 2, dtype=torch.bool)}

        def carried(self, v, name):
            return self.targets(v)["tcm_guidance"][0].permute(1, 2, 0).reshape(-1, 3), None

    truth = torch.zeros(8, 8, 3)
    truth[:, 4:, 2], truth[:, :4, 0] = 1.0, 1.0  # blue specimen on the right, red background on the left
    rgb = torch.full((8, 8, 3), 0.5)  # the flat guess everywhere: the target covers nothing
    mask = torch.zeros(8, 8, dtype=torch.bool)
    mask[:, 4:] = True
    ok = torch.zeros(8, 8, dtype=torch.bool)
    refs, ref_grey, ref_masks = torch.rand(1, 16, 16, 3), torch.rand(1, 16, 16), torch.zeros(1, 16, 16, dtype=torch.bool)
    space = lambda x: [x.permute(0, 3, 1, 2)]
    cc = ColorizeConfig()
    scores = {}
    for bg in ("auto", "off"):
        covered = acting_cover(ok, mask, dataclasses.replace(cc, background=bg), refs, ref_grey, ref_masks)
        g_tcm, r_tcm, g_ccm, r_ccm, gc_tcm, rc_tcm = _guide_scores(Guide(), 0, rgb, truth, space, 1, 4, covered)
        scores[bg] = (g_tcm < r_tcm and gc_tcm < rc_tcm, g_ccm < r_ccm)
    assert scores == {"auto": (True, True), "off": (False, False)}
    # no background in the other references: no line, so the background is not covered
    assert acting_cover(ok, mask, cc, refs, ref_grey, torch.ones(1, 16, 16, dtype=torch.bool)).sum() == 0


def _plate(columns):
    """One orthographic view of a flat plate, 16 x 40 px; ``columns``: (first column, grey, colour) of each part."""
    from arcsem.cameras import Cameras, look_at

    H, W = 16, 40
    eye = torch.tensor([[0.0, 0.0, 5.0]], dtype=torch.float64)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    K = torch.tensor([[[10.0, 0, W / 2], [0, 10.0, H / 2], [0, 0, 1]]], dtype=torch.float64)
    grey, image = torch.zeros(1, H, W), torch.zeros(H, W, 3)
    for start, g, c in columns:
        grey[:, :, start:], image[:, start:] = g, torch.tensor(c)
    normals = torch.zeros(1, H, W, 3, dtype=torch.float64)
    normals[..., 2] = 1.0
    return (Cameras(w2c, K, W, H, "orthographic"), torch.full((1, H, W), 5.0, dtype=torch.float64), normals,
            torch.ones(1, H, W, dtype=torch.bool), grey, image)


def test_one_reference_chooses_between_the_surface_spread_and_the_prior_on_its_halves():
    """Each half of the one reference scribbles, the other half scores. Colour by position (red on the left, blue
    elsewhere, one grey): the spread carries it, the prior (one grey: the mean) cannot. Colour by grey (red parts
    of grey 0.3, blue of 0.7, alternating): across a part border the spread brings the neighbour's colour with full
    confidence (the only way out of the part), the prior the right one."""
    from arcsem.colorize.validate import validate_single

    red, blue = [0.9, 0.1, 0.1], [0.1, 0.2, 0.9]
    cc = ColorizeConfig()
    cams, depth, normal, masks, grey, image = _plate([(0, 0.5, red), (10, 0.5, blue)])
    by_position = validate_single(cams, depth, normal, masks, grey, 0, image, cc)
    assert by_position["surface"] == "fill" and by_position["references"] == 1
    assert by_position["target_mse"]["fill/grey"] < 0.75 * by_position["target_mse"]["off/grey"]
    cams, depth, normal, masks, grey, image = _plate([(0, 0.3, red), (10, 0.7, blue), (20, 0.3, red),
                                                      (30, 0.7, blue)])
    by_grey = validate_single(cams, depth, normal, masks, grey, 0, image, cc)
    assert (by_grey["surface"], by_grey["prior"]) == ("off", "grey")
    assert by_grey["target_mse"]["off/grey"] < 0.1 * by_grey["target_mse"]["fill/grey"]


def test_an_addition_switched_off_stays_off_in_the_validation():
    """``colorize.prior=off`` (or the surface spread, the shading): the validation chooses among the rest only, so
    an ablation measures what it says; pseudo-colours alone is always a setting."""
    import dataclasses

    from arcsem.colorize.validate import grid, validate_single

    cc = ColorizeConfig()
    assert grid(cc) == GRID
    no_prior = dataclasses.replace(cc, prior="off")
    assert len(grid(no_prior)) == 4 and all(g["prior"] == "off" for g in grid(no_prior))
    off = dataclasses.replace(no_prior, shading="off", surface=dataclasses.replace(cc.surface, mode="off"))
    assert grid(off) == [{"surface": "off", "shading": "off", "prior": "off"}]
    red, blue = [0.9, 0.1, 0.1], [0.1, 0.2, 0.9]
    args = _plate([(0, 0.3, red), (10, 0.7, blue), (20, 0.3, red), (30, 0.7, blue)])
    cams, depth, normal, masks, grey, image = args
    choice = validate_single(cams, depth, normal, masks, grey, 0, image, no_prior)
    assert set(choice["target_mse"]) == {"fill/off", "off/off"} and choice["prior"] == "off"
