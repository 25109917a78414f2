"""Stage 2: colour a trained grey model from a few artist references (geometry frozen, no ACT).

``run_stage2(cfg, scene, run_dir)`` is what ``arcsem stage=color`` (and the second half of
``stage=all``) runs. Reference views get ``20 x L1``; every other view gets
``lambda_pc * pseudo + lambda_tcm * TCM + lambda_cc * CCM`` (each switchable, ``weight: 0`` = off).
It writes into ``run_dir``: ``colored/<name>.png`` for every training view (input names),
``colorize/pseudo/<name>.png`` (pseudo-colour previews), ``colored_turntable.mp4``, the coloured
model (``colored_model.ply`` for Gaussians), the coloured mesh (``colored_mesh.ply``/``.glb``) and
viewer folder (``colored_viewer/``), ``colorize/views.csv``, and returns the metrics
against ground-truth colour (where the dataset has it; held-out PSNR also inside and outside the
pseudo-colour coverage, :mod:`arcsem.colorize.coverage`) plus ``features``: the TCM/CCM extractor
(``vgg16-imagenet``, ``vgg16-random``, ``daisy``, ``learned``; ``colorize.features``) or ``unused``.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F

from ..devices import run_device
from ..errors import DataError
from ..registry import plain
from ..runconfig import run_config
from ..timing import phase
from .background import background_target, fit_background
from .config import ColorizeConfig
from .guidance import Guidance
from .masks import specimen_masks
from .prior import fit_grey_prior, grey_prior
from .pseudocolor import cached_pseudo_colors, pseudo_colors, pseudo_key, render_depths
from .references import load_references
from .shading import fit_shading, shade
from .targets import ColorTargetHook

__all__ = ["check_stage1_model", "colorize_config", "colorize_losses", "find_stage1", "run_stage2"]

log = logging.getLogger(__name__)


def colorize_config(cfg: Any) -> ColorizeConfig:
    """The validated ``colorize`` group of ``cfg`` (a run's :class:`~arcsem.runconfig.RunConfig`: validated once)."""
    return run_config(cfg).colorize


def colorize_losses(cc: ColorizeConfig, backbone: Any, validated: dict | None = None):
    """The stage-2 :class:`LossSet` (terms with weight 0 dropped), checked against ``backbone`` (class or model);
    ``validated``: the run's cache of the terms' Configs (:meth:`arcsem.runconfig.RunConfig.loss_configs`)."""
    from ..train import build_losses

    terms = {k: v for k, v in (plain(cc.losses) or {}).items() if v is not None and float(v.get("weight", 1)) != 0}
    return build_losses(terms, backbone.provides, backbone.batch_mode, where="colorize.losses", backbone=backbone.name,
                        batch_parts=frozenset({"color"}), validated=validated)


def check_stage1_model(cfg: Any, cc: ColorizeConfig, scene, run_dir: Path) -> Path:
    """The stage-1 checkpoint :func:`find_stage1` finds, after checking it was trained on ``scene``'s dataset."""
    from ..runs import saved_config
    from ..scene import scene_fingerprint

    ckpt = find_stage1(cfg, cc, run_dir)
    saved = saved_config(ckpt).get("dataset_fingerprint")
    here = scene_fingerprint(scene)
    if saved is None:
        raise DataError(f"colorize.stage1: {ckpt} records no dataset fingerprint (an older arcsem); retrain stage 1")
    if saved["hash"] != here["hash"]:
        raise DataError(f"colorize.stage1: {ckpt} was trained on another dataset ({saved['train_views']} training + "
                        f"{saved['test_views']} test views, fingerprint {saved['hash']}) than this run's "
                        f"({here['train_views']} + {here['test_views']} views, {here['hash']}): same views, cameras "
                        "and split are needed")
    return ckpt


def find_stage1(cfg: Any, cc: ColorizeConfig, run_dir: Path) -> Path:
    """The stage-1 checkpoint: ``colorize.stage1`` (file or run folder), this run's, or the shared cache's."""
    cands = []
    if cc.stage1:
        p = Path(cc.stage1)
        cands = [p] if p.is_file() else [p / "checkpoints" / "last.pt"]
    else:
        cands.append(run_dir / "checkpoints" / "last.pt")
        cands.append(run_dir / "stage1" / "checkpoints" / "last.pt")  # share_stage1: link to the shared model
        try:
            from ..share import stage1_dir

            cands.append(stage1_dir(cfg, create=False) / "checkpoints" / "last.pt")
        except Exception as exc:  # noqa: BLE001 (no shared cache configured: not an error)
            log.debug("no shared stage-1 cache: %s", exc)
    for c in cands:
        if c.is_file():
            return c
    raise DataError(f"colorize: no stage-1 checkpoint (looked for {', '.join(map(str, cands))}); "
                    "run stage=gray first or set colorize.stage1=<run dir or checkpoint>")


def _resize_images(x: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """``[N, H, W, 3]`` -> ``[N, h, w, 3]`` box-filtered (as the training images are)."""
    if x.shape[1:3] == (h, w):
        return x
    return F.interpolate(x.permute(0, 3, 1, 2).float(), size=(h, w), mode="area").permute(0, 2, 3, 1)


def _prepare_scene(scene, ckpt: Path, cc: ColorizeConfig):
    """The scene at the colourisation resolution (stage 1's unless ``colorize.downscale/width`` say otherwise)."""
    from ..runs import saved_config
    from ..train.sampling import resize_scene

    saved = saved_config(ckpt).get("train") or {}
    down, width = (cc.downscale, cc.width) if (cc.downscale != 1.0 or cc.width) else \
        (float(saved.get("downscale", 1.0)), saved.get("width"))
    return resize_scene(scene, down, width)


def _pseudo(cc, cfg, ckpt, backbone, split, masks, refs, cache_dir, geo: SurfaceGeometry):
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


def _extractor(cc, cfg, ckpt, backbone, split, masks, cache_dir, features: str | None = None) -> tuple[Any, Any, dict]:
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


def _guide_factory(cc, extractor, space, split, geo: SurfaceGeometry, cache_dir):
    """``(reference view indices, their colours [R, H, W, 3]) -> Guidance`` of this run (guarded where
    ``colorize.guard.enabled``: the stage-1 geometry's descriptors, :mod:`arcsem.colorize.guard`)."""
    geometry = None
    if cc.guard.enabled:
        from .guard import geometry_descriptors

        geometry = geometry_descriptors(split.cameras.to(device="cpu"), *geo.value)
    return lambda idx, images: Guidance(extractor, space, split.images, idx, images, cc.tcm_downscale,
                                        cc.ccm_downscale, cc.ccm_max_dist, cc.ccm_white, cache_dir,
                                        geometry=geometry, guard=cc.guard)


def _surface_points(split, geo: SurfaceGeometry) -> tuple[torch.Tensor, float]:
    """The stage-1 surface point of every pixel ``[N, H, W, 3]`` (NaN: none) and a pixel's median world size."""
    from .pseudocolor import pixel_footprint

    depth, _ = geo.value
    cams = split.cameras.to(device="cpu", dtype=torch.float64)
    pts = cams.unproject(depth.double())
    pts = torch.where((depth > 0)[..., None], pts, torch.full_like(pts, float("nan")))
    foot = pixel_footprint(cams, depth.double().reshape(len(depth), -1))[(depth > 0).reshape(len(depth), -1)]
    return pts, float(foot.median()) if foot.numel() else 1.0


def _agree(guidance: Guidance, split, geo: SurfaceGeometry, tol: float) -> dict[str, float]:
    """The guidance's cross-view agreement test on the stage-1 surface points of every pixel."""
    return guidance.agree(*_surface_points(split, geo), tol)


def _match_check(cc, guidance: Guidance, split, refs, masks, pseudo, valid2d, geo: SurfaceGeometry, prior_rgb=None):
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
                        (*_surface_points(split, geo), cc.radius_factor))
    return without_losses(cc, [k for k, c in check.items() if not c["keep"]]), check


def _validate(cc, split, masks, refs, geo: SurfaceGeometry, guidance):
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


def _pseudo_quality(split, masks, refs, colors, valid, name: str = "coverage") -> dict:
    """Share of the non-reference views' mask pixels that ``valid`` holds (``name``) and, where the dataset has
    colour, the mean absolute error of ``colors`` there against it (``mae_vs_gt``)."""
    others = [i for i in range(len(split)) if i not in set(refs.indices.tolist())]
    out = {name: float(valid[others].sum() / masks[others].sum().clamp_min(1)) if others else float("nan")}
    if split.colors is not None and others and bool(valid[others].any()):
        err = (colors[others] - split.colors[others]).abs()[valid[others]]
        out["mae_vs_gt"] = float(err.mean())
    return out


def run_stage2(cfg: Any, scene, run_dir: str | Path) -> dict:
    """Colour the stage-1 model; returns ``{"stage2": {...}, "features": <extractor label>|"unused"}``."""
    from ..runs import load_stage1
    from ..share import cache_root
    from ..train import LoopConfig, train
    from ..train.evaluate import write_views_csv
    from ..train.trend import loss_trend_warning
    from .outputs import evaluate_and_write, write_colored_products

    run_dir = Path(run_dir)
    rc = run_config(cfg)
    cfg, cc = rc.cfg, rc.colorize
    timings: dict[str, float] = {}
    with phase(timings, "prepare"):  # the stage-1 model, references, masks
        ckpt = check_stage1_model(cfg, cc, scene, run_dir)
        refs = load_references(scene, cc.references)  # validated against the dataset's views
        backbone, _ = load_stage1(ckpt, scene, cfg)  # (resizes the scene as stage 1 did, internally)
        scene = _prepare_scene(scene, ckpt, cc)
        backbone.set_act(None)  # stage 2 never uses ACT (the paper found it hurt colourisation)
        split = scene.train
        refs.images = _resize_images(refs.images, split.cameras.height, split.cameras.width)
        masks = specimen_masks(split, cc.masks, cc.mask_folder, cc.sam_checkpoint)
        cache_dir = Path(cc.cache_dir) if cc.cache_dir else cache_root(cfg) / "colorize"
        geo = SurfaceGeometry(backbone, split)
    extractor, space, finfo, make = None, None, None, None
    validated = rc.loss_configs("colorize.losses")
    with phase(timings, "guidance"):  # features, the reference-by-reference validation
        if any(n in colorize_losses(cc, backbone, validated).terms for n in ("tcm", "ccm")):
            extractor, space, finfo = _extractor(cc, cfg, ckpt, backbone, split, masks, cache_dir, rc.features)
            make = _guide_factory(cc, extractor, space, split, geo, cache_dir)
        guidance = make(refs.indices.tolist(), refs.images) if make is not None else None
        cc, validation = _validate(cc, split, masks, refs, geo, guidance)
    with phase(timings, "pseudo"):
        pseudo, valid, pinfo = _pseudo(cc, cfg, ckpt, backbone, split, masks, refs, cache_dir, geo)
    prior_rgb = pinfo.pop("prior_rgb", None)
    losses = colorize_losses(cc, backbone, validated)
    if any(n in losses.terms for n in ("tcm", "ccm")):
        t0 = time.perf_counter()
        for i in range(len(split)):  # once per view, before training (cached on disk)
            guidance.matches(i)
        if cc.guard.enabled:
            finfo["agreement_dropped"] = _agree(guidance, split, geo, cc.guard.views_tol)
            if cc.guard.check and (validation is None or validation["references"] < 2):  # else the validation
                cc, finfo["match_check"] = _match_check(cc, guidance, split, refs, masks, pseudo, pinfo["valid2d"], geo,
                                                         prior_rgb)
                losses = colorize_losses(cc, backbone, validated)
        finfo["time_s"] += time.perf_counter() - t0
        timings["matches_s"] = time.perf_counter() - t0
    if not any(n in losses.terms for n in ("tcm", "ccm")):
        guidance, space = None, None
    hook = ColorTargetHook(refs, pseudo, valid, guidance, space, cc.tcm_downscale, cc.ccm_downscale,
                           uncovered_only=cc.guard.enabled and cc.guard.uncovered_only, covered=pinfo["covered"])
    hook.to(run_device(cfg))  # the targets, the guidance and the loss space's extractor follow the model
    loop = LoopConfig(steps=cc.steps, stage="color", batch_views=cc.batch_views, frozen_mb=cc.frozen_mb,
                      log_every=cc.log_every, checkpoint_every=cc.checkpoint_every, resume=cc.resume,
                      seed=int(cfg.get("seed", 0)),
                      progress=cc.progress, desc=f"stage 2 ({backbone.name})")
    with phase(timings, "train"):
        res = train(backbone, split, losses, loop, optim=cc.optim, ckpt_dir=run_dir / "colorize" / "checkpoints",
                    config={"colorize": plain(cfg.get("colorize")), "stage1": str(ckpt), "pseudo": pinfo["key"]},
                    batch_hook=hook)
    backbone.eval()
    if res.history:  # stage 2's loss (and its terms) per logged step, as stage 1's train_history.csv
        write_views_csv(run_dir / "colorize" / "train_history.csv", res.history)
    features = finfo["label"] if guidance is not None else "unused"
    result = evaluate_and_write(backbone, scene, refs, run_dir, cc, (masks, pinfo["valid2d"]), (pseudo, valid), timings)
    with phase(timings, "products"):  # the coloured mesh and viewer
        result.update(write_colored_products(rc, backbone, scene, run_dir, res.steps, cc.progress))
    record = {**_pseudo_quality(split, masks, refs, pseudo, pinfo["valid2d"]), "cache_hit": pinfo["cache_hit"],
              "time_s": pinfo["time_s"], "shading": pinfo["shading"]}
    covered = pinfo["covered"] & masks.bool()
    if "surface" in pinfo:  # what each fill gave, and how close to the truth where the dataset has colour
        record["surface"] = {**pinfo["surface"], **_pseudo_quality(split, masks, refs, pseudo,
                                                                   covered & ~pinfo["valid2d"], "filled")}
    if "background" in pinfo:
        record["background"] = pinfo["background"]
    if "prior" in pinfo:
        record["prior"] = {**pinfo["prior"], **_pseudo_quality(split, masks, refs, pseudo, valid & ~pinfo["covered"],
                                                                 "filled")}
    result.update(
        features=features, references=refs.names, losses=sorted(losses.terms), steps=res.steps, time_s=res.time_s,
        steps_per_s=res.steps_per_s, frozen_renders=res.frozen, stage1_checkpoint=str(ckpt), image_size=[split.cameras.width, split.cameras.height],
        pseudo=record, guidance_time_s=finfo["time_s"] if guidance is not None else 0.0,
        feature_extractor=finfo, final_loss=res.history[-1]["loss"] if res.history else None,
        validation=validation)
    warning = loss_trend_warning(res.history, loop.desc)
    if warning:
        log.warning(warning)
        result["warnings"] = [warning]
    return {"stage2": result, "features": features, "timings": timings}
