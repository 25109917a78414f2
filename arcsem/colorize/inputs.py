"""What stage 2 trains towards, built before its training from the frozen stage-1 model and the references: the
scene at the colourisation resolution, the model's depth and normals (:class:`SurfaceGeometry`), the pseudo-colour
target (:func:`pseudo_target`), the TCM/CCM features and guidance, and the checks that decide which of them act
(:func:`validate_settings`, :func:`check_matches`). :func:`arcsem.colorize.stage2.run_stage2` calls them in turn;
the benchmarks that score the targets without training call the same functions.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from ..errors import DataError
from .background import background_target, fit_background
from .config import ColorizeConfig
from .guidance import Guidance
from .prior import fit_grey_prior, grey_prior
from .pseudocolor import cached_pseudo_colors, pseudo_colors, pseudo_key, render_depths
from .shading import fit_shading, shade

__all__ = ["SurfaceGeometry", "agree_across_views", "check_matches", "feature_extractor", "guidance_factory",
           "prepare_scene", "pseudo_target", "resize_images", "surface_points", "validate_settings"]


def resize_images(x: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """``[N, H, W, 3]`` -> ``[N, h, w, 3]`` box-filtered (as the training images are)."""
    if x.shape[1:3] == (h, w):
        return x
    return F.interpolate(x.permute(0, 3, 1, 2).float(), size=(h, w), mode="area").permute(0, 2, 3, 1)


def prepare_scene(scene, ckpt: Path, cc: ColorizeConfig):
    """The scene at the colourisation resolution (stage 1's unless ``colorize.downscale/width`` say otherwise)."""
    from ..runs import saved_config
    from ..train.sampling import resize_scene

    saved = saved_config(ckpt).get("train") or {}
    down, width = (cc.downscale, cc.width) if (cc.downscale != 1.0 or cc.width) else \
        (float(saved.get("downscale", 1.0)), saved.get("width"))
    return resize_scene(scene, down, width)


def pseudo_target(cc, cfg, ckpt, backbone, split, masks, refs, cache_dir, geo: SurfaceGeometry):
    """The pseudo-colour target ``[N, H, W, 3]`` and its pixels ``[N, H, W]`` of every training view: the 2-D
    pseudo-colours (:mod:`.pseudocolor`), completed by the surface spread (:mod:`.surface`, ``colorize.surface``)
    and shaded for each view (:mod:`.shading`, ``colorize.shading``), the background's line of the grey outside the
    specimen masks (:mod:`.background`, ``colorize.background``) and, on the specimen pixels none of these reach,
    the references' colour at the pixel's grey (:mod:`.prior`, ``colorize.prior``); returns them and what to
    record (``covered``: the pixels before the prior)."""
    t0 = time.perf_counter()
    depth_src = ckpt if cc.depth == "model" else split.depths
    if cc.depth == "dataset" and split.depths is None:
        raise DataError("colorize.depth=dataset but the dataset has no depth maps; use depth: model")
    grey = split.images.float().mean(-1).cpu()  # [N, H, W]
    ridx = refs.indices.tolist()
    carried = torch.cat([refs.images.float(), grey[ridx][..., None]], -1)  # colour + the grey it was painted on
    key = pseudo_key(depth_src, carried, refs.names, cc.radius, cc.radius_factor, masks, split.cameras)

    def compute():
        depths = geo.value[0] if cc.depth == "model" else split.depths  # one render of every view serves both
        return pseudo_colors(split.cameras, depths, masks, ridx, carried, cc.radius, cc.radius_factor,
                             progress=cc.progress)

    colors, valid, hit = cached_pseudo_colors(cache_dir, key, compute)
    info = {"cache_hit": hit, "time_s": time.perf_counter() - t0, "key": key}
    info["valid2d"] = valid  # the 2-D pseudo-colours' reach: the coverage split of the metrics
    if cc.surface.mode == "fill":
        colors, valid, info["surface"] = _surface_fill(cc, geo, split, masks, carried, ridx, cache_dir, key, colors,
                                                       valid)
    a, b = fit_shading(refs.images, grey[ridx], masks[ridx]) if cc.shading == "auto" else (1.0, 0.0)
    info["shading"] = {"mode": cc.shading, "a": a, "b": b}
    colors = torch.where(valid[..., None], shade(colors[..., :3], colors[..., 3], grey, a, b), colors[..., :3])
    if cc.background == "auto":  # the substrate: the references' background colour as a line of the grey
        line = fit_background(refs.images, grey[ridx], masks[ridx])
        info["background"] = line or {"pixels": 0}
        if line is not None:
            rgb, where = background_target(grey, masks, line)
            where = where & ~valid
            colors, valid = torch.where(where[..., None], rgb, colors), valid | where
    info["covered"] = valid  # what the evidence reaches: TCM/CCM act on the cells it leaves
    if cc.prior == "grey":  # the specimen pixels still without a target: the references' colour at their grey
        lut = fit_grey_prior(refs.images, grey[ridx], masks[ridx])
        where = masks.bool() & ~valid
        if lut is not None:
            info["prior_rgb"] = grey_prior(lut, grey)  # [N, H, W, 3]; the match check's guess too
            colors, valid = torch.where(where[..., None], info["prior_rgb"], colors), valid | where
        info["prior"] = {"filled_px": int(where.sum()) if lut is not None else 0}
    return colors, valid, info


class SurfaceGeometry:
    """The stage-1 model's z-depth ``[N, H, W]`` (0 where alpha < 0.5) and unit world normals ``[N, H, W, 3]`` of
    every view of ``split``, on the CPU, rendered on first use (``.value``) and kept for the run's other users."""

    def __init__(self, backbone, split):
        self.backbone, self.split, self._value = backbone, split, None

    @property
    def value(self) -> tuple[torch.Tensor, torch.Tensor]:
        if self._value is None:
            from ..visual import render_layers

            layers = [render_layers(self.backbone, self.split.cameras[i:i + 1]) for i in range(len(self.split))]
            depth = torch.cat([torch.where(x["valid"], x["depth"], torch.zeros_like(x["depth"])).cpu() for x in layers])
            self._value = depth, torch.cat([x["normal"].cpu() for x in layers])
        return self._value


def _surface_fill(cc, geo: SurfaceGeometry, split, masks, carried, ridx, cache_dir, key, colors, valid):
    """The 2-D pseudo-colours ``colors [N, H, W, C]``, ``valid [N, H, W]`` completed with the surface spread of the
    references' ``carried [R, H, W, C]`` (:mod:`arcsem.colorize.surface`) where they have none; returns them and what
    to record."""
    from dataclasses import asdict

    from .pseudocolor import cache_key
    from .surface import surface_colors

    t0, figures = time.perf_counter(), {}

    def compute():
        depth, normal = geo.value
        cols, ok, figs = surface_colors(split.cameras.to(device="cpu"), depth, masks, split.images.float().mean(-1).cpu(),
                                        normal, ridx, carried, cc.surface)
        figures.update(figs)
        return cols, ok

    skey = cache_key("surface-v1", key, asdict(cc.surface))
    scol, sok, hit = cached_pseudo_colors(cache_dir, skey, compute)
    fill = sok & ~valid
    colors = torch.where(fill[..., None], scol, colors)
    info = {**figures, "cache_hit": hit, "filled_px": int(fill.sum()), "time_s": time.perf_counter() - t0}
    return colors, valid | fill, info


def feature_extractor(cc, cfg, ckpt, backbone, split, masks, cache_dir, features: str | None = None) -> tuple[Any, Any, dict]:
    """The TCM/CCM feature extractor (``colorize.features``, or ``features``: that name as the run's check resolved
    it), its loss space and what to record."""
    from .features import SceneContext, build_extractor, tcm_space
    from .features.base import space_label
    from .pseudocolor import cache_key

    t0 = time.perf_counter()
    from_model = cc.depth == "model"
    ctx = SceneContext(gray=split.images, cameras=split.cameras, masks=masks,
                       depths=(lambda: render_depths(backbone, split)) if from_model else (lambda: split.depths),
                       depth_key=cache_key(Path(ckpt)) if from_model else cache_key(split.depths),
                       seed=int(cfg.get("seed", 0)), downscale=cc.tcm_downscale, cache_dir=cache_dir,
                       progress=cc.progress)
    extractor = build_extractor(features or cc.features, ctx)
    space = tcm_space(cc.tcm_space, extractor)
    info = {"requested": cc.features, "name": extractor.name, "label": extractor.label(),
            "tcm_space": space_label(space), "time_s": time.perf_counter() - t0}
    if hasattr(extractor, "weights_detail"):
        info["weights"] = extractor.weights_detail
    if hasattr(extractor, "info"):
        info["training"] = extractor.info
    return extractor, space, info


def guidance_factory(cc, extractor, space, split, geo: SurfaceGeometry, cache_dir):
    """``(reference view indices, their colours [R, H, W, 3]) -> Guidance`` of this run (guarded where
    ``colorize.guard.enabled``: the stage-1 geometry's descriptors, :mod:`arcsem.colorize.guard`)."""
    geometry = None
    if cc.guard.enabled:
        from .guard import geometry_descriptors

        geometry = geometry_descriptors(split.cameras.to(device="cpu"), *geo.value)
    return lambda idx, images: Guidance(extractor, space, split.images, idx, images, cc.tcm_downscale,
                                        cc.ccm_downscale, cc.ccm_max_dist, cc.ccm_white, cache_dir,
                                        geometry=geometry, guard=cc.guard)


def surface_points(split, geo: SurfaceGeometry) -> tuple[torch.Tensor, float]:
    """The stage-1 surface point of every pixel ``[N, H, W, 3]`` (NaN: none) and a pixel's median world size."""
    from .pseudocolor import pixel_footprint

    depth, _ = geo.value
    cams = split.cameras.to(device="cpu", dtype=torch.float64)
    pts = cams.unproject(depth.double())
    pts = torch.where((depth > 0)[..., None], pts, torch.full_like(pts, float("nan")))
    foot = pixel_footprint(cams, depth.double().reshape(len(depth), -1))[(depth > 0).reshape(len(depth), -1)]
    return pts, float(foot.median()) if foot.numel() else 1.0


def agree_across_views(guidance: Guidance, split, geo: SurfaceGeometry, tol: float) -> dict[str, float]:
    """The guidance's cross-view agreement test on the stage-1 surface points of every pixel."""
    return guidance.agree(*surface_points(split, geo), tol)


def check_matches(cc, guidance: Guidance, split, refs, masks, pseudo, valid2d, geo: SurfaceGeometry, prior_rgb=None):
    """:func:`arcsem.colorize.guard.match_check` on the non-reference views (``prior_rgb [N, H, W, 3]``: the grey
    prior's colours, the guess without matches; None: the references' mean colour), the matches searched beyond the
    pseudo-colours' search radius (``colorize.radius_factor`` cells) from each location's own surface point: the
    config without the losses whose matches carry no colour, and the scores."""
    from .guard import match_check
    from .validate import without_losses

    others = [i for i in range(len(split)) if i not in set(refs.indices.tolist())]
    ref_masks = masks[refs.indices]
    if prior_rgb is not None:  # what the uncovered cells hold without matches: the prior
        guess = prior_rgb
    elif bool(ref_masks.any()):
        guess = refs.images.float()[ref_masks].mean(0)
    else:
        guess = refs.images.float().mean((0, 1, 2))
    check = match_check(guidance, others, pseudo.cpu(), valid2d.cpu(), guess,
                        (*surface_points(split, geo), cc.radius_factor))
    return without_losses(cc, [k for k, c in check.items() if not c["keep"]]), check


def validate_settings(cc, split, masks, refs, geo: SurfaceGeometry, guidance):
    """``colorize.validate=auto`` (:mod:`arcsem.colorize.validate`; one reference: its halves): the config with
    the scene's own choice and the scores (None: not validated)."""
    from .validate import apply_choice, validate, validate_single

    if cc.validate != "auto":
        return cc, None
    t0 = time.perf_counter()
    depth, normal = geo.value
    args = (split.cameras.to(device="cpu"), depth, normal, masks, split.images.float().mean(-1).cpu())
    choice = validate(*args, refs.indices.tolist(), refs.images, cc, guidance) if len(refs) >= 2 else \
        validate_single(*args, int(refs.indices[0]), refs.images[0], cc)
    choice["time_s"] = time.perf_counter() - t0
    return apply_choice(cc, choice), choice
