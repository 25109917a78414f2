"""Recompute the coverage split of finished stage-2 runs (``stage2.<part>.psnr_covered|uncovered|coverage``)
with the current :mod:`arcsem.colorize.coverage` rule, from each run's coloured model, and update its
``metrics.json`` (atomically; the other metrics are left as they are). For runs made before the rule
changed (``coverage_rule`` absent or older): rule 2 leaves specimen pixels without model surface out of
both parts.

Usage::

    ARCSEM_CACHE=... .venv/bin/python benchmarks/archive/rescore_coverage.py RUN_OR_SWEEP [...] [--force]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
from omegaconf import OmegaConf


def rescore(run: Path) -> dict:
    """The coverage metrics of one run folder (its config, stage-1 model, stage-2 checkpoint and caches)."""
    from arcsem.colorize.coverage import coverage_metrics
    from arcsem.colorize.inputs import prepare_scene as _prepare_scene
    from arcsem.colorize.inputs import pseudo_target as _pseudo
    from arcsem.colorize.inputs import resize_images as _resize_images
    from arcsem.colorize.masks import specimen_masks
    from arcsem.colorize.references import load_references
    from arcsem.colorize.stage2 import colorize_config
    from arcsem.data import load_scene
    from arcsem.runs import load_stage1
    from arcsem.share import cache_root
    from arcsem.train.checkpoint import load_checkpoint, load_module_state

    cfg = OmegaConf.load(run / "config.yaml")
    cc = colorize_config(cfg)
    metrics = json.loads((run / "metrics.json").read_text())
    ckpt = Path(metrics["stage2"]["stage1_checkpoint"])
    scene = load_scene(cfg.dataset)
    refs = load_references(scene, cc.references)
    backbone, _ = load_stage1(ckpt, scene, cfg)
    scene = _prepare_scene(scene, ckpt, cc)
    backbone.act = None
    load_module_state(backbone, load_checkpoint(run / "colorize" / "checkpoints" / "last.pt")["model"])
    backbone.eval()
    split = scene.train
    refs.images = _resize_images(refs.images, split.cameras.height, split.cameras.width)
    masks = specimen_masks(split, cc.masks, cc.mask_folder, cc.sam_checkpoint)
    cache_dir = Path(cc.cache_dir) if cc.cache_dir else cache_root(cfg) / "colorize"
    _, valid, _ = _pseudo(cc, cfg, ckpt, backbone, split, masks, refs, cache_dir)
    with torch.no_grad():
        return coverage_metrics(backbone, scene, refs, masks, valid, cc)


def main(argv=None) -> int:
    from arcsem.app import write_json_atomic
    from arcsem.colorize.coverage import RULE
    from arcsem.report.collect import find_runs

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+")
    ap.add_argument("--force", action="store_true", help="also runs already scored with the current rule")
    a = ap.parse_args(argv)
    for run in find_runs([Path(p) for p in a.paths]):
        metrics = json.loads((run / "metrics.json").read_text())
        s2 = metrics.get("stage2")
        if not isinstance(s2, dict) or not (run / "colorize" / "checkpoints" / "last.pt").exists():
            continue
        if not a.force and (s2.get("test") or {}).get("coverage_rule") == RULE:
            continue
        for part, vals in rescore(run).items():
            s2.setdefault(part, {}).update(vals)
        write_json_atomic(run / "metrics.json", metrics)
        t = s2.get("test", {})
        print(f"{run}: held-out PSNR in cov. {t.get('psnr_covered', float('nan')):.2f}, "
              f"out cov. {t.get('psnr_uncovered', float('nan')):.2f}, coverage {t.get('coverage', float('nan')):.4f}, "
              f"no surface {t.get('no_surface', float('nan')):.4f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
