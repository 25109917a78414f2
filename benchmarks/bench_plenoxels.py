"""Plenoxels backbone performance: training rays/s, seconds per 256x192 image, memory; the ray marcher old vs new.

Each case runs in its own process so that the process peak (ru_maxrss) belongs to that case:

    .venv/bin/python benchmarks/bench_plenoxels.py --compare-torch   # quick (128x128x96), dense 128^3, paper (304x304x128)
    .venv/bin/python benchmarks/bench_plenoxels.py --case quick --runs 5

The fused marcher against the one before issue 20 (built from git, ``--old-ref``), side by side in one
process (kernel calls only: forward + backward of 5000 rays, alternating, median of ``--runs``):

    .venv/bin/python benchmarks/bench_plenoxels.py --marcher --threads 1

Grids hold a sphere shell (radii 0.5..0.7 of the half box, ~11% of the voxels: a pollen-like shell)
with density 5 (1 / normalised length) and random SH; ``dense128`` is svox2's dense initial grid.
A training step = 5000 random rays from 8 views of 256x192, MSE + TV, backward, RMSProp step.
"""
from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import time

import torch

CASES = {  # name: (reso, occupancy)
    "quick": ([128, 128, 96], "shell"),  # the largest grid of conf/train/quick.yaml (64^3 -> 128x128x96)
    "dense128": ([128, 128, 128], "dense"),
    "paper": ([304, 304, 128], "shell"),
}


def scene(n=8, w=256, h=192):
    from arcsem.cameras import Cameras, look_at
    from arcsem.scene import Scene, Split

    ang = torch.linspace(-1.0, 1.0, n)
    eye = torch.stack([2.6 * torch.sin(ang), torch.full_like(ang, -0.6), -2.6 * torch.cos(ang)], -1)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0]))
    K = torch.tensor([[230.0, 0, w / 2], [0, 230.0, h / 2], [0, 0, 1]]).repeat(n, 1, 1)
    cams = Cameras(w2c, K, w, h, "pinhole", image_ids=torch.arange(n))
    img = torch.rand(n, h, w, 3, generator=torch.Generator().manual_seed(0))
    return Scene("bench", Split([f"v{i}" for i in range(n)], cams, img), Split([], cams[[]], img[:0]),
                 torch.tensor([[-1.0] * 3, [1.0] * 3]))


def build(reso, occupancy, rasterizer="auto", next_reso=None):
    from arcsem.backbones.plenoxels import Plenoxels
    from arcsem.backbones.plenoxels.grid import build_index

    from arcsem.registry import validate_config

    sc = scene()
    cfg = validate_config(Plenoxels.Config, {"reso": [[4, 4, 4], reso] + ([next_reso] if next_reso else []), "rasterizer": rasterizer}, where="bench")
    bb = Plenoxels(cfg, scene=sc)
    axes = [torch.linspace(-1, 1, r) for r in reso]
    X, Y, Z = torch.meshgrid(*axes, indexing="ij")
    r = (X * X + Y * Y + Z * Z).sqrt()
    occ = torch.ones(reso, dtype=torch.bool) if occupancy == "dense" else (r > 0.5) & (r < 0.7)
    index = build_index(occ)
    m = int(occ.sum())
    g = torch.Generator().manual_seed(0)
    dens = torch.full((m,), 0.1 if occupancy == "dense" else 5.0)
    bb.set_grid(index, dens, 0.1 * torch.randn(m, 9, 3, generator=g))
    bb.level.fill_(1)
    return bb, sc, m / occ.numel()


def median_time(fn, runs):
    fn()  # warm-up
    ts = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def run_upsample():
    """One coarse-to-fine transition of the paper: 256x256x128 -> 304x304x128, weight pruning on 8 views."""
    bb, _, _ = build([256, 256, 128], "shell", next_reso=[304, 304, 128])
    before = bb.num_primitives()
    t = time.perf_counter()
    bb.upsample()
    dt = time.perf_counter() - t
    return {"case": "upsample", "reso": [304, 304, 128], "renderer": "torch", "voxels_before": before,
            "voxels": bb.num_primitives(), "seconds": dt, "param_index_bytes": bb.memory_bytes(),
            "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def run_case(name, runs, renderer):
    if name == "upsample":
        return run_upsample()
    reso, occupancy = CASES[name]
    bb, sc, frac = build(reso, occupancy, renderer)
    cams = sc.train.cameras
    o, d = cams.rays()
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    target = sc.train.images.reshape(-1, 3)
    ids = torch.arange(len(cams)).repeat_interleave(cams.width * cams.height)
    opts = bb.make_optimizers("geometry", bb.param_groups("geometry"))
    gen = torch.Generator().manual_seed(1)

    def fwd_bwd():
        sel = torch.randint(0, o.shape[0], (5000,), generator=gen)
        out = bb.render_rays(o[sel], d[sel], ids[sel])
        loss = ((out["rgb"] - target[sel]) ** 2).mean() + out["tv"]
        for opt in opts.values():
            opt.zero_grad(set_to_none=True)
        loss.backward()
        return out

    def step():
        fwd_bwd()
        for opt in opts.values():
            opt.step()

    def image():
        with torch.no_grad():
            return bb.render(cams[:1])

    res = {"case": name, "reso": reso, "renderer": renderer, "voxels": bb.num_primitives(),
           "occupancy": round(frac, 4), "param_index_bytes": bb.memory_bytes()}
    t_fb = median_time(fwd_bwd, runs)
    res["train_fwd_bwd_s"] = t_fb
    res["train_rays_per_s"] = 5000 / t_fb
    res["train_step_s"] = median_time(step, runs)
    res["image_256x192_s"] = median_time(image, runs)
    res["mean_alpha"] = float(image()["alpha"].mean())
    res["peak_rss_bytes"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--marcher", action="store_true", help="old vs new fused marcher, side by side (bench_plenoxels_marcher.py)")
    ap.add_argument("--threads", type=int, default=1, help="with --marcher: torch/OpenMP threads")
    ap.add_argument("--old-ref", default=None, help="with --marcher: git revision of the old kernel")
    ap.add_argument("--case", default="all", choices=["all", "upsample", *CASES])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--renderer", default="auto", choices=["auto", "cpp", "torch"])
    ap.add_argument("--compare-torch", action="store_true", help="also run the quick case with the PyTorch renderer")
    ap.add_argument("--child", action="store_true")
    a = ap.parse_args()
    if a.marcher:
        from bench_plenoxels_marcher import run_marcher

        run_marcher(a.runs if a.runs != 3 else 7, a.threads, a.old_ref)
        return
    if a.child:
        print(json.dumps(run_case(a.case, a.runs, a.renderer)))
        return
    jobs = [(c, a.renderer) for c in ([*CASES, "upsample"] if a.case == "all" else [a.case])]
    if a.compare_torch:
        jobs.append(("quick", "torch"))
    rows = []
    for case, renderer in jobs:
        cmd = [sys.executable, __file__, "--case", case, "--runs", str(a.runs), "--renderer", renderer, "--child"]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.strip().splitlines()[-1]
        rows.append(json.loads(out))
        r = rows[-1]
        if r["case"] == "upsample":
            print(f"upsample 256x256x128 -> 304x304x128 + weight prune: {r['seconds']:.1f} s, voxels "
                  f"{r['voxels_before']} -> {r['voxels']}, peak RSS {r['peak_rss_bytes'] / 2**20:.0f} MiB", flush=True)
            continue
        print(f"{r['case']:>9} {r['renderer']:>5} {'x'.join(map(str, r['reso'])):>12} voxels {r['voxels']:>9} "
              f"({100 * r['occupancy']:.1f}%)  train {r['train_rays_per_s']:8.0f} rays/s (fwd+bwd {r['train_fwd_bwd_s']:.2f} s,"
              f" step {r['train_step_s']:.2f} s)  image {r['image_256x192_s']:.2f} s  params+index "
              f"{r['param_index_bytes'] / 2**20:.0f} MiB  peak RSS {r['peak_rss_bytes'] / 2**20:.0f} MiB", flush=True)
    base = {r["case"]: r for r in rows if r["renderer"] != "torch"}
    for r in rows:
        if r["renderer"] == "torch" and r["case"] in base:
            b = base[r["case"]]
            print(f"ratio {r['case']} cpp/torch: train rays/s x{b['train_rays_per_s'] / r['train_rays_per_s']:.1f}, "
                  f"image x{r['image_256x192_s'] / b['image_256x192_s']:.1f}")
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}")


if __name__ == "__main__":
    main()
