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

from ..devices import run_device
from ..errors import DataError
from ..registry import plain
from ..runconfig import run_config
from ..timing import phase
from .config import ColorizeConfig
from .inputs import (
    SurfaceGeometry,
    agree_across_views,
    check_matches,
    feature_extractor,
    guidance_factory,
    prepare_scene,
    pseudo_target,
    resize_images,
    validate_settings,
)
from .masks import specimen_masks
from .references import load_references
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
        scene = prepare_scene(scene, ckpt, cc)
        backbone.set_act(None)  # stage 2 never uses ACT (the paper found it hurt colourisation)
        split = scene.train
        refs.images = resize_images(refs.images, split.cameras.height, split.cameras.width)
        masks = specimen_masks(split, cc.masks, cc.mask_folder, cc.sam_checkpoint)
        cache_dir = Path(cc.cache_dir) if cc.cache_dir else cache_root(cfg) / "colorize"
        geo = SurfaceGeometry(backbone, split)
    extractor, space, finfo, make = None, None, None, None
    validated = rc.loss_configs("colorize.losses")
    with phase(timings, "guidance"):  # features, the reference-by-reference validation
        if any(n in colorize_losses(cc, backbone, validated).terms for n in ("tcm", "ccm")):
            extractor, space, finfo = feature_extractor(cc, cfg, ckpt, backbone, split, masks, cache_dir, rc.features)
            make = guidance_factory(cc, extractor, space, split, geo, cache_dir)
        guidance = make(refs.indices.tolist(), refs.images) if make is not None else None
        cc, validation = validate_settings(cc, split, masks, refs, geo, guidance)
    with phase(timings, "pseudo"):
        pseudo, valid, pinfo = pseudo_target(cc, cfg, ckpt, backbone, split, masks, refs, cache_dir, geo)
    prior_rgb = pinfo.pop("prior_rgb", None)
    losses = colorize_losses(cc, backbone, validated)
    if any(n in losses.terms for n in ("tcm", "ccm")):
        t0 = time.perf_counter()
        for i in range(len(split)):  # once per view, before training (cached on disk)
            guidance.matches(i)
        if cc.guard.enabled:
            finfo["agreement_dropped"] = agree_across_views(guidance, split, geo, cc.guard.views_tol)
            if cc.guard.check and (validation is None or validation["references"] < 2):  # else the validation
                cc, finfo["match_check"] = check_matches(cc, guidance, split, refs, masks, pseudo, pinfo["valid2d"], geo,
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
