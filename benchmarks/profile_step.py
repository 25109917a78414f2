"""Where a stage-1 training step spends its time: every part, forward and backward, over a real run.

Runs stage 1 as ``arcsem stage=gray`` would (the composed config, the real trainer, densification, checkpoints),
under ``torch.profiler`` in windows of ``--window`` steps, and attributes the time to the named regions the
code marks (``arcsem::render/composite``, ``arcsem::loss/dssim``, ...). A backward op is charged to the region
whose forward op created it (the autograd sequence number links them), so "render/composite" has a forward
and a backward figure. Then the final evaluation (renders, LPIPS, the video) is timed once.

    .venv/bin/python benchmarks/profile_step.py --backbone gs2d                         # 288x192 built-in scene
    .venv/bin/python benchmarks/profile_step.py --backbone gs2d --textured             # 768x512, textured
    .venv/bin/python benchmarks/profile_step.py --backbone gs3d --steps 300 -- train.steps=300   # overrides

Prints a markdown table: seconds per step of every part (forward, backward, both) and its share of the
wall time of the profiled steps; "untracked" is what no region covers (the loop, the progress bar, the
profiler itself). ``--steps N`` profiles only the first N steps of the schedule (the model is smaller early on).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile, schedule

PREFIX = "arcsem::"
BWD = "autograd::engine::evaluate_function: "


def _region(e) -> str | None:
    """Name of the nearest enclosing arcsem region of an event (None: none, or inside a backward node)."""
    p = e.cpu_parent
    while p is not None:
        if p.name.startswith(PREFIX):
            return p.name[len(PREFIX):]
        if p.name.startswith(BWD):
            return None
        p = p.cpu_parent
    return None


def attribute(events, seq_region: dict[int, str]) -> dict[tuple[str, str], float]:
    """``{(part, 'fwd'|'bwd'): microseconds}`` of one profiling window.

    Region self time (less nested regions and backward nodes) is forward time; a backward node goes to the region
    of the forward op with its sequence number (``seq_region``, filled here and kept across windows)."""
    out: dict[tuple[str, str], float] = defaultdict(float)
    nested: dict[int, float] = defaultdict(float)  # id of a region event -> time of what is charged elsewhere
    regions = []
    for e in events:
        name, dur = e.name, e.time_range.elapsed_us()
        if name.startswith(PREFIX):
            regions.append(e)
            p = e.cpu_parent
            while p is not None and not p.name.startswith(PREFIX):
                p = p.cpu_parent
            if p is not None:
                nested[id(p)] += dur
        elif name.startswith(BWD):
            outer = e.cpu_parent
            while outer is not None and not outer.name.startswith((BWD, PREFIX)):
                outer = outer.cpu_parent
            if outer is not None and outer.name.startswith(BWD):
                continue  # nested backward node: counted with its parent
            out[(seq_region.get(e.sequence_nr, "backward: not attributed"), "bwd")] += dur
            if outer is not None:
                nested[id(outer)] += dur
        elif e.sequence_nr >= 0:
            r = _region(e)
            if r is not None:  # the last op that saw a sequence number is the one whose node took it
                seq_region[e.sequence_nr] = r
    for e in regions:
        out[(e.name[len(PREFIX):], "fwd")] += e.time_range.elapsed_us() - nested[id(e)]
    return out


def compose(overrides: list[str]):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module

    with initialize_config_module("arcsem.conf", version_base=None):
        return hydra_compose("config", overrides=overrides)


def profile_stage1(cfg, window: int, run_dir: Path) -> dict:
    """Train stage 1 of ``cfg`` under the profiler; returns per-part microseconds, wall seconds, steps, evaluation."""
    from arcsem.app import seed_everything, set_threads
    from arcsem.data import load_scene
    from arcsem.train.loop import LoopConfig, train
    from arcsem.train.stage1 import (
        act_config,
        build_model,
        evaluate,
        prepare_scene,
        stage1_losses,
        train_config,
    )

    seed_everything(int(cfg.seed))
    set_threads(cfg.get("threads"))
    t0 = time.perf_counter()
    raw = load_scene(cfg.dataset)
    load_s = time.perf_counter() - t0
    tc = train_config(cfg)
    scene = prepare_scene(raw, tc)
    backbone, act = build_model(cfg, scene, tc)
    losses = stage1_losses(cfg, tc, act)
    loop = LoopConfig(steps=tc.steps, stage="geometry", batch_views=tc.batch_views,
                      rays_per_batch=tc.rays_per_batch or int(backbone.rays_per_step), log_every=tc.log_every,
                      checkpoint_every=tc.checkpoint_every, resume="never", seed=int(cfg.seed), progress=False)
    parts: dict[tuple[str, str], float] = defaultdict(float)
    seq_region: dict[int, str] = {}
    prims: list[int] = []
    spent = [0.0]  # seconds spent here, taken off the wall time

    def ready(prof):
        t = time.perf_counter()
        for k, v in attribute(prof.events(), seq_region).items():
            parts[k] += v
        seq_region.clear()  # sequence numbers are not reused; drop the window's
        prims.append(int(backbone.num_primitives()))
        spent[0] += time.perf_counter() - t

    prof = profile(activities=[ProfilerActivity.CPU], schedule=schedule(wait=0, warmup=0, active=window),
                   on_trace_ready=ready)
    t0 = time.perf_counter()
    with prof:
        res = train(backbone, scene.train, losses, loop, optim=tc.optim, ckpt_dir=run_dir / "checkpoints",
                    act=act, act_lr=act_config(cfg).lr, on_step=lambda s, r: prof.step())
    wall = time.perf_counter() - t0 - spent[0]
    backbone.eval()
    t0 = time.perf_counter()
    metrics = evaluate(backbone, scene, run_dir, tc.eval)
    eval_s = time.perf_counter() - t0
    size = (scene.train.cameras.width, scene.train.cameras.height)
    return {"parts": dict(parts), "wall_s": wall, "train_s": res.time_s, "steps": res.steps, "eval_s": eval_s,
            "load_s": load_s, "primitives": prims, "size": size, "metrics": metrics}


def table(r: dict) -> str:
    steps, wall = r["steps"], r["wall_s"]
    per = defaultdict(lambda: [0.0, 0.0])
    for (part, kind), us in r["parts"].items():
        per[part][kind == "bwd"] += us * 1e-6 / steps
    tracked = sum(a + b for a, b in per.values())
    per["untracked (loop, progress, profiler)"] = [wall / steps - tracked, 0.0]
    rows = ["| part | forward s/step | backward s/step | total s/step | share |", "|---|---|---|---|---|"]
    for part, (f, b) in sorted(per.items(), key=lambda kv: -sum(kv[1])):
        rows.append(f"| {part} | {f:.4f} | {b:.4f} | {f + b:.4f} | {100 * (f + b) * steps / wall:.1f} % |")
    rows.append(f"| **step (wall, profiled)** | | | **{wall / steps:.4f}** | 100 % |")
    rows.append(f"| final evaluation (once: renders, LPIPS, video) | | | {r['eval_s']:.1f} s in all | "
                f"{100 * r['eval_s'] / (wall + r['eval_s']):.1f} % of the stage |")
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backbone", default="gs2d", choices=("gs2d", "gs3d", "plenoxels"))
    ap.add_argument("--textured", action="store_true", help="768x512, dataset.texture=0.3 (texture everywhere)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=None, help="profile the first N steps of the schedule only")
    ap.add_argument("--act", default=None, help="act config (default: paper for gs2d, none otherwise)")
    ap.add_argument("--window", type=int, default=25, help="steps per profiler window")
    ap.add_argument("overrides", nargs="*", help="more Hydra overrides (after --)")
    a = ap.parse_args()
    # the grayscale study's variants: 2DGS + ACT, 3DGS and Plenoxels without
    ov = [f"backbone={a.backbone}", "train=quick", f"threads={a.threads}", f"act={a.act or ('paper' if a.backbone == 'gs2d' else 'none')}"]
    if a.textured:
        ov += ["dataset.texture=0.3", "dataset.width=768", "dataset.height=512", "train.width=768"]
    cfg = compose(ov + list(a.overrides))
    if a.steps:
        cfg.train.steps = a.steps
    one, five, _ = os.getloadavg()
    print(f"{a.backbone}, {'768x512 textured' if a.textured else '288x192 built-in'} scene, {a.threads} threads, "
          f"torch {torch.__version__}; load average before {one:.2f} / {five:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        r = profile_stage1(cfg, a.window, Path(tmp))
    one, five, _ = os.getloadavg()
    test = r["metrics"].get("test", {})
    print(f"{r['steps']} steps at {r['size'][0]}x{r['size'][1]}: {r['wall_s']:.1f} s profiled wall "
          f"({r['train_s']:.1f} s in the steps), primitives per window {r['primitives'][0]}..{r['primitives'][-1]}; "
          f"held-out PSNR {test.get('psnr', float('nan')):.2f} dB; load average after {one:.2f} / {five:.2f}")
    print(table(r))


if __name__ == "__main__":
    main()
