"""``colorize.validate=auto``: stage 2's settings chosen by the scene itself, each reference held out in turn.

With two or more references, each reference ``r`` in turn is treated as a view nobody coloured: what stage 2 would
train towards on it is built from the other references and scored against ``r``'s own artist colours, over its
specimen pixels. Closed form, no training: a few seconds per reference. The declared grid (:data:`GRID`):

* **the pseudo-colour target**: the surface spread on or off (``colorize.surface.mode``) x the shading transfer on
  or off (``colorize.shading``) x the grey prior on or off (``colorize.prior``). Scored by its mean squared error
  over every specimen pixel of ``r``; a pixel the target does not reach is scored as what stage 2 leaves there:
  the other references' colour at its grey with the prior, its grey without (the stage-1 model's). The setting
  with the least error is chosen; pseudo-colours alone (all off) is one of the eight. An addition switched off in
  the config stays off (:func:`grid`: an ablation is one);
* **TCM** is kept where its guarded guidance lies closer to the truth in the TCM loss space than the chosen
  target image (the same locations, mean cosine distance), and the colours its matches bring closer to the truth's
  (squared error of the cell colours) than the target's: a loss space of features without meaning (VGG16 with random
  weights) can be nearer where the colour is further; **CCM** where its targets lie closer (squared error) to
  the truth's cell colours than the target's cell means on the cells it acts on. Both are scored where they act in
  training: with ``colorize.guard.uncovered_only`` on the cells the target leaves before the prior (there the
  target image holds the prior, or the grey), less the background when ``colorize.background=auto`` gives it a target (:func:`acting_cover`).
  Where they act nowhere, or lose, their weight becomes 0.

With **one reference** nothing can be held out whole, so its specimen pixels are: split into a left and a right
half (at the median column), each half in turn scribbles the surface spread and fits the prior, and the other half
scores what they give it (:func:`validate_single`: the surface spread x the prior, the shading as configured; the
half's pixels are what no scribble shows, the case of the spread and the prior). TCM and CCM are left to the
guard's match check (``colorize.guard.check``).

So the chosen setting is never worse than pseudo-colours alone on the validation. The scores and the choice are
recorded in ``metrics.json`` (``stage2.validation``).
"""
from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F
from torch import Tensor

from ..imageops import downscale, patch_means
from .background import fit_background
from .guidance import cell_colours
from .prior import fit_grey_prior, grey_prior
from .pseudocolor import pseudo_colors
from .shading import fit_shading, shade
from .surface import surface_colors

__all__ = [
    "GRID",
    "acting_cover",
    "apply_choice",
    "grid",
    "guide_choice",
    "held_out_targets",
    "target_error",
    "validate",
    "validate_single",
    "without_losses",
]

GRID = [{"surface": s, "shading": h, "prior": p} for s in ("fill", "off") for h in ("auto", "off")
        for p in ("grey", "off")]


def grid(cc) -> list[dict[str, str]]:
    """The settings of :data:`GRID` the config allows: an addition switched off in ``cc`` (the stage-2 config)
    stays off (an ablation), so pseudo-colours alone is always among them."""
    on = {"surface": cc.surface.mode, "shading": cc.shading, "prior": cc.prior}
    return [g for g in GRID if all(g[k] == "off" or on[k] != "off" for k in on)]


def held_out_targets(cams, depth: Tensor, normal: Tensor, masks: Tensor, grey: Tensor, ridx: list[int],
                     images: Tensor, r: int, cc, graph=None) -> dict[str, Tensor]:
    """What the other references give view ``ridx[r]``: 2-D pseudo-colours and surface colours, each with the grey
    they were painted on (``[H, W, 4]``) and their pixels (``[H, W]``), the shading line of the others and their
    grey prior on the view (``[H, W, 3]``, :mod:`arcsem.colorize.prior`; the grey where they have no specimen pixel)
    (``graph``: the views' surface graph, :func:`arcsem.colorize.surface.build_graph`, built once for all)."""
    v, others = ridx[r], [i for i in range(len(ridx)) if i != r]
    carried = torch.cat([images[others].float(), grey[[ridx[i] for i in others]][..., None]], -1)
    sub = [ridx[i] for i in others] + [v]
    p, pv = pseudo_colors(cams[torch.as_tensor(sub)], depth[sub], masks[sub], list(range(len(others))), carried,
                          cc.radius, cc.radius_factor, progress=False)
    s, sv, _ = surface_colors(cams, depth, masks, grey, normal, [ridx[i] for i in others], carried, cc.surface, graph)
    a, b = fit_shading(images[others], grey[[ridx[i] for i in others]], masks[[ridx[i] for i in others]])
    lut = fit_grey_prior(images[others], grey[[ridx[i] for i in others]], masks[[ridx[i] for i in others]])
    plain = grey[v].float()[..., None].expand(*grey[v].shape, 3)
    return {"pseudo": p[-1], "pseudo_valid": pv[-1], "surface": s[v], "surface_valid": sv[v], "shading": (a, b),
            "prior": grey_prior(lut, grey[v]) if lut is not None else plain, "plain": plain}


def target_image(t: dict[str, Tensor], grey: Tensor, surface: str, shading: str, prior: str = "off"
                 ) -> tuple[Tensor, Tensor]:
    """The target ``[H, W, 3]`` of one grid setting on a held-out view of grey ``[H, W]`` and its pixels before
    the prior ``[H, W]``; the other pixels hold the prior (``prior="grey"``) or the grey."""
    col, ok = t["pseudo"], t["pseudo_valid"]
    if surface == "fill":
        fill = t["surface_valid"] & ~ok
        col, ok = torch.where(fill[..., None], t["surface"], col), ok | fill
    a, b = t["shading"] if shading == "auto" else (1.0, 0.0)
    rest = t["prior"] if prior == "grey" else t["plain"]
    rgb = torch.where(ok[..., None], shade(col[..., :3], col[..., 3], grey, a, b), rest)
    return rgb, ok


def target_error(rgb: Tensor, truth: Tensor, mask: Tensor) -> float:
    """Mean squared error over the mask's pixels (``rgb``, ``truth`` ``[H, W, 3]``)."""
    return float(((rgb - truth.float()) ** 2).sum(-1)[mask].mean() / 3) if bool(mask.any()) else float("nan")


def _guide_scores(guidance, v: int, rgb: Tensor, truth: Tensor, space, tcm_downscale: int, ccm_downscale: int,
                  covered: Tensor | None = None):
    """``(tcm guidance, tcm target, ccm guidance, ccm target, tcm colour guidance, tcm colour target)`` distances to
    the truth on view ``v``'s guarded locations (NaN where a loss acts nowhere): TCM in its loss space and by the
    colours its matches bring (:meth:`~arcsem.colorize.guidance.Guidance.carried`, against the cell colours); with
    ``covered [H, W]`` (the target's pixels), only on the cells the target leaves, as in training
    (``colorize.guard.uncovered_only``)."""
    t = dict(guidance.targets(v))
    if covered is not None:
        from .guard import uncovered_cells

        free = lambda ok: ok & uncovered_cells(covered[None], tuple(ok.shape[-2:]))[0]
        t["ccm_valid"] = free(t["ccm_valid"])
        t["tcm_valid"] = [free(t["tcm_valid"][b] if "tcm_valid" in t else torch.ones(g.shape[1:], dtype=torch.bool))
                          for b, g in enumerate(t["tcm_guidance"])]
    with torch.no_grad():
        f_truth = space(downscale(truth[None].float(), tcm_downscale))
        f_rgb = space(downscale(rgb[None].float(), tcm_downscale))
    g_err, r_err, gc_err, rc_err, n = 0.0, 0.0, 0.0, 0.0, 0
    for b, guide in enumerate(t["tcm_guidance"]):
        ok = t["tcm_valid"][b] if "tcm_valid" in t else torch.ones(guide.shape[1:], dtype=torch.bool)
        if bool(ok.any()):
            g_err += float((1 - F.cosine_similarity(guide[None].float(), f_truth[b], dim=1)[0])[ok].mean())
            r_err += float((1 - F.cosine_similarity(f_rgb[b], f_truth[b], dim=1)[0])[ok].mean())
            brought, cells = guidance.carried(v, f"tcm{b}")[0].float(), cell_colours(truth[None], tuple(ok.shape))
            sel = ok.reshape(-1)
            gc_err += float(((brought - cells) ** 2)[sel].mean())
            rc_err += float(((cell_colours(rgb[None], tuple(ok.shape)) - cells) ** 2)[sel].mean())
            n += 1
    cells, truth_cells = patch_means(rgb[None], ccm_downscale)[0], patch_means(truth[None].float(), ccm_downscale)[0]
    ok = t["ccm_valid"]
    c = (float(((t["ccm_target"] - truth_cells) ** 2)[ok].mean()), float(((cells - truth_cells) ** 2)[ok].mean())) \
        if bool(ok.any()) else (float("nan"), float("nan"))
    nan = float("nan")
    return (g_err / n, r_err / n, *c, gc_err / n, rc_err / n) if n else (nan, nan, *c, nan, nan)


def acting_cover(ok: Tensor, mask: Tensor, cc, ref_colors: Tensor, ref_grey: Tensor, ref_masks: Tensor):
    """The cells TCM/CCM leave alone in training on a held-out view, as ``[H, W]`` (None: they act everywhere):
    with ``colorize.guard.uncovered_only``, the target's pixels ``ok``, and with ``colorize.background=auto`` (when
    the other references give a background line) the pixels outside the specimen ``mask`` too, which the
    background target holds. ``ref_*``: the other references' colours ``[R', H, W, 3]``, grey and masks."""
    if not (cc.guard.enabled and cc.guard.uncovered_only):
        return None
    if cc.background == "auto" and fit_background(ref_colors, ref_grey, ref_masks) is not None:
        return ok | ~mask.bool()
    return ok


def validate(cams, depth: Tensor, normal: Tensor, masks: Tensor, grey: Tensor, ridx: list[int], images: Tensor, cc,
             guidance=None) -> dict:
    """Scores of every grid setting and the choice (:func:`apply_choice` reads it).

    Args: cams, depth ``[N, H, W]``, normal ``[N, H, W, 3]``, masks, grey ``[N, H, W]``: every training view;
        ridx: ``R >= 2`` reference views; images ``[R, H, W, 3]`` their colours; cc: the stage-2 config;
        guidance: the run's TCM/CCM guidance of all ``R`` references (None: TCM/CCM are not scored), held out
        from with :meth:`~arcsem.colorize.guidance.Guidance.without`.
    """
    from .surface import build_graph

    name = lambda g: f"{g['surface']}/{g['shading']}/{g['prior']}"
    settings = grid(cc)
    errs = {name(g): [] for g in settings}
    guide = {"tcm": [], "ccm": [], "tcm_colour": []}
    graph = build_graph(cams, depth, masks, grey, normal, cc.surface)
    for r in range(len(ridx)):
        v = ridx[r]
        t = held_out_targets(cams, depth, normal, masks, grey, ridx, images, r, cc, graph)
        for g in settings:
            rgb, _ = target_image(t, grey[v], g["surface"], g["shading"], g["prior"])
            errs[name(g)].append(target_error(rgb, images[r], masks[v]))
        guide["rgb_" + str(r)] = t  # kept for the TCM/CCM scores below
    mean = {k: sum(e) / len(e) for k, e in errs.items()}
    best = min(mean, key=mean.get)
    surface, shading, prior = best.split("/")
    out = {"references": len(ridx), "target_mse": mean, "surface": surface, "shading": shading, "prior": prior}
    if guidance is not None:
        for r in range(len(ridx)):
            held = guidance.without(r)
            rgb, ok = target_image(guide["rgb_" + str(r)], grey[ridx[r]], surface, shading, prior)
            rest = [i for i in range(len(ridx)) if i != r]
            others = [ridx[i] for i in rest]
            acts = acting_cover(ok, masks[ridx[r]], cc, images[rest], grey[others], masks[others])
            s = _guide_scores(held, ridx[r], rgb, images[r], held.space, held.tcm_downscale, held.ccm_downscale, acts)
            guide["tcm"].append(s[:2])
            guide["ccm"].append(s[2:4])
            guide["tcm_colour"].append(s[4:])
        out.update(guide_choice(guide))
    return out


def guide_choice(scores: dict[str, list[tuple[float, float]]]) -> dict[str, dict]:
    """Whether TCM and CCM are kept, from the held-out references' ``(guidance, target)`` distances (NaN: the loss
    acts nowhere on that view) under ``tcm`` (loss space), ``tcm_colour`` and ``ccm``: each kept where its mean
    distance is below the target's over the views where it acts; TCM in its loss space and in colour both."""
    out = {}
    for k in ("tcm", "ccm", "tcm_colour"):
        pairs = [p for p in scores[k] if p[0] == p[0]]  # not NaN
        g, t = (sum(p[0] for p in pairs) / len(pairs), sum(p[1] for p in pairs) / len(pairs)) if pairs else (1, 0)
        out[k] = {"guidance": g, "target": t, "keep": bool(pairs) and g < t}
    colour = out.pop("tcm_colour")
    out["tcm"].update(colour_guidance=colour["guidance"], colour_target=colour["target"],
                      keep=out["tcm"]["keep"] and colour["keep"])
    return out


def validate_single(cams, depth: Tensor, normal: Tensor, masks: Tensor, grey: Tensor, v: int, image: Tensor, cc
                    ) -> dict:
    """One reference (view ``v``, colours ``image [H, W, 3]``): the surface spread and the prior chosen with half
    of its specimen pixels held out in turn (the left and right of the median column); other arguments as
    :func:`validate`. Returns the scores (``target_mse`` by ``surface/prior``) and the choice."""
    from .surface import build_graph, surface_colors

    graph = build_graph(cams, depth, masks, grey, normal, cc.surface)
    m = masks[v].bool()
    cols = torch.nonzero(m)[:, 1]
    errs = {f"{g['surface']}/{g['prior']}": [] for g in grid(cc) if g["shading"] == "off"}
    if len(cols) < 32:
        return {"references": 1, "split": "halves", "target_mse": {}, "surface": cc.surface.mode,
                "shading": cc.shading, "prior": cc.prior}
    left = m & (torch.arange(m.shape[1])[None] < cols.median())
    plain = grey[v].float()[..., None].expand(*m.shape, 3)
    for seen, held in ((left, m & ~left), (m & ~left, left)):
        s, sv, _ = surface_colors(cams, depth, masks, grey, normal, [v], image[None].float(), cc.surface, graph,
                                  ref_keep=seen[None])
        lut = fit_grey_prior(image[None], grey[v][None], seen[None])
        rest = {"grey": grey_prior(lut, grey[v]) if lut is not None else plain, "off": plain}
        for key, err in errs.items():
            sm, pm = key.split("/")
            rgb = torch.where((sv[v] & (sm == "fill"))[..., None], s[v][..., :3], rest[pm])
            err.append(target_error(rgb, image, held))
    mean = {k: sum(e) / len(e) for k, e in errs.items()}
    surface, prior = min(mean, key=mean.get).split("/")
    return {"references": 1, "split": "halves", "target_mse": mean, "surface": surface, "shading": cc.shading,
            "prior": prior}


def without_losses(cc, names: list[str]):
    """``cc`` (the stage-2 config) with the weight of each loss in ``names`` set to 0."""
    losses = {k: dict(v) for k, v in (cc.losses or {}).items()}
    for k in names:
        if k in losses:
            losses[k]["weight"] = 0.0
    return dataclasses.replace(cc, losses=losses)


def apply_choice(cc, choice: dict):
    """``cc`` (the stage-2 config) with the validation's choice: surface mode, shading, prior, TCM/CCM weights (0
    where dropped)."""
    cc = without_losses(cc, [k for k in ("tcm", "ccm") if k in choice and not choice[k]["keep"]])
    return dataclasses.replace(cc, surface=dataclasses.replace(cc.surface, mode=choice["surface"]),
                               shading=choice["shading"], prior=choice.get("prior", cc.prior))
