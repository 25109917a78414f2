"""Stage 1 on a GPU: steps per second, SM utilisation, host synchronisations and the kernels of a window of steps.

Trains stage 1 of the demo job (``experiment=demo``, the built-in scene) with ``device=cuda`` through the real
trainer, ``--steps`` steps of the 1500-step schedule (densification as in the demo), and measures:

* ``steps_per_s``: steps ``--skip``..``--steps`` (wall, the device synchronised at both ends; the first steps
  include CUDA start-up and kernel compilation);
* ``sm_util_pct``: the mean ``sm`` column of ``nvidia-smi dmon -s u`` sampled once a second over those steps;
* ``syncs_per_step``: host synchronisations per step over ``--window`` steps (``torch.cuda.set_sync_debug_mode``
  warns at each; grouped by the arcsem source line that caused it);
* the profiler's top CUDA kernels and CPU operators over the same window (``torch.profiler``), with the number of
  kernel launches and operator calls per step.

    python benchmarks/gpu/stage1_profile.py --name gs2d -- backbone.rasterizer=auto
    python benchmarks/gpu/stage1_profile.py --name gs2d_gsplat --json out.json -- backbone.rasterizer=gsplat

Prints a summary and, with ``--json``, appends one record to that file (a list of records). Needs a CUDA device.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter
from pathlib import Path

import torch


def compose(overrides: list[str]):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_module

    with initialize_config_module("arcsem.conf", version_base=None):
        return hydra_compose("config", overrides=overrides)


class Dmon:
    """``nvidia-smi dmon -s u`` in the background; :meth:`mean_sm` averages the samples between two marks."""

    def __init__(self):
        self.proc = subprocess.Popen(["nvidia-smi", "dmon", "-s", "u", "-d", "1"], stdout=subprocess.PIPE, text=True)
        self.samples: list[tuple[float, float]] = []
        import threading

        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        for line in self.proc.stdout:
            parts = line.split()
            if parts and parts[0].isdigit() and len(parts) > 1 and parts[1].isdigit():
                self.samples.append((time.time(), float(parts[1])))

    def mean_sm(self, t0: float, t1: float) -> float:
        inside = [s for t, s in self.samples if t0 <= t <= t1 + 0.5]
        return sum(inside) / len(inside) if inside else float("nan")

    def stop(self):
        self.proc.terminate()


def _arcsem_frame(stack: list[traceback.FrameSummary]) -> str:
    for f in reversed(stack):
        if ("arcsem" in f.filename or "/backbones/" in f.filename or "/losses/" in f.filename) and \
                "benchmarks" not in f.filename:
            return f"{Path(f.filename).parent.name}/{Path(f.filename).name}:{f.lineno} {f.line}"
    return "outside arcsem"


def measure(overrides: list[str], steps: int, skip: int, window: int, dmon: Dmon | None, device: str = "cuda") -> dict:
    from torch.profiler import ProfilerActivity, profile

    from arcsem.app import seed_everything
    from arcsem.data import load_scene
    from arcsem.train import loop as loop_module
    from arcsem.train.loop import LoopConfig, train
    from arcsem.train.stage1 import act_config, build_model, prepare_scene, stage1_losses, train_config

    cuda = device == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    debug = torch.cuda.set_sync_debug_mode if cuda else (lambda mode: None)
    cfg = compose(["experiment=demo", f"device={device}", *overrides])
    seed_everything(int(cfg.seed))
    tc = train_config(cfg)
    scene = prepare_scene(load_scene(cfg.dataset), tc)
    backbone, act = build_model(cfg, scene, tc)
    losses = stage1_losses(cfg, tc, act)
    loop = LoopConfig(steps=steps, stage="geometry", batch_views=tc.batch_views, log_every=tc.log_every,
                      checkpoint_every=0, resume="never", seed=int(cfg.seed), progress=False)
    marks: dict[str, float] = {}
    prof = profile(activities=[ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else []))
    w0, w1 = skip + 20, skip + 20 + window  # the sync-counting window, then the profiled one

    def on_step(s: int) -> None:
        if s == skip:
            sync()
            marks["t0"] = time.time()
        if s == w0:
            warnings.simplefilter("always")
            debug("warn")
        if s == w1:
            debug("default")
            prof.start()
        if s == w1 + window:
            sync()
            prof.stop()

    with tempfile.TemporaryDirectory() as tmp:
        t_start = time.time()
        restore = _count_sync_warnings()
        periodic = loop_module._periodic  # called after every step with the run; an on_step callback would make
        loop_module._periodic = lambda run, *a: (on_step(run.step), periodic(run, *a))  # the loop read values back
        try:
            res = train(backbone, scene.train, losses, loop, optim=tc.optim, ckpt_dir=Path(tmp) / "ck", act=act,
                        act_lr=act_config(cfg).lr)
            sync()
        finally:
            loop_module._periodic = periodic
            restore()
        t_end = time.time()
    sites = Counter(_SITES)
    _SITES.clear()
    timed = steps - skip
    sps = timed / (t_end - marks["t0"])
    ka = prof.key_averages()
    annotations = {e.name for e in prof.events() if getattr(e, "is_user_annotation", False)}
    kernels = sorted((e for e in ka if e.device_type == torch.autograd.DeviceType.CUDA and e.key not in annotations
                      and not e.key.startswith("arcsem::")), key=lambda e: -_dev_self(e))  # kernels and copies
    n_launch = sum(e.count for e in ka if e.key.startswith(("cudaLaunchKernel", "cuLaunchKernel", "cudaLaunch")))
    ops = sorted((e for e in ka if e.key.startswith("aten::")), key=lambda e: -e.self_cpu_time_total)
    dev_total = sum(_dev_self(e) for e in kernels)
    out = {
        "overrides": overrides, "device": torch.cuda.get_device_name() if cuda else "cpu", "torch": torch.__version__,
        "steps": steps, "timed_steps": timed, "stage1_steps_per_s": round(sps, 2),
        "wall_all_steps_s": round(t_end - t_start, 2), "primitives": int(backbone.num_primitives()),
        "sm_util_pct": round(dmon.mean_sm(marks["t0"], t_end), 1) if dmon else None,
        "syncs_per_step": round(sum(sites.values()) / window, 2),
        "sync_sites": dict(sites.most_common(25)),
        "kernel_launches_per_step": round(n_launch / window, 1),
        "aten_calls_per_step": round(sum(e.count for e in ops) / window, 1),
        "gpu_kernel_ms_per_step": round(dev_total / 1000 / window, 3),  # kernels and copies, no annotations
        "top_kernels_ms_per_step": [(e.key[:90], round(_dev_self(e) / 1000 / window, 4), round(e.count / window, 1))
                                    for e in kernels[:25]],
        "top_cpu_ops_ms_per_step": [(e.key, round(e.self_cpu_time_total / 1000 / window, 4), round(e.count / window, 1))
                                    for e in ops[:30]],
        "train_history_last": res.history[-1] if res.history else None,
    }
    return out


def _dev_self(e) -> float:
    return float(getattr(e, "self_device_time_total", None) or getattr(e, "self_cuda_time_total", 0.0))


_SITES: Counter = Counter()


def _count_sync_warnings():
    """Count each sync-debug warning at the arcsem line that caused it (the warning's own location is torch's);
    returns the function that restores ``warnings.showwarning``."""
    orig = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        if "synchroniz" in str(message):
            _SITES[_arcsem_frame(traceback.extract_stack()[:-1])] += 1
            return
        orig(message, category, filename, lineno, file, line)

    warnings.showwarning = show
    return lambda: setattr(warnings, "showwarning", orig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--name", required=True)
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--skip", type=int, default=50)
    ap.add_argument("--window", type=int, default=20)
    ap.add_argument("--json", default=None)
    ap.add_argument("--device", default="cuda", help="cpu: a smoke test of this script (no syncs to count)")
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_args()
    if a.device == "cuda" and not torch.cuda.is_available():
        sys.exit("error: no CUDA device")
    dmon = None
    try:
        dmon = Dmon()
    except OSError as e:
        print(f"nvidia-smi dmon not available: {e}")
    try:
        r = {"name": a.name, **measure(a.overrides, a.steps, a.skip, a.window, dmon, a.device)}
    finally:
        if dmon:
            dmon.stop()
    print(json.dumps(r, indent=1))
    if a.json:
        p = Path(a.json)
        old = json.loads(p.read_text()) if p.is_file() else []
        p.write_text(json.dumps(old + [r], indent=1))


if __name__ == "__main__":
    main()
