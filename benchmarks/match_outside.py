"""What the TCM/CCM matches bring where no reference looks, scored before any training.

For a stage-1 run and a reference set, builds stage 2's inputs as a run does (:mod:`arcsem.colorize.inputs`: the
pseudo-colour target with the surface spread, shading and grey prior the validation chooses, the guarded matches
with their cross-view agreement) and scores, against the dataset's true colour on the non-reference training views:

* on the specimen pixels **outside** the references' coverage (decided on the true depth, as the held-out metrics):
  the target stage 2 trains towards, the grey prior alone, and, on the cells where each match kind keeps a match,
  the colour it brings against the target's and the prior's on the same pixels (the question TCM/CCM answer);
* the one-reference **match check** on the covered cells (:func:`arcsem.colorize.guard.match_check`), with the
  matches as found (the reference shows the very point) and searched apart from each location's own point (as a
  point no reference sees must be matched): which of the two predicts the outside?

PSNR in dB over the pooled pixels (cells: each cell's colour on its pixels). The last line counts the decisions in
which each check keeps a loss exactly where its matches beat the prior outside the coverage. No training: seconds
per line::

    .venv/bin/python benchmarks/match_outside.py RUN_DIR [--references one three] [--features auto daisy learned]

RUN_DIR: a run folder (its config.yaml; the stage-1 model found as stage 2 finds it: the run's own, its shared
one, or ``colorize.stage1``); its dataset needs colour and depth (a built-in scene).
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from types import SimpleNamespace

import torch
import torch.nn.functional as F
from omegaconf import OmegaConf

from arcsem.colorize import inputs as prep
from arcsem.colorize.coverage import coverage_masks
from arcsem.colorize.guard import match_check
from arcsem.colorize.masks import specimen_masks
from arcsem.colorize.references import load_references
from arcsem.colorize.stage2 import find_stage1
from arcsem.data import load_scene
from arcsem.runconfig import run_config
from arcsem.runs import load_stage1


def _db(pred, gt, sel) -> float:
    return -10 * math.log10(float(((pred - gt)[sel] ** 2).mean())) if bool(sel.any()) else float("nan")


def open_run(run: Path, refs_spec: str, **colorize) -> SimpleNamespace:
    """A run folder's stage-2 inputs for ``refs_spec`` as stage 2 opens them (``colorize``: overrides of its
    ``colorize`` group, dotted keys): ``rc``, ``cfg``, ``cc``, ``ckpt`` (its stage-1 model, found as stage 2 finds
    it), ``backbone`` (no ACT), ``split`` (the training views at colourisation size), ``refs`` (resized to it) and
    ``masks`` ``[N, H, W]``. Shared by the closed-form stage-2 benchmarks."""
    cfg = OmegaConf.load(run / "config.yaml")
    cfg.colorize.references, cfg.colorize.progress = refs_spec, False
    for key, value in colorize.items():
        OmegaConf.update(cfg, f"colorize.{key}", value)
    rc = run_config(cfg)
    cfg, cc = rc.cfg, rc.colorize
    ckpt = find_stage1(cfg, cc, run)
    scene = load_scene(cfg.dataset)
    refs = load_references(scene, cc.references)
    backbone, _ = load_stage1(ckpt, scene, cfg)
    split = prep.prepare_scene(scene, ckpt, cc).train
    backbone.set_act(None)
    refs.images = prep.resize_images(refs.images, split.cameras.height, split.cameras.width)
    masks = specimen_masks(split, cc.masks, cc.mask_folder, cc.sam_checkpoint)
    return SimpleNamespace(rc=rc, cfg=cfg, cc=cc, ckpt=ckpt, backbone=backbone, split=split, refs=refs, masks=masks)


def score(run: Path, refs_spec: str, features: str, cache: Path) -> dict:
    r = open_run(run, refs_spec, features=features, cache_dir=str(cache))
    rc, cfg, cc, ckpt, backbone, split, refs, masks = (r.rc, r.cfg, r.cc, r.ckpt, r.backbone, r.split, r.refs,
                                                       r.masks)
    geo = prep.SurfaceGeometry(backbone, split)
    extractor, space, _ = prep.feature_extractor(cc, cfg, ckpt, backbone, split, masks, cache, rc.features)
    guidance = prep.guidance_factory(cc, extractor, space, split, geo, cache)(refs.indices.tolist(), refs.images)
    cc, validation = prep.validate_settings(cc, split, masks, refs, geo, guidance)
    pseudo, _, info = prep.pseudo_target(cc, cfg, ckpt, backbone, split, masks, refs, cache, geo)
    prior = info["prior_rgb"]
    for v in range(len(split)):
        guidance.matches(v)
    prep.agree_across_views(guidance, split, geo, cc.guard.views_tol)
    ridx = refs.indices.tolist()
    others = [v for v in range(len(split)) if v not in ridx]
    gt = split.colors.float()
    covered = coverage_masks(split.cameras[ridx], split.depths[ridx], masks[ridx], split.cameras, split.depths,
                             masks.bool())
    outside = masks.bool() & ~covered
    outside[ridx] = False
    out = {"references": refs_spec, "features": extractor.label(), "outside_px": int(outside.sum()),
           "validation": {k: validation[k] for k in ("surface", "prior")} if validation else None,
           "target_db": _db(pseudo, gt, outside), "prior_db": _db(prior, gt, outside), "kinds": {}}
    H, W = gt.shape[1:3]
    for name, grid in guidance.kinds():
        carried = [guidance.carried(v, name) for v in range(len(split))]
        cols = torch.stack([c.reshape(*grid, 3) for c, _ in carried]).permute(0, 3, 1, 2).float()
        keep = torch.stack([k.reshape(grid) for _, k in carried])[:, None].float()
        cols = F.interpolate(cols, size=(H, W), mode="nearest").permute(0, 2, 3, 1)
        sel = outside & (F.interpolate(keep, size=(H, W), mode="nearest")[:, 0] > 0.5)
        out["kinds"][name] = {"kept_outside": float(sel.sum() / outside.sum().clamp_min(1)),
                              "match_db": _db(cols, gt, sel), "target_db": _db(pseudo, gt, sel),
                              "prior_db": _db(prior, gt, sel)}
    points = prep.surface_points(split, geo)
    for label, apart in (("as_found", None), ("apart", (*points, cc.radius_factor))):
        check = match_check(guidance, others, pseudo, info["valid2d"], prior, apart)
        out[f"check_{label}"] = {k: {"match": c["match"], "guess": c["guess"], "keep": c["keep"]}
                                 for k, c in check.items()}
    return out


def carries(r: dict, loss: str) -> bool:
    """Whether ``loss``'s kept matches beat the prior outside the coverage on the pixels where they act (TCM: the
    mean over its blocks of the difference in dB)."""
    k = r["kinds"]
    blocks = ["ccm"] if loss == "ccm" else [n for n in k if n.startswith("tcm")]
    return sum(k[b]["match_db"] - k[b]["prior_db"] for b in blocks) / len(blocks) > 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--references", nargs="+", default=["one"])
    ap.add_argument("--features", nargs="+", default=["auto"])
    ap.add_argument("--cache", type=Path, default=Path("/tmp/arcsem_match_outside"))
    args = ap.parse_args()
    agree = {"as_found": 0, "apart": 0}
    decisions = 0
    for refs in args.references:
        for feats in args.features:
            r = score(args.run, refs, feats, args.cache)
            for loss in ("tcm", "ccm"):
                decisions += 1
                for how in agree:
                    agree[how] += r[f"check_{how}"][loss]["keep"] == carries(r, loss)
            print(json.dumps(r))
            line = " ".join(f"{k} kept {x['kept_outside']:.2f} match {x['match_db']:.2f} / prior {x['prior_db']:.2f}"
                            for k, x in r["kinds"].items())
            check = " ".join(f"{k}: {c['match']:.4f} vs {c['guess']:.4f} ({'keep' if c['keep'] else 'drop'}) -> "
                             f"apart {r['check_apart'][k]['match']:.4f} ({'keep' if r['check_apart'][k]['keep'] else 'drop'})"
                             for k, c in r["check_as_found"].items())
            print(f"# {args.run.name} {refs} {r['features']}: outside {r['outside_px']} px, target "
                  f"{r['target_db']:.2f} dB, prior {r['prior_db']:.2f} dB | {line} | check {check}")
    print(f"# the check keeps a loss exactly where its matches beat the prior outside: as found {agree['as_found']} "
          f"of {decisions} decisions, apart {agree['apart']} of {decisions}")


if __name__ == "__main__":
    main()
