"""Training views scored as the paper's Table 1 did: each view's own ACT against the observed image.

Runs made since the trainer records both protocols carry this score as ``stage1.train_paper`` in
``metrics.json`` (and the grayscale table shows it); this script re-scores older stage-1 runs the same way
(``evaluate_split(..., protocol="paper")``) and, when runs of two rows share seeds, pairs them.

Usage (run folders with ``config.yaml`` and ``stage1/checkpoints/last.pt``; the dataset must be
readable, e.g. the same ``ARCSEM_CACHE`` as the runs)::

    .venv/bin/python benchmarks/archive/paper_protocol.py SWEEP_OR_RUN [...] [--a gs2d --b gs2d_act]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd
from omegaconf import OmegaConf

from arcsem.data import load_scene
from arcsem.errors import DataError
from arcsem.report.collect import collect
from arcsem.report.paired import describe, pair, summary
from arcsem.runs import load_stage1
from arcsem.train.evaluate import evaluate_split
from arcsem.train.stage1 import prepare_scene, train_config


def observed_scores(run: Path) -> dict[str, float]:
    """Mean PSNR / SSIM of the training views, own ACT, against the observed (noisy, drifting) images."""
    cfg = OmegaConf.load(run / "config.yaml")
    scene = load_scene(cfg.dataset)
    backbone, _ = load_stage1(run / "stage1" / "checkpoints" / "last.pt", scene, cfg)
    train = prepare_scene(scene, train_config(cfg)).train
    _, mean, _ = evaluate_split(backbone, train, split_name="train_paper", with_lpips=False, protocol="paper")
    return {"psnr": mean["psnr"], "ssim": mean["ssim"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+", help="run or sweep folders")
    ap.add_argument("--a", default="gs2d", help="baseline row for the paired summary")
    ap.add_argument("--b", default="gs2d_act", help="compared row")
    args = ap.parse_args(argv)
    try:
        runs = collect(args.paths).runs
    except DataError as err:
        raise SystemExit(f"paper_protocol: {err}") from None
    runs = runs[runs["stage1.train.psnr"].notna()] if "stage1.train.psnr" in runs else runs.iloc[:0]
    if runs.empty:
        raise SystemExit(f"paper_protocol: no stage-1 runs under {args.paths}")
    recs = []
    print("| run | row | seed | train PSNR (own ACT, observed) | SSIM | tables' train PSNR (mean ACT, clean) |")
    print("|---|---|---|---|---|---|")
    for _, r in runs.sort_values(["row", "seed"]).iterrows():
        s = observed_scores(Path(r["run_dir"]))
        recs.append({"row": r["row"], "seed": r["seed"], "run_dir": r["run_dir"],
                     "observed.psnr": s["psnr"], "observed.ssim": s["ssim"]})
        print(f"| {r['run_dir']} | {r['row']} | {r['seed']} | {s['psnr']:.2f} | {s['ssim']:.4f} | "
              f"{r['stage1.train.psnr']:.2f} |", flush=True)
    df = pd.DataFrame.from_records(recs)
    if {args.a, args.b} <= set(df["row"]):
        for metric in ("observed.psnr", "observed.ssim"):
            table, _ = pair(df, args.a, args.b, metric)
            if len(table) > 1:
                print(f"{metric}: {args.b} - {args.a} " + describe(summary(table["delta"], lower=False), args.b))
    return 0


if __name__ == "__main__":
    sys.exit(main())
