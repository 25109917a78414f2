"""Per-view costs on a finished Gaussian run: the fused compositing kernels and TSDF fusion.

    .venv/bin/python benchmarks/bench_views.py RUN [--threads 1]              # RUN: a stage-1 run folder (the demo's)
    .venv/bin/python benchmarks/bench_views.py --part tsdf [--threads 2]      # 5.2 M voxels, one 288x192 view, torch vs cpp
    .venv/bin/python benchmarks/bench_views.py RUN --part mesh --threads 2   # RUN's whole fusion, torch vs cpp

``render``: the run's stage-1 model (``RUN/checkpoints/last.pt``, its own config) renders its training views, forward
only and forward + backward of ``sum(rgb)``; prints ms per view (median over the views of ``--repeats`` passes) and
the fused kernels' own time a view (``torch.profiler``: ``--passes`` passes over all views; the median pass, then
each). ``tsdf``: :meth:`TSDFVolume.integrate` of one view, each ``--impl`` in turn, (a depth map with holes and background pixels) into the
demo's grid size, median of 5. Compare commits by running this script in each checkout (its venv) on the same run
folder, alternately.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch


def render_part(run: Path, repeats: int, passes: int) -> None:
    from omegaconf import OmegaConf
    from torch.profiler import ProfilerActivity, profile

    from arcsem.data import load_scene
    from arcsem.runs import load_stage1
    from arcsem.train.stage1 import prepare_scene, train_config

    # the resolved config the run wrote (its .hydra copy keeps interpolations such as ${train.steps} unresolved)
    cfg = OmegaConf.load(run / "config.yaml" if (run / "config.yaml").exists() else run / ".hydra" / "config.yaml")
    scene = load_scene(cfg.dataset)
    bb, _ = load_stage1(run / "checkpoints" / "last.pt", scene, cfg)
    cams = prepare_scene(scene, train_config(cfg)).train.cameras

    def forward(i):
        with torch.no_grad():
            bb.render(cams[i:i + 1])

    def both(i):
        bb.render(cams[i:i + 1])["rgb"].sum().backward()

    print(f"{bb.num_primitives():,} Gaussians, {cams.width}x{cams.height}, {torch.get_num_threads()} thread(s)")
    for name, fn in (("forward", forward), ("forward + backward", both)):
        fn(0)
        times = []
        for _ in range(repeats):
            for i in range(len(cams)):
                t0 = time.perf_counter()
                fn(i)
                times.append(time.perf_counter() - t0)
        print(f"{name}: {1e3 * statistics.median(times):.1f} ms a view")
    kernels: dict[str, list[float]] = {}
    for _ in range(passes):  # the kernels' own time: a pass over every view under the profiler, median of passes
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            for i in range(len(cams)):
                both(i)
        for e in prof.key_averages():
            if e.key.startswith(("_Composite", "_Project", "_ShColors")):
                kernels.setdefault(e.key, []).append(e.self_cpu_time_total / 1e3 / e.count)
    for key, ms in sorted(kernels.items()):
        print(f"{key}: {statistics.median(ms):.2f} ms a view ({', '.join(f'{m:.2f}' for m in ms)})")


def tsdf_part(impls: list[str]) -> None:
    from arcsem.cameras import Cameras, look_at
    from arcsem.mesh.tsdf import TSDFVolume, make_grid

    grid = make_grid(torch.tensor([[-1.3, -1.3, -1.0], [1.3, 1.3, 1.1]], dtype=torch.float64), 0.01447)
    vols = {impl: TSDFVolume(grid, 6 * 0.01447, impl=impl) for impl in impls}
    eye = torch.tensor([[0.0, 0.0, -4.0]], dtype=torch.float64)
    w2c = look_at(eye, torch.zeros_like(eye), torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64))
    cam = Cameras(w2c, torch.tensor([[[300.0, 0, 144], [0, 300.0, 96], [0, 0, 1]]], dtype=torch.float64), 288, 192,
                  "pinhole")
    g = torch.Generator().manual_seed(0)
    depth = 3.5 + torch.rand(192, 288, generator=g)
    valid = torch.rand(192, 288, generator=g) > 0.3
    rgb = torch.rand(192, 288, 3, generator=g)
    times: dict[str, list[float]] = {impl: [] for impl in impls}
    for _ in range(6):  # the implementations alternate, view after view
        for impl, vol in vols.items():
            t0 = time.perf_counter()
            vol.integrate(cam, depth, valid, rgb, ~valid)
            times[impl].append(time.perf_counter() - t0)
    n = grid.shape[0] * grid.shape[1] * grid.shape[2]
    med = {impl: statistics.median(t[1:]) for impl, t in times.items()}
    for impl in impls:
        print(f"TSDF integrate ({impl}), {n / 1e6:.1f} M voxels {grid.shape}: {med[impl]:.3f} s a view")
    if len(impls) == 2:
        print(f"{impls[0]} / {impls[1]}: {med[impls[0]] / med[impls[1]]:.1f}x")


def mesh_part(run: Path, impls: list[str]) -> None:
    """The run's whole mesh fusion (every training view, the run's mesh settings) with each TSDF path: seconds, and
    whether the fused volumes and the meshes are the same."""
    import numpy as np
    from omegaconf import OmegaConf

    from arcsem.data import load_scene
    from arcsem.mesh.extract import fuse_views, mesh_config
    from arcsem.mesh.tsdf import extract_mesh
    from arcsem.runs import load_stage1
    from arcsem.train.stage1 import prepare_scene, train_config

    cfg = OmegaConf.load(run / "config.yaml")
    scene = load_scene(cfg.dataset)
    bb, _ = load_stage1(run / "checkpoints" / "last.pt", scene, cfg)
    scene = prepare_scene(scene, train_config(cfg))
    vols = {}
    for impl in impls:
        mc = mesh_config({**OmegaConf.to_container(cfg.get("mesh") or {}), "impl": impl})
        t0 = time.perf_counter()
        vols[impl], info = fuse_views(bb, scene, mc)
        print(f"fuse_views ({impl}): {time.perf_counter() - t0:.2f} s, {info['views']} views, grid {info['grid']}")
    (a, va), (b, vb) = list(vols.items())[:2] if len(vols) > 1 else (next(iter(vols.items())),) * 2
    flips = int((va.weight != vb.weight).sum() + (va.color_weight != vb.color_weight).sum())
    same = (va.weight == vb.weight) & (va.color_weight == vb.color_weight)
    print(f"{a} vs {b}: {flips} voxel weights differ of {va.weight.numel():,}; largest TSDF difference elsewhere "
          f"{float((va.tsdf - vb.tsdf)[same].abs().max()):.2e}, colour {float((va.color - vb.color)[same].abs().max()):.2e}")
    ma, mb = extract_mesh(va), extract_mesh(vb)
    print(f"meshes: {len(ma[1])} / {len(mb[1])} faces, vertices equal: {ma[0].shape == mb[0].shape and np.array_equal(ma[0], mb[0])}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, nargs="?", help="a finished stage-1 run folder (--part render)")
    ap.add_argument("--part", choices=("render", "tsdf", "mesh"), default="render")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--passes", type=int, default=3, help="profiled passes over the views (kernel times)")
    ap.add_argument("--impl", nargs="+", default=["torch", "cpp"], help="TSDF paths to time side by side (--part tsdf)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    if a.part == "tsdf":
        tsdf_part(a.impl)
    elif a.run is None:
        ap.error(f"--part {a.part} needs a run folder")
    elif a.part == "mesh":
        mesh_part(a.run, a.impl)
    else:
        render_part(a.run, a.repeats, a.passes)


if __name__ == "__main__":
    main()
