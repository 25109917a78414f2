"""Train one stage 1 from Hydra overrides and print held-out metrics: a quick look, not a study row.

The real trainer and evaluation code, without the run folder, the cache, videos or meshes: the time per
step every 25 steps (with the primitive count), the training time, the held-out PSNR / SSIM / depth error
(as ``metrics.json``'s ``stage1.test``), and, with ``--figure``, a PNG of two held-out views (ground truth,
render, alpha, normalised depth per row). Used for the Plenoxels tuning runs in benchmarks/results/README.md:

    .venv/bin/python benchmarks/archive/stage1_probe.py backbone=plenoxels act=none threads=1 \\
        backbone.background_model=plane --figure /tmp/plane.png
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch


def compose(overrides: list[str]):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module

    with initialize_config_module("arcsem.conf", version_base="1.3"):
        return hydra_compose("config", overrides=overrides)


def figure(backbone, split, path: Path, views=(0, 4)) -> None:
    """Ground truth, render, alpha and normalised depth of ``views`` of ``split``, one row each."""
    import imageio.v3 as iio

    views = [v for v in views if v < len(split)]
    with torch.no_grad():
        out = backbone.render(split.cameras[views])
    rows = []
    for i, v in enumerate(views):
        a = out["alpha"][i, ..., 0].numpy()
        dep = out["depth"][i, ..., 0].numpy()
        fg = a > 0.5
        lo, span = (dep[fg].min(), max(1e-6, float(np.ptp(dep[fg])))) if fg.any() else (0.0, 1.0)
        dn = np.where(fg, (dep - lo) / span, 0.0)
        grey = lambda x: np.repeat(x[..., None], 3, -1)
        rows.append(np.concatenate([split.images[v].numpy(), out["rgb"][i].clamp(0, 1).numpy(), grey(a), grey(dn)], 1))
    iio.imwrite(path, (np.concatenate(rows, 0) * 255).astype(np.uint8))


def main() -> None:
    from arcsem.app import seed_everything
    from arcsem.data import load_scene
    from arcsem.train import LoopConfig, train
    from arcsem.train.evaluate import evaluate_split
    from arcsem.train.stage1 import act_config, build_model, prepare_scene, stage1_losses, train_config

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("overrides", nargs="*")
    ap.add_argument("--figure", type=Path, default=None)
    a = ap.parse_args()
    cfg = compose(a.overrides)
    torch.set_num_threads(int(cfg.threads or torch.get_num_threads()))
    seed_everything(int(cfg.seed))
    tc = train_config(cfg)
    scene = prepare_scene(load_scene(cfg.dataset), tc)
    bb, act = build_model(cfg, scene, tc)
    stamps = [time.perf_counter()]

    def on_step(s: int, rec: dict) -> None:
        stamps.append(time.perf_counter())
        if s % 25 == 0 or s == tc.steps:
            n = min(25, len(stamps) - 1)
            print(f"step {s}: {(stamps[-1] - stamps[-1 - n]) / n * 1e3:.0f} ms/step, loss {rec['loss']:.4f}, "
                  f"batch PSNR {rec['psnr']:.2f}, primitives {bb.num_primitives()}", flush=True)

    loop = LoopConfig(steps=tc.steps, batch_views=tc.batch_views, log_every=tc.log_every, progress=False,
                      rays_per_batch=tc.rays_per_batch or int(getattr(bb, "rays_per_step", 1)), checkpoint_every=0,
                      resume="never", seed=int(cfg.seed))
    with tempfile.TemporaryDirectory() as tmp:
        res = train(bb, scene.train, stage1_losses(cfg, tc, act), loop, optim=tc.optim, ckpt_dir=Path(tmp), act=act,
                    act_lr=act_config(cfg).lr, on_step=on_step)
    bb.eval()
    with torch.no_grad():
        _, summary, _ = evaluate_split(bb, scene.test, split_name="test", length_scale=scene.scale[0], with_lpips=False)
    keys = ("psnr", "ssim", "psnr_masked", "depth_mae_pct")
    print(f"train time {res.time_s:.1f} s for {res.steps} steps; held-out " +
          ", ".join(f"{k} {summary[k]:.4g}" for k in keys if k in summary))
    if a.figure is not None:
        figure(bb, scene.test, a.figure)


if __name__ == "__main__":
    main()
