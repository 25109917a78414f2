"""Stage-1 wall time of each row of the grayscale comparison under one preset, side by side: the equal budget.

Each variant (``conf/variant``) trains its whole stage 1 as ``arcsem experiment=grayscale_comparison
preset=quick variant=... threads=1`` composes it (the real trainer, one thread, no evaluation, no
checkpoints) on the built-in scene; the figure is the training time the trainer reports (steps only,
``TrainResult.time_s``). Variants alternate within each repeat (the order reversed every other repeat) and
the table gives the median over repeats, the seconds per step, and each variant's time relative to the
reference (2DGS + ACT). For a ray backbone it also prints the steps that would fill the reference's time
at its measured seconds per step: the numbers to put into its ``conf/tuning/quick_<backbone>.yaml``.

    .venv/bin/python benchmarks/bench_budget.py                      # plenoxels and gs2d_act, once
    .venv/bin/python benchmarks/bench_budget.py --variants plenoxels,gs3d,gs2d,gs2d_act --repeats 3

Runs take the whole schedule (minutes each); load from other processes inflates all of them alike only
when they run at the same time: quote the load average printed with the table.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import torch

REFERENCE = "gs2d_act"


def compose(variant: str, preset: str, extra: list[str]):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module

    over = ["experiment=grayscale_comparison", f"preset={preset}", f"variant={variant}", "threads=1", *extra]
    with initialize_config_module("arcsem.conf", version_base="1.3"):
        return hydra_compose("config", overrides=over)


def train_time(variant: str, preset: str, extra: list[str], seed: int = 0) -> dict:
    """Train one variant's stage 1 (no evaluation) -> ``{"time_s", "steps", "primitives"}``."""
    from arcsem.app import seed_everything
    from arcsem.data import load_scene
    from arcsem.train import LoopConfig, train
    from arcsem.train.stage1 import act_config, build_model, prepare_scene, stage1_losses, train_config

    cfg = compose(variant, preset, extra)
    torch.set_num_threads(1)
    seed_everything(seed)
    tc = train_config(cfg)
    scene = prepare_scene(load_scene(cfg.dataset), tc)
    backbone, act = build_model(cfg, scene, tc)
    loop = LoopConfig(steps=tc.steps, stage="geometry", batch_views=tc.batch_views,
                      rays_per_batch=tc.rays_per_batch or int(getattr(backbone, "rays_per_step", 1)),
                      log_every=tc.log_every, checkpoint_every=0, resume="never", seed=seed, progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        res = train(backbone, scene.train, stage1_losses(cfg, tc, act), loop, optim=tc.optim, ckpt_dir=Path(tmp),
                    act=act, act_lr=act_config(cfg).lr)
    return {"time_s": res.time_s, "steps": res.steps, "primitives": int(backbone.num_primitives()),
            "rays": getattr(backbone, "rays_per_step", None)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default=f"plenoxels,{REFERENCE}")
    ap.add_argument("--preset", default="quick")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--override", action="append", default=[], help="extra Hydra override for every run")
    a = ap.parse_args()
    variants = a.variants.split(",")
    times: dict[str, list[dict]] = {v: [] for v in variants}
    t0 = time.time()
    for r in range(a.repeats):
        for v in (variants if r % 2 == 0 else variants[::-1]):
            times[v].append(train_time(v, a.preset, a.override))
            res = times[v][-1]
            print(f"repeat {r + 1}: {v:>10} {res['time_s']:8.1f} s for {res['steps']} steps "
                  f"({res['primitives']} primitives)", flush=True)
    med = {v: statistics.median(x["time_s"] for x in runs) for v, runs in times.items()}
    ref = med.get(REFERENCE)
    print(f"\n{'variant':>10} {'stage 1 s':>10} {'steps':>6} {'s/step':>7} {'vs ' + REFERENCE:>12}")
    for v, runs in times.items():
        steps = runs[0]["steps"]
        rel = f"{med[v] / ref:11.2f}x" if ref else "n/a"
        print(f"{v:>10} {med[v]:10.1f} {steps:6d} {med[v] / steps:7.3f} {rel:>12}")
    for v, runs in times.items():
        if ref and runs[0]["rays"] and v != REFERENCE:
            steps = runs[0]["steps"]
            print(f"{v}: {steps} steps of {runs[0]['rays']} rays take {med[v]:.0f} s; {REFERENCE}'s {ref:.0f} s "
                  f"would allow {round(steps * ref / med[v])} steps (scale train.steps and the step-based keys of "
                  f"conf/tuning/{a.preset}_{v}.yaml by {ref / med[v]:.2f})")
    load = os.getloadavg()
    print(f"median of {a.repeats} repeat(s); threads 1; wall {time.time() - t0:.0f} s; load average "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; {os.cpu_count()} cores; torch {torch.__version__}")


if __name__ == "__main__":
    main()
