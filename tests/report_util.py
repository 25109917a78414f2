"""Run-folder fixtures for the report tests: shaped like what ``arcsem`` writes (metrics.json,
config.yaml, .hydra/overrides.yaml, multirun.yaml, renders/), not mocks of the product."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

GRAY = {  # variant -> (train psnr, ssim, lpips, test psnr, depth pct)
    "plenoxels": (30.0, 0.80, 0.50, 28.0, 2.0),
    "gs3d": (33.5, 0.90, 0.40, 31.0, 1.5),
    "gs2d": (33.0, 0.88, 0.45, 30.5, 0.8),
    "gs2d_act": (34.0, 0.89, 0.42, 31.5, 0.9),
}


def _png(path: Path, value: int, shape=(12, 16, 3)) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full(shape, value, np.uint8))


def _job(sweep: Path, num: int, overrides: list[str], metrics: dict | None, seed: int = 0) -> Path:
    job = sweep / str(num)
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(overrides))
    if metrics is not None:
        (job / "config.yaml").write_text(yaml.safe_dump({"seed": seed, "dataset": {"name": "synthetic"}}))
        full = {"seed": seed, "git": "abc123", "overrides": overrides, **metrics}
        (job / "metrics.json").write_text(json.dumps(full))
    return job


def _sweep(root: Path, experiment: str, key: str, values: list[str]) -> Path:
    root.mkdir(parents=True)
    multirun = {"hydra": {"sweeper": {"params": {key: ",".join(values)}},
                          "overrides": {"task": [f"experiment={experiment}"]}}, "seed": 0}
    (root / "multirun.yaml").write_text(yaml.safe_dump(multirun))
    return root


def _stage1(psnr, ssim, lpips, tpsnr, pct, lpips_note="/root/.cache/torch/hub/checkpoints/alexnet-owt-7be5be79.pth"):
    return {"stage1": {"train_paper": {"psnr": psnr, "ssim": ssim, "lpips": lpips},
                       # the mean-ACT / clean-image score of the training views: a decoy the tables must not show
                       "train": {"psnr": psnr + 50, "ssim": ssim / 2, "lpips": 9.0},
                       "test": {"psnr": tpsnr, "ssim": ssim - 0.01, "lpips": lpips + 0.01},
                       # the trainer's keys; median_abs_pct (the older name) is a decoy the table must not use
                       "depth": {"test_mae": pct / 100, "test_mae_pct": pct, "median_abs_pct": 99.0},
                       "steps": 100, "time_s": 1.0, "num_primitives": 1000, "lpips_weights": lpips_note,
                       "metrics_convention": {"name": "3dgs", "quantise": True, "ssim": "3dgs", "lpips_net": "vgg"}}}
